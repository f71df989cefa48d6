//! Issue 23, points 3–5: field-log statistics that respect the data. Every log here is
//! written by the test (CSV, one row per update) with a known truth, and judged through the
//! `autotune nis` binary's JSON and text, so the tests compile and run on builds before
//! the fix too.
//!
//! - A channel whose mean carries most of E[ν²/S] and whose innovations persist (ρ₁ ≈ 0.99)
//!   is named a bias, not "decrease R".
//! - Strongly correlated innovations leave too few independent samples for the NIS level:
//!   "not enough independent samples to judge", never "underconfident" / "decrease R".
//! - A real Kalman filter (1-D constant velocity, three sensors) with every R four times too
//!   small blames R; with Q / 25 it blames Q (the pooled lag-1 sign).
//! - The table shows the mean over every update beside the gated one.
//! - Time stamps that stand still or go back are warned about, and a moving window in
//!   seconds never reaches across a jump back.

use crate::common;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use autotune::SimRng;
use common::autotune;
use nalgebra::{Matrix2, RowVector2, Vector2};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use serde_json::Value;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn nis_json(args: &[&str]) -> (i32, Value) {
    let mut all = vec!["nis", "--json"];
    all.extend_from_slice(args);
    let (code, out, err) = autotune(&all);
    let v: Value = serde_json::from_str(&out)
        .unwrap_or_else(|e| panic!("not JSON ({e}); stderr: {err}; stdout: {out}"));
    (code.expect("exit code"), v)
}

fn sensor<'a>(v: &'a Value, name: &str) -> &'a Value {
    v["sensors"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == name)
        .unwrap_or_else(|| panic!("no sensor {name}"))
}

/// A scalar channel `name` whose normalized innovation is `offset + x_k`, x an AR(1) of
/// coefficient `phi` and standard deviation `sd` (S = 1), `n` updates at 0.2 s.
fn ar1_channel(name: &str, n: usize, offset: f64, phi: f64, sd: f64, seed: u64) -> String {
    let mut rng = SimRng::seed_from_u64(seed);
    let w = (1.0 - phi * phi).sqrt();
    let mut x = sd * rng.sample::<f64, _>(StandardNormal);
    let mut out = String::new();
    for k in 0..n {
        x = phi * x + sd * w * rng.sample::<f64, _>(StandardNormal);
        let _ = writeln!(out, "{},{name},{},1", k as f64 * 0.2, offset + x);
    }
    out
}

const HEADER: &str = "time,sensor,nu_1,S_1_1\n";

/// The heading of the issue's v1.11 log, rebuilt: the mean innovation (0.5σ) carries 80% of
/// E[ν²/S], the rest is a slow wander (ρ₁ = 0.97, 0.25σ), 200 updates. The NIS average is
/// far below 1, and the raw lag-1 correlation near 0.99 made the advice "decrease R"; the
/// zero-mean test cannot be significant (about 3 effective samples). The finding must name
/// the bias and its share, on every one of 10 seeds (the share is 0.8 ± about 0.1 here,
/// far from the 0.5 threshold), and never advise a scale of R or Q.
#[test]
fn issue23_a_mean_carrying_most_of_the_nis_is_named_a_bias_not_decrease_r() {
    let dir = tempfile::tempdir().unwrap();
    for seed in 0..10 {
        let text = format!(
            "{HEADER}{}",
            ar1_channel("heading", 200, 0.5, 0.97, 0.25, 23_100 + seed)
        );
        let p = write(dir.path(), &format!("bias{seed}.csv"), &text);
        let (_, v) = nis_json(&[p.to_str().unwrap()]);
        let s = sensor(&v, "heading");
        let f = &s["finding"];
        assert_eq!(f["suspect"], "bias", "seed {seed}: {f}");
        let action = f["action"].as_str().unwrap();
        assert!(
            action.contains("% of E[ν²/S]") && action.contains("not a scale of Q or R"),
            "seed {seed}: {action}"
        );
        let share = s["mean_tests"][0]["mean_share"].as_f64().unwrap();
        assert!(share > 0.6 && share < 0.95, "seed {seed}: share {share}");
        assert_ne!(s["nis"]["verdict"], "underconfident", "seed {seed}");
    }
    // In words, on the summary.
    let text = format!(
        "{HEADER}{}",
        ar1_channel("heading", 200, 0.5, 0.97, 0.25, 23_100)
    );
    let p = write(dir.path(), "bias.csv", &text);
    let (_, out, _) = autotune(&["nis", p.to_str().unwrap()]);
    assert!(
        out.contains("heading: the mean innovation carries"),
        "{out}"
    );
    assert!(!out.contains("decrease R"), "{out}");
}

