//! Issue 24: the live monitor (`fieldlog::NisMonitor`) fed update by update says what
//! `autotune nis` says of a CSV log of the same rows.
//!
//! - Its final report is the binary's `--json` report, value for value, but for `sources`
//!   (the monitor has no file: its source is `live`, format `monitor`; the binary's is the
//!   CSV's path, format `csv`; both count the same rows). The arithmetic is the same code on
//!   the same f64s (the CSV holds each number's shortest round-trip decimal), so the values
//!   are compared exactly, not to a tolerance.
//! - Its status at any point is the batch report of the rows up to there.
//! - The status line's window interval is the χ² window interval (scipy reference values),
//!   its window and running NIS the averages of the NIS computed here independently.
//! - Bad dimensions and bad numbers are typed errors that leave the monitor as it was.

use crate::common;

use std::fmt::Write as _;

use autotune::SimRng;
use autotune::internals::fieldlog::{
    MonitorError, NisMonitor, NisReport, NisSettings, ReadOptions, Window, analyze,
};
use autotune::internals::stats::Verdict;
use common::autotune;
use nalgebra::{DMatrix, Matrix2, Matrix3};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use serde_json::Value;

/// One update of one sensor.
struct Row {
    sensor: &'static str,
    /// s.
    time: f64,
    nu: Vec<f64>,
    /// m × m, row-major.
    s: Vec<f64>,
    /// Write only S's diagonal to the CSV (the reader fills zeros, as given here).
    diagonal: bool,
}

/// Three sensors with something to find in each test `autotune nis` runs:
/// - `pos`: 2-D, a full S that changes with time, consistent innovations;
/// - `alt`: 1-D, innovations twice as wide as S says (NIS ×4), and a 12σ glitch every 250
///   updates (outliers);
/// - `mag`: 3-D every third step, diagonal S, AR(1) innovations (ρ = 0.6: not white) with
///   an offset of 0.4σ on its second axis; one update repeats the previous one's time.
fn rows(seed: u64, steps: usize) -> Vec<Row> {
    let mut rng = SimRng::seed_from_u64(seed);
    let mut n = move || rng.sample::<f64, _>(StandardNormal);
    let mut ar = [0.0f64; 3];
    let mut out = Vec::new();
    for k in 0..steps {
        let t = 0.05 * k as f64;
        let phase = 0.01 * k as f64;
        let (a, b, c) = (1.0 + 0.5 * phase.sin(), 2.0 + 0.7 * phase.cos(), 0.4);
        let (l11, l21) = (a.sqrt(), c / a.sqrt());
        let l22 = (b - l21 * l21).sqrt();
        let (z1, z2) = (n(), n());
        out.push(Row {
            sensor: "pos",
            time: t,
            nu: vec![l11 * z1, l21 * z1 + l22 * z2],
            s: vec![a, c, c, b],
            diagonal: false,
        });
        let glitch = if k % 250 == 249 { 12.0 } else { 0.0 };
        out.push(Row {
            sensor: "alt",
            time: t,
            nu: vec![0.5f64.sqrt() * (2.0 * n() + glitch)],
            s: vec![0.5],
            diagonal: false,
        });
        if k % 3 == 0 {
            let sd = [0.2f64.sqrt(), 0.3f64.sqrt(), 0.4f64.sqrt()];
            let mut nu = Vec::new();
            for j in 0..3 {
                ar[j] = 0.6 * ar[j] + 0.8 * n();
                nu.push(sd[j] * (ar[j] + if j == 1 { 0.4 } else { 0.0 }));
            }
            out.push(Row {
                sensor: "mag",
                time: if k == 300 { 0.05 * 297.0 } else { t },
                nu,
                s: vec![0.2, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.4],
                diagonal: true,
            });
        }
    }
    out
}

