//! A vehicle filter that watches its own consistency while it runs: a phone-like navigation
//! KF (planar position and velocity, altitude and climb rate) fusing a 1 Hz GPS fix and a
//! 10 Hz barometer, with the barometer's R set 4× too small (σ 0.25 m where the sensor's
//! noise is 0.5 m). Every update goes to an [`autotune::NisMonitor`]; a status line
//! every 30 s of simulated time gives each sensor's running NIS against its χ² interval, the
//! last window's NIS against its own, and the verdict so far; at the end, the verdict and the
//! advice of `autotune nis`.
//!
//! ```sh
//! cargo run --release --example live_monitor                         # status lines, advice
//! cargo run --release --example live_monitor -- --log /tmp/live.csv --json > /tmp/live.json
//! autotune nis /tmp/live.csv --json > /tmp/nis.json                  # the same report
//! ```
//!
//! Options: `--log FILE` also writes every update to FILE as a CSV field log
//! (docs/fieldlog.md), as it goes (so `autotune nis --follow FILE` can watch it); `--json`
//! prints the monitor's final report as JSON instead of the status lines;
//! `--seconds T` simulates T seconds (default 300); `--seed N` seeds the simulation.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use autotune::SimRng;
use autotune::{NisMonitor, NisSettings};
use nalgebra::{SMatrix, SVector};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

/// Filter step, s.
const DT: f64 = 0.1;
/// GPS fix every this many steps (1 Hz).
const GPS_EVERY: usize = 10;
/// A status line every this many steps (30 s).
const STATUS_EVERY: usize = 300;
/// Acceleration noise spectral densities, horizontal and vertical, m²/s³ (truth and filter).
const Q_HORIZONTAL: f64 = 0.05;
const Q_VERTICAL: f64 = 0.01;
/// GPS horizontal σ, m (truth and filter).
const GPS_SIGMA: f64 = 2.5;
/// Barometer σ, m: the sensor's, and the filter's too small one.
const BARO_SIGMA_TRUE: f64 = 0.5;
const BARO_SIGMA_FILTER: f64 = 0.25;
/// Largest sensor dimension: the CSV log's `nu_*` and `S_*_*` columns.
const MAX_M: usize = 2;

/// State: x, vx, y, vy (m, m/s), altitude h, climb rate vh (m, m/s).
type State = SVector<f64, 6>;
type Cov = SMatrix<f64, 6, 6>;

/// Constant-velocity transition and its process noise for one step.
fn transition() -> (Cov, Cov) {
    let mut f = Cov::identity();
    let mut q = Cov::zeros();
    let (t3, t2) = (DT.powi(3) / 3.0, DT.powi(2) / 2.0);
    for (a, qa) in [(0, Q_HORIZONTAL), (2, Q_HORIZONTAL), (4, Q_VERTICAL)] {
        f[(a, a + 1)] = DT;
        q[(a, a)] = qa * t3;
        q[(a, a + 1)] = qa * t2;
        q[(a + 1, a)] = qa * t2;
        q[(a + 1, a + 1)] = qa * DT;
    }
    (f, q)
}

/// The filter's estimate.
struct Kf {
    x: State,
    p: Cov,
}

impl Kf {
    /// A Joseph-form update with measurement `z`, model `h`, noise `r`; returns the
    /// innovation ν and its covariance S the filter used.
    fn update<const M: usize>(
        &mut self,
        z: SVector<f64, M>,
        h: SMatrix<f64, M, 6>,
        r: SMatrix<f64, M, M>,
    ) -> (SVector<f64, M>, SMatrix<f64, M, M>) {
        let nu = z - h * self.x;
        let s = h * self.p * h.transpose() + r;
        let chol = s.cholesky().expect("S is positive definite");
        let k = chol.solve(&(h * self.p)).transpose();
        self.x += k * nu;
        let i_kh = Cov::identity() - k * h;
        self.p = i_kh * self.p * i_kh.transpose() + k * r * k.transpose();
        self.p = (self.p + self.p.transpose()) * 0.5;
        (nu, s)
    }
}

/// Command-line options.
struct Options {
    log: Option<PathBuf>,
    json: bool,
    seconds: f64,
    seed: u64,
}

fn options() -> Result<Options, String> {
    let mut o = Options {
        log: None,
        json: false,
        seconds: 300.0,
        seed: 24,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |flag: &str| args.next().ok_or(format!("{flag} needs a value"));
        match a.as_str() {
            "--log" => o.log = Some(PathBuf::from(value("--log")?)),
            "--json" => o.json = true,
            "--seconds" => {
                let v = value("--seconds")?;
                o.seconds = v
                    .parse()
                    .ok()
                    .filter(|s: &f64| s.is_finite() && *s > 0.0 && *s <= 1e6)
                    .ok_or(format!("--seconds {v}: a number of seconds in (0, 1e6]"))?;
            }
            "--seed" => {
                let v = value("--seed")?;
                o.seed = v.parse().map_err(|_| format!("--seed {v}: not a number"))?;
            }
            _ => {
                return Err(format!(
                    "unknown argument '{a}' (options: --log FILE, --json, --seconds T, --seed N)"
                ));
            }
        }
    }
    Ok(o)
}

/// The CSV field log of docs/fieldlog.md: one row per update, all m² entries of S.
struct CsvLog(BufWriter<File>);