/// Zero-mean innovations that wander (ρ₁ = 0.97, 0.5σ: the NIS average near 0.25) over 200
/// updates: about 13 independent samples of u², too few for the NIS test to tell a factor of
/// 2 at its level. The NIS level is inconclusive with the reason, the table says it, and the
/// advice never says "decrease" (R or Q), on every one of 20 seeds where the mean does not
/// carry half of E[u²] (a wander that slow looks like an offset on some seeds: those are
/// named a bias, which the test above covers). Before issue 23 the level read
/// "underconfident" and the advice "decrease R".
#[test]
fn issue23_strongly_correlated_innovations_are_not_enough_independent_samples_to_judge() {
    let dir = tempfile::tempdir().unwrap();
    let mut judged = 0;
    for seed in 0..20 {
        let text = format!(
            "{HEADER}{}",
            ar1_channel("hagl", 200, 0.0, 0.97, 0.5, 23_200 + seed)
        );
        let p = write(dir.path(), &format!("wander{seed}.csv"), &text);
        let (_, v) = nis_json(&[p.to_str().unwrap()]);
        let s = sensor(&v, "hagl");
        let action = s["finding"]["action"].as_str().unwrap_or("");
        assert!(
            !action.contains("decrease") && !action.contains("increase"),
            "seed {seed}: {action}"
        );
        if s["mean_tests"][0]["mean_share"].as_f64().unwrap_or(0.0) >= 0.5 {
            continue;
        }
        judged += 1;
        assert_eq!(s["nis"]["verdict"], "inconclusive", "seed {seed}: {s:#}");
        let reason = s["inconclusive_reason"].as_str().unwrap();
        assert!(
            reason.starts_with("not enough independent samples to judge: about")
                && reason.contains("of 200 (ρ₁ = +0.9"),
            "seed {seed}: {reason}"
        );
        let n_eff = s["n_eff"].as_f64().unwrap();
        assert!(n_eff > 3.0 && n_eff < 40.0, "seed {seed}: n_eff {n_eff}");
        assert!(
            action.starts_with("not enough independent samples"),
            "{action}"
        );
        if judged == 1 {
            let (_, out, _) = autotune(&["nis", p.to_str().unwrap()]);
            assert!(
                out.contains("hagl: NIS level not judged: not enough independent samples"),
                "{out}"
            );
            assert!(!out.contains("underconfident"), "{out}");
        }
    }
    assert!(
        judged >= 10,
        "only {judged} of 20 seeds without an offset-like mean"
    );
}

/// A white channel's numbers do not move: no effective-sample correction, n_eff = the gated
/// updates, and the interval is the textbook one.
#[test]
fn issue23_a_white_channel_keeps_its_interval_and_all_its_samples() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!(
        "{HEADER}{}",
        ar1_channel("baro", 2000, 0.0, 0.0, 1.0, 23_300)
    );
    let p = write(dir.path(), "white.csv", &text);
    let (_, v) = nis_json(&[p.to_str().unwrap()]);
    let s = sensor(&v, "baro");
    assert!(s["inconclusive_reason"].is_null());
    let gated = s["updates"].as_f64().unwrap() - s["outliers"].as_f64().unwrap();
    assert!((s["n_eff"].as_f64().unwrap() - gated).abs() < 1e-9);
    assert_eq!(s["nis"]["verdict"], "consistent");
}