/// The rows as a CSV field log (docs/fieldlog.md), numbers as their shortest round-trip
/// decimals.
fn csv(rows: &[Row]) -> String {
    const M: usize = 3;
    let mut o = String::from("time,sensor,nu_1,nu_2,nu_3");
    for i in 1..=M {
        for j in 1..=M {
            write!(o, ",S_{i}_{j}").unwrap();
        }
    }
    o.push('\n');
    for r in rows {
        let m = r.nu.len();
        write!(o, "{},{}", r.time, r.sensor).unwrap();
        for j in 0..M {
            o.push(',');
            if j < m {
                write!(o, "{}", r.nu[j]).unwrap();
            }
        }
        for i in 0..M {
            for j in 0..M {
                o.push(',');
                if i < m && j < m && (i == j || !r.diagonal) {
                    write!(o, "{}", r.s[i * m + j]).unwrap();
                }
            }
        }
        o.push('\n');
    }
    o
}

fn fed(settings: NisSettings, rows: &[Row]) -> NisMonitor {
    let mut m = NisMonitor::new(settings);
    for r in rows {
        m.update(r.sensor, r.time, &r.nu, &r.s).unwrap();
    }
    m
}

/// The report as JSON, without `sources`, and the sources apart.
fn split(mut v: Value) -> (Value, Value) {
    let sources = v.as_object_mut().unwrap().remove("sources").unwrap();
    (v, sources)
}

#[test]
fn monitor_report_is_the_autotune_nis_report_of_its_rows() {
    let rows = rows(24, 1500);
    let settings = NisSettings::default()
        .with_alpha(0.01)
        .unwrap()
        .with_gate(1e-6)
        .unwrap()
        .with_window(Window::Updates(40))
        .unwrap()
        .with_lags(8)
        .unwrap();
    let monitor = fed(settings, &rows);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("live.csv");
    std::fs::write(&path, csv(&rows)).unwrap();
    let p = path.to_str().unwrap();
    let (code, stdout, stderr) = autotune(&[
        "nis", p, "--json", "--alpha", "0.01", "--gate", "1e-6", "--window", "40", "--lags", "8",
    ]);
    assert_eq!(code, Some(1), "inconsistent rows: exit 1; stderr: {stderr}");
    let mut cli: Value = serde_json::from_str(&stdout).unwrap();
    // What the command prints carries autotune's mark; the monitor's report is the value.
    assert_eq!(
        cli.as_object_mut().unwrap().remove("written_by"),
        Some(Value::from("autotune 0.1.0"))
    );
    let (cli, cli_sources) = split(cli);
    let (live, live_sources) = split(serde_json::to_value(monitor.report()).unwrap());
    assert_eq!(
        first_difference(&live, &cli, "report"),
        None,
        "the monitor's report is autotune nis's, value for value"
    );
    assert_eq!(live, cli);
    assert_eq!(live_sources[0]["rows"], cli_sources[0]["rows"]);
    assert_eq!(live_sources[0]["rows"], rows.len());
    assert_eq!(live_sources[0]["path"], "live");
    assert_eq!(live_sources[0]["format"], "monitor");
    assert_eq!(cli_sources[0]["format"], "csv");

    // The comparison covers every test the rows were made to trip, not a trivial report.
    let report: NisReport = monitor.report();
    let sensor = |n: &str| report.sensors.iter().find(|s| s.name == n).unwrap();
    assert_eq!(report.verdict, Verdict::Overconfident);
    assert_eq!(sensor("pos").verdict, Verdict::Consistent);
    assert!(sensor("pos").window.windows > 1000);
    assert_eq!(sensor("alt").nis.verdict, Verdict::Overconfident);
    assert_eq!(sensor("alt").outliers_verdict, Verdict::Overconfident);
    assert!(sensor("alt").finding.is_some());
    assert!(
        sensor("mag")
            .whiteness_tests
            .iter()
            .any(|w| w.verdict == Verdict::NotWhite)
    );
    assert!(
        sensor("mag")
            .mean_tests
            .iter()
            .any(|t| t.verdict == Verdict::Biased)
    );
    assert_eq!(
        report.warnings.len(),
        1,
        "mag's repeated time: {:?}",
        report.warnings
    );
}

