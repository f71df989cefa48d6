//! Issue 23: what `autotune nis` concludes on PX4 logs — only what EKF2 fused from a sensor
//! is judged, the publisher is checked, a bias is named rather than read as correlation,
//! every R too small blames R, and the advice speaks in EKF2's parameters with the log's
//! values. The fixtures come from `support::px4_fixtures` (an independent ULog writer with
//! known truth); the two real logs are PX4's own (tests/data/px4/real, BSD-3-Clause).
use crate::support;

use std::path::{Path, PathBuf};

use autotune::internals::fieldlog::{EventKind, NisReport, NisSettings, ReadOptions, analyze};
use autotune::internals::stats::Suspect;
use support::px4_fixtures as fx;

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(format!("{name}.ulg"));
    std::fs::write(&p, bytes).unwrap();
    p
}

fn judge(path: &Path) -> NisReport {
    analyze(
        &[path.to_path_buf()],
        &ReadOptions::default(),
        NisSettings::default(),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn judge_bytes(bytes: &[u8]) -> NisReport {
    let dir = tempfile::tempdir().unwrap();
    judge(&write(dir.path(), "log", bytes))
}

fn real(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/px4/real")
        .join(name)
}

/// No sensor, finding or parameter advice on a channel whose name contains `part`.
fn never_advised(r: &NisReport, part: &str) {
    for s in &r.sensors {
        assert!(!s.name.contains(part), "{} was judged", s.name);
        if let Some(f) = &s.finding {
            assert!(!f.component.contains(part), "advice on {}", f.component);
        }
    }
}

#[test]
fn issue23_fake_position_fusion_is_reported_as_such_and_never_advised_on() {
    for seed in 1..=3 {
        let (bytes, _) = fx::fake_position_v111(seed);
        let r = judge_bytes(&bytes);
        never_advised(&r, "gps_hpos");
        let info = r.sources[0].px4.as_ref().unwrap();
        let fake: Vec<_> = info
            .not_judged
            .iter()
            .filter(|n| n.reason.starts_with("fake-position"))
            .map(|n| n.name.as_str())
            .collect();
        assert_eq!(
            fake,
            ["ekf0.gps_hpos[0]", "ekf0.gps_hpos[1]"],
            "seed {seed}"
        );
        // Baro is underconfident on its own (S ≈ 3× the truth): with the fake channels
        // out of its peers, its own R is blamed, in EKF2's parameter.
        let baro = r
            .sensors
            .iter()
            .find(|s| s.name == "ekf0.baro_vpos")
            .unwrap();
        let f = baro.finding.as_ref().expect("baro fails");
        assert_eq!(f.suspect, Some(Suspect::R), "seed {seed}: {}", f.action);
        assert_eq!(baro.parameters[0].param, "EKF2_BARO_NOISE");
        assert_eq!(baro.parameters[0].value, Some(3.5));
        // v1.11 logs have no timestamp_sample: the summary says what rows were paired on.
        let notes = r.sources[0].notes.join("\n");
        assert!(
            notes.contains("this release logs no timestamp_sample"),
            "{notes}"
        );
        // The innovations are logged at 5 Hz while baro data come at about 20 Hz.
        assert!(baro.px4.as_ref().unwrap().sampled, "seed {seed}");
    }
}

#[test]
fn issue23_an_lpe_published_ekf2_innovations_is_refused_in_one_line() {
    let (bytes, _) = fx::lpe_legacy(1);
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "lpe", &bytes);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_autotune"))
        .args(["nis", p.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("lpe.ulg") && err.contains("SYS_MC_EST_GROUP = 1") && err.contains("LPE"),
        "{err}"
    );
    assert!(out.stdout.is_empty());
}

#[test]
fn issue23_a_bias_with_rho1_near_one_is_named_and_its_level_not_judged() {
    // Raw ρ₁ ≈ 0.99 and a mean carrying 80 % of E[ν²/S]: one AR(1) with φ = 0.98 around a
    // constant, so about n(1 − φ)/(1 + φ) ≈ 10 independent samples of 1000.
    for seed in 1..=10 {
        let (bytes, _) = fx::biased_heading(seed);
        let r = judge_bytes(&bytes);
        let h = r.sensors.iter().find(|s| s.name == "ekf0.heading").unwrap();
        let reason = h.inconclusive_reason.as_deref().unwrap_or("");
        assert!(
            reason.contains("not enough independent samples"),
            "seed {seed}: {reason:?}"
        );
        let f = h.finding.as_ref().expect("a finding");
        assert_eq!(f.suspect, Some(Suspect::Bias), "seed {seed}: {}", f.action);
        assert!(
            !f.action.contains("decrease R"),
            "seed {seed}: {}",
            f.action
        );
    }
}

/// Whether every failing sensor's advice says `words` first (e.g. "increase Q": the
/// blame table's "increase Q relative to R" counts, it still asks for more Q).
fn all_say(r: &NisReport, words: &str) -> bool {
    let f: Vec<_> = r
        .sensors
        .iter()
        .filter_map(|s| s.finding.as_ref())
        .collect();
    !f.is_empty() && f.iter().all(|f| f.action.starts_with(words))
}

#[test]
fn issue23_every_r_too_small_blames_r_and_q_too_small_blames_q() {
    // A real Kalman filter with every R ×1/4 (innovations alternate) or Q ÷ 25 (they
    // persist). A rule right 95 % of the time per seed gives ≥ 19 of 20 with probability
    // 0.74; a coin, 2·10⁻⁵.
    let (mut r_right, mut q_right) = (0, 0);
    for seed in 1..=20 {
        let (bytes, _) = fx::all_r_too_small(seed);
        let r = judge_bytes(&bytes);
        r_right += usize::from(r.suspect == Some(Suspect::R) && !all_say(&r, "increase Q"));
        let (bytes, _) = fx::all_q_too_small(seed);
        let r = judge_bytes(&bytes);
        let ok = all_say(&r, "increase Q");
        if !ok {
            let f: Vec<_> = r
                .sensors
                .iter()
                .filter_map(|s| s.finding.as_ref())
                .map(|f| f.action.clone())
                .collect();
            eprintln!("Q seed {seed}: {f:?}");
        }
        q_right += usize::from(ok);
    }
    eprintln!("R blamed on {r_right} of 20, Q on {q_right} of 20");
    assert!(r_right >= 19, "R blamed on {r_right} of 20");
    assert!(q_right >= 19, "Q blamed on {q_right} of 20");
}

#[test]
fn issue23_the_suggested_ekf2_noise_recovers_the_true_baro_noise() {
    // True σ = 2.0 m, EKF2_BARO_NOISE = 3.5 m in the log. Over ~1000 baro updates the NIS
    // average has a relative sd of √(2/1000) ≈ 4.5 %, so σ's is ≈ 2.3 %: each seed within
    // 8 % (3.5 sd), the mean of 20 within 2 % (≈ 4 sd of the mean).
    let mut got = Vec::new();
    for seed in 1..=20 {
        let (bytes, truth) = fx::known_baro_noise(seed);
        let r = judge_bytes(&bytes);
        let baro = r
            .sensors
            .iter()
            .find(|s| s.name.ends_with("baro_vpos"))
            .unwrap();
        let p = baro
            .parameters
            .first()
            .unwrap_or_else(|| panic!("seed {seed}: no parameter advice: {:?}", baro.finding));
        assert_eq!(p.param, "EKF2_BARO_NOISE");
        assert_eq!(p.value, Some(3.5));
        let sigma = truth
            .channels
            .iter()
            .find_map(|c| c.true_sigma.filter(|_| c.param == Some("EKF2_BARO_NOISE")))
            .unwrap();
        let s = p.suggested.unwrap();
        assert!(
            (s / sigma - 1.0).abs() < 0.08,
            "seed {seed}: {s} for {sigma}"
        );
        assert!(
            p.text.contains("EKF2_BARO_NOISE = 3.50 m → about"),
            "{}",
            p.text
        );
        got.push(s / sigma);
    }
    let mean = got.iter().sum::<f64>() / got.len() as f64;
    let worst = got.iter().map(|r| (r - 1.0).abs()).fold(0.0, f64::max);
    eprintln!("suggested/true σ: mean {mean:.4}, worst {worst:.4}");
    assert!((mean - 1.0).abs() < 0.02, "mean ratio {mean}");
}

#[test]
fn issue23_aid_source_topics_use_fused_count_rejections_and_skip_fake_fusion() {
    let (bytes, truth) = fx::aid_src_v114(1);
    let r = judge_bytes(&bytes);
    never_advised(&r, "fake_pos");
    let info = r.sources[0].px4.as_ref().unwrap();
    assert_eq!(
        info.not_judged
            .iter()
            .filter(|n| n.name.contains("fake_pos"))
            .count(),
        4
    );
    for c in &truth.channels {
        if c.kind != fx::Kind::Sensor {
            continue;
        }
        let src = c.topic.trim_start_matches("estimator_aid_src_");
        let axis = c.field.strip_prefix("innovation").unwrap_or("");
        let name = format!("ekf{}.{src}{axis}", c.instance);
        let s = r
            .sensors
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no {name}"));
        assert_eq!(s.updates, c.fused + c.rejected, "{name}");
        assert_eq!(s.px4.as_ref().unwrap().rejected, Some(c.rejected), "{name}");
    }
    // Instance 1's GNSS position has S ×4 too small: its own R is blamed, in EKF2's words.
    let g = r
        .sensors
        .iter()
        .find(|s| s.name == "ekf1.gnss_pos[0]")
        .unwrap();
    assert_eq!(g.finding.as_ref().unwrap().suspect, Some(Suspect::R));
    assert_eq!(g.parameters[0].param, "EKF2_GPS_P_NOISE");
}

#[test]
fn issue23_the_primary_instance_its_switch_and_the_flight_are_events() {
    let (bytes, truth) = fx::primary_switch(1);
    let r = judge_bytes(&bytes);
    let info = r.sources[0].px4.as_ref().unwrap();
    let origin = info.time_origin_us as f64;
    let at = |us: u64| (us as f64 - origin) * 1e-6;
    let primary: Vec<_> = info
        .events
        .iter()
        .filter(|e| e.kind == EventKind::Primary)
        .collect();
    assert_eq!(primary.len(), truth.primary.len());
    for (e, (t, inst)) in primary.iter().zip(&truth.primary) {
        assert_eq!(e.what, format!("primary: ekf{inst}"));
        assert!((e.time - at(*t)).abs() < 1e-9);
    }
    let find = |k: EventKind| info.events.iter().find(|e| e.kind == k).unwrap().time;
    assert!((find(EventKind::Takeoff) - at(truth.takeoff_us)).abs() < 0.6);
    assert!((find(EventKind::Landing) - at(truth.landing_us)).abs() < 0.6);
    let secs: f64 = info.instances.iter().filter_map(|i| i.primary_s).sum();
    assert!(
        info.instances.iter().all(|i| i.primary_s.unwrap() > 0.0),
        "{:?}",
        info.instances
    );
    assert!(secs > 150.0, "{secs}");
}

#[test]
fn issue23_the_real_v1_13_log_has_only_fake_position_on_gps_hpos_and_no_gps() {
    let r = judge(&real("sample_logging_tagged_and_default_params.ulg"));
    never_advised(&r, "gps_hpos");
    let info = r.sources[0].px4.as_ref().unwrap();
    assert_eq!(info.publisher, "EKF2");
    assert_eq!(info.version.as_deref(), Some("v1.13.0"));
    assert_eq!(info.params.get("EKF2_BARO_NOISE"), Some(&3.5));
    for inst in 0..3 {
        for axis in 0..2 {
            let name = format!("ekf{inst}.gps_hpos[{axis}]");
            let n = info.not_judged.iter().find(|n| n.name == name).unwrap();
            assert!(
                n.reason.starts_with("fake-position"),
                "{name}: {}",
                n.reason
            );
        }
    }
    // The selector says ekf0 was primary throughout.
    assert!(info.instances[0].primary_s.unwrap() > 9.0);
    assert_eq!(info.instances[1].primary_s, Some(0.0));
    // Instances 1 and 2 are logged at 2 Hz while baro data come at about 19 Hz.
    let b1 = r
        .sensors
        .iter()
        .find(|s| s.name == "ekf1.baro_vpos")
        .unwrap();
    assert!(b1.px4.as_ref().unwrap().sampled);
}

#[test]
fn issue23_the_real_v1_15_log_judges_gps_only_after_it_starts() {
    let r = judge(&real("sample_px4_events.ulg"));
    let info = r.sources[0].px4.as_ref().unwrap();
    let gps_on = info
        .events
        .iter()
        .find(|e| e.what == "ekf0: GPS on")
        .unwrap()
        .time;
    assert!((gps_on - 9.652).abs() < 1e-6, "{gps_on}");
    let takeoff = info
        .events
        .iter()
        .find(|e| e.kind == EventKind::Takeoff)
        .unwrap()
        .time;
    assert!((takeoff - 16.74).abs() < 1e-6);
    for s in r.sensors.iter().filter(|s| s.name.contains("gps_")) {
        assert!(
            s.time_span.0 >= gps_on - 1e-9,
            "{} from {}",
            s.name,
            s.time_span.0
        );
    }
    let hpos = r
        .sensors
        .iter()
        .find(|s| s.name == "ekf0.gps_hpos[0]")
        .unwrap();
    assert!(hpos.px4.as_ref().unwrap().fake > 0);
    // The innovations are correlated over ~40 samples: the GPS velocity level is not judged.
    let v = r
        .sensors
        .iter()
        .find(|s| s.name == "ekf0.gps_hvel[0]")
        .unwrap();
    assert!(v.inconclusive_reason.is_some());
    assert!(
        v.finding
            .as_ref()
            .is_none_or(|f| !f.action.starts_with("decrease R"))
    );
}

#[test]
fn issue23_channels_fused_only_on_the_ground_are_not_called_not_fused() {
    use autotune::internals::fieldlog::{Dropped, NisAnalyzer, SensorInfo};
    let mut an = NisAnalyzer::new(NisSettings::default());
    for (name, dropped) in [
        (
            "ekf0.rng_vpos",
            Dropped {
                on_ground: 40,
                ..Dropped::default()
            },
        ),
        (
            "ekf0.ev_vpos",
            Dropped {
                idle: 40,
                ..Dropped::default()
            },
        ),
    ] {
        let i = an
            .sensor(SensorInfo {
                name: name.into(),
                components: vec![name.into()],
                group: "ekf0".into(),
            })
            .unwrap();
        an.drop_rows(i, dropped);
    }
    let text = autotune::report::nis::nis_summary_text(&an.report());
    assert!(
        text.contains("not fused (no update): ekf0.ev_vpos\n"),
        "{text}"
    );
    assert!(
        text.contains("fused only on the ground (set aside by --in-air): ekf0.rng_vpos\n"),
        "{text}"
    );
}