/// A 1-D constant-velocity target manoeuvring hard (white acceleration of spectral density
/// 100 m²/s³, steps of 0.1 s), three sensors: position A every step (R = 1), position B
/// every second step (R = 4), velocity every fifth (R = 0.04). The gain is high enough that
/// a wrong one shows in the lag-1 correlation of each sensor's own sequence. The filter runs with its own Q and R scaled by `q_scale` and
/// `r_scale`; the log is its innovations and S as CSV.
fn cv_log(q_scale: f64, r_scale: f64, steps: usize, seed: u64) -> String {
    const DT: f64 = 0.1;
    let q = 100.0;
    let mut rng = SimRng::seed_from_u64(seed);
    let mut n = || rng.sample::<f64, _>(StandardNormal);
    let f = Matrix2::new(1.0, DT, 0.0, 1.0);
    let qm = |q: f64| {
        Matrix2::new(
            q * DT.powi(3) / 3.0,
            q * DT.powi(2) / 2.0,
            q * DT.powi(2) / 2.0,
            q * DT,
        )
    };
    let l_true = qm(q).cholesky().unwrap().l();
    let q_f = qm(q * q_scale);
    let mut x = Vector2::new(0.0, 1.0);
    let mut xh = x;
    let mut p = Matrix2::identity();
    let mut out = String::from(HEADER);
    for k in 1..=steps {
        x = f * x + l_true * Vector2::new(n(), n());
        xh = f * xh;
        p = f * p * f.transpose() + q_f;
        let mut sensors = vec![("pos_a", 0usize, 1.0)];
        if k % 2 == 0 {
            sensors.push(("pos_b", 0, 4.0));
        }
        if k % 5 == 0 {
            sensors.push(("vel", 1, 0.04));
        }
        for (name, i, r) in sensors {
            let h = if i == 0 {
                RowVector2::new(1.0, 0.0)
            } else {
                RowVector2::new(0.0, 1.0)
            };
            let z = x[i] + f64::sqrt(r) * n();
            let r_f = r * r_scale;
            let nu = z - (h * xh)[0];
            let s = (h * p * h.transpose())[0] + r_f;
            let gain = p * h.transpose() / s;
            xh += gain * nu;
            let ikh = Matrix2::identity() - gain * h;
            p = ikh * p * ikh.transpose() + gain * gain.transpose() * r_f;
            let _ = writeln!(out, "{},{name},{nu},{s}", k as f64 * DT);
        }
    }
    out
}

/// How many of 20 seeds blame `want`, and the first other answer.
fn blamed(q_scale: f64, r_scale: f64, want: &str, base: u64) -> (usize, Option<String>) {
    let dir = tempfile::tempdir().unwrap();
    let (mut hits, mut other) = (0, None);
    for seed in 0..20 {
        let p = write(
            dir.path(),
            &format!("cv{seed}.csv"),
            &cv_log(q_scale, r_scale, 3000, base + seed),
        );
        let (code, v) = nis_json(&[p.to_str().unwrap()]);
        assert_eq!(code, 1, "seed {seed}: the filter is off, the log must fail");
        if v["suspect"] == want {
            hits += 1;
        } else if other.is_none() {
            let actions: Vec<String> = v["sensors"]
                .as_array()
                .unwrap()
                .iter()
                .map(|s| format!("{}: {}", s["name"], s["finding"]["action"]))
                .collect();
            other = Some(format!("seed {seed}: {} ({actions:?})", v["suspect"]));
        }
    }
    (hits, other)
}

/// Every sensor's R four times too small: every NIS is too high, and in the level alone
/// that looks like a Q too small (what the sensors share). The gain is too high, so the
/// innovations alternate: the pooled lag-1 correlation is negative and R is blamed, with
/// "increase every sensor's R". Required on at least 19 of 20 seeds: a rule that decided
/// right with probability 0.95 per seed would pass with probability 0.74, one that could
/// not tell (a coin) with probability 2·10⁻⁵, and the rule before issue 23 (Q whenever every
/// sensor is off the same way) on none.
#[test]
fn issue23_every_r_too_small_blames_r_on_nineteen_of_twenty_seeds() {
    let (hits, other) = blamed(1.0, 0.25, "r", 23_400);
    eprintln!("R × 1/4: R blamed on {hits} of 20; first other: {other:?}");
    assert!(hits >= 19, "R blamed on {hits} of 20: {other:?}");
    // The words.
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "r.csv", &cv_log(1.0, 0.25, 3000, 23_499));
    let (_, out, _) = autotune(&["nis", p.to_str().unwrap()]);
    assert!(out.contains("increase every sensor's R"), "{out}");
    assert!(out.contains("ρ₁ pooled over them = -0."), "{out}");
}