/// Where two JSON values first differ (a path and both values), or `None`.
fn first_difference(a: &Value, b: &Value, path: &str) -> Option<String> {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| match (x.get(k), y.get(k)) {
                (Some(u), Some(v)) => first_difference(u, v, &format!("{path}.{k}")),
                _ => Some(format!("{path}.{k}: present in one report only")),
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (u, v))| first_difference(u, v, &format!("{path}[{i}]"))),
        _ => (a != b).then(|| format!("{path}: {a} (monitor) vs {b} (autotune nis)")),
    }
}

/// What the status gives of one sensor, bit for bit.
fn numbers(nis: f64, lo: f64, hi: f64, window: Option<(f64, f64, f64)>) -> Vec<u64> {
    let mut v = vec![nis.to_bits(), lo.to_bits(), hi.to_bits()];
    if let Some((w, l, h)) = window {
        v.extend([w.to_bits(), l.to_bits(), h.to_bits()]);
    }
    v
}

#[test]
fn status_at_any_time_is_the_batch_report_of_the_rows_so_far() {
    let rows = rows(7, 600);
    // A window in seconds here (the other test has one in updates).
    let settings = NisSettings::default()
        .with_window(Window::Seconds(2.0))
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut monitor = NisMonitor::new(settings);
    assert_eq!(monitor.status().to_string(), "waiting for updates");
    let mut checked = 0;
    for (i, r) in rows.iter().enumerate() {
        monitor.update(r.sensor, r.time, &r.nu, &r.s).unwrap();
        let taken = i + 1;
        if ![5, 97, 640, rows.len()].contains(&taken) {
            continue;
        }
        let path = dir.path().join(format!("prefix{taken}.csv"));
        std::fs::write(&path, csv(&rows[..taken])).unwrap();
        let batch = analyze(&[path], &ReadOptions::default(), settings).unwrap();
        let status = monitor.status();
        assert_eq!(status.updates, taken);
        assert_eq!(status.verdict, batch.verdict);
        assert_eq!(status.sensors.len(), batch.sensors.len());
        for (s, b) in status.sensors.iter().zip(&batch.sensors) {
            assert_eq!(s.name, b.name);
            assert_eq!((s.updates, s.outliers), (b.updates, b.outliers));
            assert_eq!(
                numbers(
                    s.nis,
                    s.interval.lower,
                    s.interval.upper,
                    s.window
                        .map(|w| (w.nis, w.interval.lower, w.interval.upper))
                ),
                numbers(
                    b.nis.mean,
                    b.nis.interval.lower,
                    b.nis.interval.upper,
                    b.window.last
                ),
                "{} after {taken} rows",
                s.name
            );
            assert_eq!(s.verdict, b.verdict);
            let words = |f: Option<&autotune::internals::stats::Finding>| {
                f.map(|f| (f.action.clone(), f.evidence.clone()))
            };
            assert_eq!(words(s.advice.as_ref()), words(b.finding.as_ref()));
        }
        checked += 1;
    }
    assert_eq!(checked, 4);
}

/// `scipy.stats.chi2.ppf` (scipy 1.17.1, from tests/data/chi2_scipy.csv): the 2.5 % and
/// 97.5 % quantiles of χ²(100).
const CHI2_100: (f64, f64) = (74.22192747492373, 129.5611971858366);