impl CsvLog {
    fn create(path: &PathBuf) -> std::io::Result<CsvLog> {
        let mut w = BufWriter::new(File::create(path)?);
        let mut header = vec!["time".to_string(), "sensor".to_string()];
        header.extend((1..=MAX_M).map(|j| format!("nu_{j}")));
        for i in 1..=MAX_M {
            header.extend((1..=MAX_M).map(|j| format!("S_{i}_{j}")));
        }
        writeln!(w, "{}", header.join(","))?;
        Ok(CsvLog(w))
    }

    /// One row; `{}` writes the shortest decimal that reads back as the same f64, so the
    /// log holds exactly the numbers the monitor was given.
    fn row<const M: usize>(
        &mut self,
        time: f64,
        sensor: &str,
        nu: &SVector<f64, M>,
        s: &SMatrix<f64, M, M>,
    ) -> std::io::Result<()> {
        let cell = |i: usize, j: usize| {
            if i < M && j < M {
                format!("{}", s[(i, j)])
            } else {
                String::new()
            }
        };
        let mut cells = vec![format!("{time}"), sensor.to_string()];
        cells.extend((0..MAX_M).map(|j| nu.get(j).map_or(String::new(), |v| format!("{v}"))));
        for i in 0..MAX_M {
            cells.extend((0..MAX_M).map(|j| cell(i, j)));
        }
        writeln!(self.0, "{}", cells.join(","))
    }
}

fn run(o: &Options) -> Result<(), String> {
    let mut log = match &o.log {
        Some(p) => Some(CsvLog::create(p).map_err(|e| format!("{}: {e}", p.display()))?),
        None => None,
    };
    let log_err = |e: std::io::Error| format!("writing the log: {e}");
    let mut rng = SimRng::seed_from_u64(o.seed);
    let mut normal = move || rng.sample::<f64, _>(StandardNormal);
    let (f, q) = transition();
    let q_factor = q.cholesky().expect("Q is positive definite").l();

    let mut truth = State::from_column_slice(&[0.0, 12.0, 0.0, 3.0, 120.0, 0.5]);
    let mut kf = Kf {
        x: truth,
        p: Cov::from_diagonal(&State::from_column_slice(&[4.0, 1.0, 4.0, 1.0, 1.0, 0.25])),
    };
    let h_gps = SMatrix::<f64, 2, 6>::from_row_slice(&[
        1.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
        0.0, 0.0, 1.0, 0.0, 0.0, 0.0,
    ]);
    let r_gps = SMatrix::<f64, 2, 2>::identity() * GPS_SIGMA.powi(2);
    let h_baro = SMatrix::<f64, 1, 6>::from_row_slice(&[0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let r_baro = SMatrix::<f64, 1, 1>::new(BARO_SIGMA_FILTER.powi(2));

    // The settings `autotune nis` uses by default: α 0.05, gate 1e-5, window 50, 10 lags.
    let mut monitor = NisMonitor::new(NisSettings::default());
    let steps = (o.seconds / DT).round() as usize;
    for k in 1..=steps {
        let t = k as f64 * DT;
        let w = State::from_fn(|_, _| normal());
        truth = f * truth + q_factor * w;
        kf.x = f * kf.x;
        kf.p = f * kf.p * f.transpose() + q;

        let z = h_baro * truth + SVector::<f64, 1>::new(BARO_SIGMA_TRUE * normal());
        let (nu, s) = kf.update(z, h_baro, r_baro);
        monitor
            .update_matrix("baro", t, nu.as_slice(), &s)
            .map_err(|e| e.to_string())?;
        if let Some(l) = &mut log {
            l.row(t, "baro", &nu, &s).map_err(log_err)?;
        }
        if k % GPS_EVERY == 0 {
            let noise = SVector::<f64, 2>::new(normal(), normal()) * GPS_SIGMA;
            let (nu, s) = kf.update(h_gps * truth + noise, h_gps, r_gps);
            monitor
                .update_matrix("gps", t, nu.as_slice(), &s)
                .map_err(|e| e.to_string())?;
            if let Some(l) = &mut log {
                l.row(t, "gps", &nu, &s).map_err(log_err)?;
            }
        }
        if k % STATUS_EVERY == 0 {
            if let Some(l) = &mut log {
                l.0.flush().map_err(log_err)?;
            }
            if !o.json {
                println!("{}", monitor.status());
            }
        }
    }
    if let Some(l) = &mut log {
        l.0.flush().map_err(log_err)?;
    }

    if o.json {
        let json = serde_json::to_string_pretty(&monitor.report()).map_err(|e| e.to_string())?;
        println!("{json}");
        return Ok(());
    }
    let status = monitor.status();
    println!();
    for s in &status.sensors {
        println!("{s}");
    }
    println!("verdict: {}", status.verdict.describe());
    let advice: Vec<_> = status
        .sensors
        .iter()
        .filter_map(|s| s.advice.as_ref())
        .collect();
    if !advice.is_empty() {
        println!("advice:");
        for a in advice {
            println!("  {}: {} — {}", a.component, a.action, a.evidence);
        }
    }
    if let Some(p) = &o.log {
        println!(
            "\nthe log: {} (autotune nis {} gives the same statistics)",
            p.display(),
            p.display()
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let o = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("Error: {e}");
            return ExitCode::from(2);
        }
    };
    match run(&o) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("Error: {e}");
            ExitCode::from(2)
        }
    }
}