/// Q / 25: the NIS is too high again, but the gain is too low, so the innovations persist:
/// the pooled lag-1 correlation is positive and Q is blamed, on at least 19 of 20 seeds
/// (the same binomial reasoning as for R).
#[test]
fn issue23_q_too_small_blames_q_on_nineteen_of_twenty_seeds() {
    let (hits, other) = blamed(1.0 / 25.0, 1.0, "q", 23_500);
    eprintln!("Q / 25: Q blamed on {hits} of 20; first other: {other:?}");
    assert!(hits >= 19, "Q blamed on {hits} of 20: {other:?}");
}

/// The text table shows the gated mean under its name and the mean over every update
/// beside it, and the gate line says what "gated" means. A channel with glitches (10 at
/// 50σ among 2000 updates) has the two far apart: gated near 1, all near 1 + 10·2500/2000.
#[test]
fn issue23_the_table_shows_the_gated_mean_and_the_mean_over_every_update() {
    let dir = tempfile::tempdir().unwrap();
    let mut text = format!(
        "{HEADER}{}",
        ar1_channel("gps", 2000, 0.0, 0.0, 1.0, 23_600)
    );
    for k in 0..10 {
        let _ = writeln!(text, "{},gps,50,1", 400.0 + k as f64 * 0.01);
    }
    let p = write(dir.path(), "glitch.csv", &text);
    let (_, v) = nis_json(&[p.to_str().unwrap()]);
    let s = sensor(&v, "gps");
    let all = s["nis_mean_all"].as_f64().unwrap();
    assert!(all > 10.0, "{all}");
    let (_, out, _) = autotune(&["nis", p.to_str().unwrap()]);
    let header = out.lines().find(|l| l.starts_with("sensor")).unwrap();
    assert!(
        header.contains("NIS gated") && header.contains("NIS all"),
        "{header}"
    );
    assert!(out.contains("NIS gated: the average without them"), "{out}");
    let row = out.lines().find(|l| l.starts_with("gps ")).unwrap();
    assert!(row.contains(&format!("{:.4}", all)[..4]), "{row} vs {all}");
}

/// Time stamps: a channel whose times are all 0 (the LPE-published `ekf2_innovations` of
/// the issue), one whose times are all one value, and one whose clock jumps back, each give
/// one warning line in the JSON and on the summary; a channel with increasing times gives
/// none.
#[test]
fn issue23_time_stamps_that_stand_still_or_go_back_are_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::from(HEADER);
    for k in 0..212 {
        let _ = writeln!(text, "0,hagl,{},1", (k % 7) as f64 / 7.0 - 0.4);
        let _ = writeln!(text, "5.5,mag,{},1", (k % 5) as f64 / 5.0 - 0.4);
        // Five updates at the time of the one before (the reader refuses a time going
        // back in a CSV log; a PX4 log's reader may pass one on).
        let t = if (100..105).contains(&k) { 99 } else { k };
        let _ = writeln!(text, "{t},baro,{},1", (k % 3) as f64 / 3.0 - 0.3);
        let _ = writeln!(text, "{k},gps,{},1", (k % 3) as f64 / 3.0 - 0.3);
    }
    let p = write(dir.path(), "times.csv", &text);
    let (_, v) = nis_json(&[p.to_str().unwrap()]);
    let warnings: Vec<&str> = v["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_str().unwrap())
        .collect();
    assert_eq!(
        warnings,
        [
            "hagl: all 212 updates have time 0: the time axis and time windows are meaningless",
            "mag: all 212 updates have time 5.500: the time axis and time windows are meaningless",
            "baro: 5 of 212 updates do not come after the one before (equal or earlier time): the time axis and time windows are unreliable",
        ]
    );
    let (_, out, _) = autotune(&["nis", p.to_str().unwrap()]);
    assert!(
        out.contains("warning: hagl: all 212 updates have time 0"),
        "{out}"
    );
}