#[test]
fn status_line_window_interval_is_the_chi_square_window_interval() {
    // A consistent 2-D sensor: the window of 50 updates has 100 degrees of freedom, so its
    // interval is χ²⁻¹(α/2, 100)/50 to χ²⁻¹(1 − α/2, 100)/50 at α = 0.05.
    let rows: Vec<Row> = rows(3, 400)
        .into_iter()
        .filter(|r| r.sensor == "pos")
        .collect();
    let monitor = fed(NisSettings::default(), &rows);
    let status = monitor.status();
    let pos = status.sensor("pos").unwrap();
    let w = pos.window.expect("400 updates fill a window of 50");
    assert_eq!(w.window, Window::Updates(50));
    // statrs agrees with scipy to about 1e-10 relative (DESIGN.md).
    let rel = |a: f64, b: f64| (a / b - 1.0).abs();
    assert!(rel(w.interval.lower, CHI2_100.0 / 50.0) < 1e-9, "{w:?}");
    assert!(rel(w.interval.upper, CHI2_100.1 / 50.0) < 1e-9, "{w:?}");

    // The window's and the running NIS, from the rows here: ν' S⁻¹ ν of a 2 × 2 S. No
    // update of a consistent sensor is near the gate (χ²(2) beyond 23 has p = 1e-5), so
    // every one is averaged. Sums in another order: equal to a few ulps.
    let nis: Vec<f64> = rows
        .iter()
        .map(|r| {
            let (a, c, b) = (r.s[0], r.s[1], r.s[3]);
            let (x, y) = (r.nu[0], r.nu[1]);
            (b * x * x - 2.0 * c * x * y + a * y * y) / (a * b - c * c)
        })
        .collect();
    assert!(nis.iter().all(|v| *v < 23.0));
    let last50: f64 = nis[nis.len() - 50..].iter().sum::<f64>() / 50.0;
    let all: f64 = nis.iter().sum::<f64>() / nis.len() as f64;
    assert!(rel(w.nis, last50) < 1e-12, "{} vs {last50}", w.nis);
    assert!(rel(pos.nis, all) < 1e-12, "{} vs {all}", pos.nis);

    // The status line prints them (4 significant digits).
    let line = pos.to_string();
    let expected_window = format!("(window 50: {} in [1.484, 2.591])", short4(last50));
    assert!(line.starts_with("pos: NIS "), "{line}");
    assert!(
        line.contains(&expected_window),
        "{line} lacks {expected_window}"
    );
    assert!(line.ends_with(pos.verdict.label()), "{line}");

    // In seconds: with an update every 0.125 s (exact in binary), a window of 2 s holds 17
    // updates once full (both ends included): χ²(34) over 17; against statrs for this one.
    let rows: Vec<Row> = rows
        .into_iter()
        .enumerate()
        .map(|(k, r)| Row {
            time: 0.125 * k as f64,
            ..r
        })
        .collect();
    let monitor = fed(
        NisSettings::default()
            .with_window(Window::Seconds(2.0))
            .unwrap(),
        &rows,
    );
    let w = monitor.status().sensor("pos").unwrap().window.unwrap();
    let chi2 = |p: f64| {
        use statrs::distribution::{ChiSquared, ContinuousCDF};
        ChiSquared::new(34.0).unwrap().inverse_cdf(p) / 17.0
    };
    assert!(rel(w.interval.lower, chi2(0.025)) < 1e-12, "{w:?}");
    assert!(rel(w.interval.upper, chi2(0.975)) < 1e-12, "{w:?}");
    assert!(
        monitor
            .status()
            .sensor("pos")
            .unwrap()
            .to_string()
            .contains("(window 2 s: ")
    );
}

/// `v` in 4 significant digits, as the status line prints numbers from 1 to 10.
fn short4(v: f64) -> String {
    assert!((1.0..10.0).contains(&v));
    format!("{v:.3}")
}

#[test]
fn bad_dimensions_and_numbers_are_typed_errors_that_change_nothing() {
    let mut m = NisMonitor::default();
    m.update("gps", 0.0, &[0.3, -0.2], &[1.0, 0.1, 0.1, 2.0])
        .unwrap();
    m.update("baro", 0.0, &[0.5], &[2.0]).unwrap();
    let before = serde_json::to_string(&m.report()).unwrap();
    let err = |m: &mut NisMonitor, sensor: &str, t: f64, nu: &[f64], s: &[f64]| {
        m.update(sensor, t, nu, s).unwrap_err()
    };

    let e = err(&mut m, "gps", 1.0, &[0.3, -0.2], &[1.0, 0.0, 2.0]);
    assert_eq!(
        e,
        MonitorError::CovarianceLength {
            sensor: "gps".into(),
            m: 2,
            len: 3
        }
    );
    assert_eq!(
        e.to_string(),
        "gps: S has 3 entries for ν of 2: expected 2×2, row-major"
    );
    assert!(matches!(
        err(&mut m, "gps", 1.0, &[], &[]),
        MonitorError::InnovationLength { len: 0, .. }
    ));
    assert!(matches!(
        err(&mut m, "big", 1.0, &[0.0; 65], &[1.0; 65 * 65]),
        MonitorError::InnovationLength { len: 65, .. }
    ));
    assert!(matches!(
        err(&mut m, "gps", 1.0, &[0.3], &[1.0]),
        MonitorError::DimensionChanged {
            m: 1,
            before: 2,
            ..
        }
    ));
    assert!(matches!(
        err(&mut m, "gps", -0.5, &[0.3, -0.2], &[1.0, 0.0, 0.0, 2.0]),
        MonitorError::TimeBackwards { .. }
    ));
    assert!(matches!(
        err(&mut m, "gps", f64::NAN, &[0.3, -0.2], &[1.0, 0.0, 0.0, 2.0]),
        MonitorError::NotFinite {
            what: "the time",
            ..
        }
    ));
    assert!(matches!(
        err(
            &mut m,
            "gps",
            1.0,
            &[f64::INFINITY, -0.2],
            &[1.0, 0.0, 0.0, 2.0]
        ),
        MonitorError::NotFinite { what: "ν", .. }
    ));
    assert!(matches!(
        err(&mut m, "gps", 1.0, &[0.3, -0.2], &[1.0, f64::NAN, 0.0, 2.0]),
        MonitorError::NotFinite { what: "S", .. }
    ));
    assert!(matches!(
        err(&mut m, "gps", 1.0, &[0.3, -0.2], &[1.0, 0.5, 0.0, 2.0]),
        MonitorError::NotSymmetric { row: 2, col: 1, .. }
    ));
    assert!(matches!(
        err(&mut m, "gps", 1.0, &[0.3, -0.2], &[1.0, 2.0, 2.0, 1.0]),
        MonitorError::Rejected { .. }
    ));
    assert!(matches!(
        err(&mut m, "", 1.0, &[0.3], &[1.0]),
        MonitorError::SensorName(_)
    ));
    assert!(matches!(
        err(&mut m, "a\nb", 1.0, &[0.3], &[1.0]),
        MonitorError::SensorName(_)
    ));

    // nalgebra matrices: any shape that is not m × m.
    let e = m
        .update_matrix("gps", 1.0, &[0.3, -0.2], &DMatrix::<f64>::zeros(2, 3))
        .unwrap_err();
    assert_eq!(
        e,
        MonitorError::CovarianceShape {
            sensor: "gps".into(),
            m: 2,
            rows: 2,
            cols: 3
        }
    );
    assert!(matches!(
        m.update_matrix("gps", 1.0, &[0.3, -0.2], &Matrix3::<f64>::identity()),
        Err(MonitorError::CovarianceShape {
            rows: 3,
            cols: 3,
            ..
        })
    ));

    assert_eq!(
        serde_json::to_string(&m.report()).unwrap(),
        before,
        "a refused update changes nothing"
    );
    assert_eq!(m.updates(), 2);

    // The same update through a matrix and a row-major slice is the same update.
    let s = Matrix2::new(1.0, 0.25, 0.25, 2.0);
    let mut a = NisMonitor::default();
    let mut b = NisMonitor::default();
    a.update_matrix("gps", 0.0, &[0.3, -0.2], &s).unwrap();
    b.update("gps", 0.0, &[0.3, -0.2], &[1.0, 0.25, 0.25, 2.0])
        .unwrap();
    assert_eq!(
        serde_json::to_string(&a.report()).unwrap(),
        serde_json::to_string(&b.report()).unwrap()
    );
}