/// A moving window of 10 s over a clock that jumps back 50 s (a reader handing the
/// analyzer such a sequence: the CSV reader refuses it): the window starts afresh at the
/// jump instead of holding every update since (the last window then has about 11 updates,
/// 1 s apart, and its upper bound χ²⁻¹(0.975, 11)/11 ≈ 2.0; a window reaching back over the
/// jump holds about 60 and bounds about 1.4). Over a clock that stands still no window is
/// ever full (it spans no time) and none is reported.
#[test]
fn issue23_a_window_in_seconds_never_reaches_across_time_going_back_or_standing_still() {
    use autotune::internals::fieldlog::{NisAnalyzer, NisSettings, SensorInfo, Update, Window};
    let settings = NisSettings::default()
        .with_window(Window::Seconds(10.0))
        .unwrap();
    let mut a = NisAnalyzer::new(settings);
    let info = |name: &str| SensorInfo {
        name: name.into(),
        components: vec![name.into()],
        group: String::new(),
    };
    let baro = a.sensor(info("baro")).unwrap();
    let hagl = a.sensor(info("hagl")).unwrap();
    let mut rng = SimRng::seed_from_u64(23_700);
    for k in 0..160 {
        let u: f64 = rng.sample(StandardNormal);
        let t = if k < 100 { k } else { k - 50 } as f64;
        for (i, time) in [(baro, t), (hagl, 0.0)] {
            let up = Update {
                time,
                nis: u * u,
                dof: 1,
                u: Some(vec![u]),
                sd: None,
            };
            a.push(i, up).unwrap();
        }
    }
    let r = a.report();
    let (_, _, upper) = r.sensors[0].window.last.unwrap();
    assert!(
        upper > 1.8,
        "the last window reaches back over the jump: {upper}"
    );
    assert_eq!(r.sensors[1].window.windows, 0);
    // The jump back and the clock standing still are warned about.
    assert_eq!(
        r.warnings,
        [
            "baro: 1 of 160 updates do not come after the one before (equal or earlier time): the time axis and time windows are unreliable",
            "hagl: all 160 updates have time 0: the time axis and time windows are meaningless",
        ]
    );
}

/// Three sensors of one estimator whose white innovations are all √2 too large (NIS ≈ 2):
/// every sensor off the same way, and nothing in the correlations to say whether Q or every
/// R is too small. The advice says the data cannot tell (Q and R together), where it used to
/// blame Q. The pooled lag-1 correlation of white innovations leaves its 95% band on about
/// 1 seed in 20; at least 17 of 20 seeds must say "cannot tell" (Bin(20, 0.05) ≥ 4 has
/// probability 0.016), and none may name R alone.
#[test]
fn issue23_every_sensor_off_with_white_innovations_cannot_tell_q_from_r() {
    let dir = tempfile::tempdir().unwrap();
    let mut cannot_tell = 0;
    for seed in 0..20u64 {
        let mut text = String::from(HEADER);
        for (i, name) in ["gps", "baro", "mag"].iter().enumerate() {
            text.push_str(&ar1_channel(
                name,
                2000,
                0.0,
                0.0,
                2f64.sqrt(),
                23_800 + 10 * seed + i as u64,
            ));
        }
        let p = write(dir.path(), &format!("scale{seed}.csv"), &text);
        let (code, v) = nis_json(&[p.to_str().unwrap()]);
        assert_eq!(code, 1);
        let action = sensor(&v, "gps")["finding"]["action"]
            .as_str()
            .unwrap()
            .to_string();
        if v["suspect"] == "q_and_r" {
            assert!(
                action.contains("the data cannot tell which"),
                "seed {seed}: {action}"
            );
            cannot_tell += 1;
        }
        assert_ne!(v["suspect"], "r", "seed {seed}: {action}");
    }
    eprintln!("cannot tell Q from R on {cannot_tell} of 20 seeds");
    assert!(
        cannot_tell >= 17,
        "cannot tell on {cannot_tell} of 20 seeds"
    );
}
