//! Issue 11, item 11: numbers that mean nothing are not reported as verdicts.
//!
//! A covariance too ill-conditioned to invert (cv1d with `q_accel` far above what the
//! position measurements pin down) once gave an ANEES of 1e17 "overconfident" with a
//! zero-width interval, so the verdict was not monotone in q; an unstable truth gave NaN
//! reported as "inconclusive (too little data)", or a 127-digit ANEES "overconfident". Now
//! the first is the verdict `ill-conditioned` (exit 1: the filter as configured fails the
//! gate) and the second `truth overflow` (exit 2 with a one-line error naming the file: the
//! problem, not the filter, must change).

use crate::common;
use autotune::Structure;

use std::path::Path;

use assert_cmd::Command;
use autotune::internals::check::check_with;
use autotune::internals::experiment::{Experiment, RunOptions};
use autotune::internals::montecarlo::{Engine, McConfig};
use autotune::internals::problem::Problem;
use autotune::internals::stats::{ConsistencyReport, StopCause, Verdict};
use common::{load, problem_path};

/// `check` of `p` at `theta` with its own Monte Carlo settings on `engine`, with the truth.
fn check_on(
    p: &Problem,
    theta: &[f64],
    engine: Engine,
) -> autotune::internals::stats::ConsistencyReport {
    check_with(
        p,
        theta,
        p.mc(),
        RunOptions {
            engine,
            progress: None,
            share: None,
        },
        autotune::Truth::Known,
    )
    .unwrap()
}

/// cv1d's verdict at `q_accel = q` (r_pos as shipped) on `engine`, with `runs` runs.
fn cv1d_verdict(p: &Problem, q: f64, engine: Engine, runs: usize) -> ConsistencyReport {
    let mut theta = p.params().values();
    theta[0] = q;
    let mc = p.mc().with_runs(runs).unwrap();
    check_with(
        p,
        &theta,
        &mc,
        RunOptions {
            engine,
            progress: None,
            share: None,
        },
        autotune::Truth::Known,
    )
    .unwrap()
}

/// The exact path's report at `theta`, if the experiment has one.
fn exact_report(p: &Problem, theta: &[f64], mc: &McConfig) -> ConsistencyReport {
    let acc = p.expected(theta, mc).expect("cv1d has exact sums");
    ConsistencyReport::from_accumulator(
        &acc,
        &mc.gate_spec(true),
        p.state_names(),
        p.measurement_names(),
    )
}

#[test]
fn verdict_is_monotone_in_q_accel_from_1e0_to_1e308_on_cv1d() {
    // The truth's q_accel is 0.5 and the shipped r_pos = 2 doubles the truth's R, so every
    // q ≥ 1 is underconfident until the predicted covariance P⁻ (whose scaled condition
    // number grows like q / r) passes 1e12, and ill-conditioned from there on, whatever
    // the engine. No decade may read overconfident, consistent or inconclusive.
    let p = load("cv1d");
    let mut verdicts = Vec::new();
    for d in 0..=308 {
        let q = 10f64.powi(d);
        let r = cv1d_verdict(&p, q, Engine::Auto, 50);
        if d % 11 == 0 {
            let g = cv1d_verdict(&p, q, Engine::Generic, 50);
            assert_eq!(g.verdict, r.verdict, "generic engine at q = 1e{d}");
        }
        let mut theta = p.params().values();
        theta[0] = q;
        let e = exact_report(&p, &theta, p.mc());
        assert_eq!(e.verdict, r.verdict, "exact path at q = 1e{d}");
        verdicts.push((d, r.verdict));
    }
    let first_ill = verdicts
        .iter()
        .find(|(_, v)| *v == Verdict::IllConditioned)
        .map(|(d, _)| *d)
        .expect("some q is ill-conditioned");
    for &(d, v) in &verdicts {
        let want = if d < first_ill {
            Verdict::Underconfident
        } else {
            Verdict::IllConditioned
        };
        assert_eq!(v, want, "q_accel = 1e{d}: {verdicts:?}");
    }
    // Where the bound of 1e12 on the condition number puts the switch for r_pos = 2.
    assert!((12..=14).contains(&first_ill), "switch at 1e{first_ill}");
}

#[test]
fn an_ill_conditioned_covariance_is_its_own_verdict_and_fails_the_gate_with_exit_1() {
    let p = load("cv1d");
    let r = cv1d_verdict(&p, 1e18, Engine::Auto, 200);
    assert_eq!(r.verdict, Verdict::IllConditioned);
    assert_eq!(r.diverged_runs, r.runs);
    assert!(
        r.divergences
            .iter()
            .all(|d| d.cause == StopCause::IllConditioned)
    );

    let out = Command::cargo_bin("autotune")
        .unwrap()
        .args(["check", problem_path("cv1d").to_str().unwrap()])
        .args(["--set", "q_accel=1e18"])
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(text.contains("verdict: ill-conditioned"), "{text}");
    assert!(text.contains("P⁻ is ill-conditioned at step 1"), "{text}");
    assert!(!text.contains("overconfident"), "{text}");
    // All runs stopped: "add runs or steps" would be the wrong advice.
    assert!(!text.contains("add runs or steps"), "{text}");
}

/// cv1d with both states growing by `growth` per step (truth and filter alike).
fn unstable_cv1d(dir: &Path, growth: f64) -> std::path::PathBuf {
    let text = include_str!("../../problems/cv1d.toml");
    let edited = text
        .replacen("F = [[1.0, 1.0],", &format!("F = [[{growth}, 1.0],"), 1)
        .replacen("     [0.0, 1.0]]", &format!("     [0.0, {growth}]]"), 1);
    assert_ne!(edited, text);
    let path = dir.join("unstable.toml");
    std::fs::write(&path, edited).unwrap();
    path
}

#[test]
fn a_truth_that_outgrows_double_precision_is_a_truth_overflow_on_every_path() {
    // x_k grows like 1.5^k while the truth-matched filter's P stays bounded, so near step 64
    // the state is 1e12 standard deviations from zero and x − x̂ has lost 12 of its 16
    // digits. This once read "overconfident" with a 127-digit ANEES.
    let dir = tempfile::tempdir().unwrap();
    let path = unstable_cv1d(dir.path(), 1.5);
    let p = Problem::load(&path).unwrap();
    let theta = [0.5, 1.0];
    for engine in [Engine::Linear, Engine::Generic] {
        let r = check_on(&p, &theta, engine);
        assert_eq!(r.verdict, Verdict::TruthOverflow, "{engine:?}");
        assert_eq!(r.diverged_runs, r.runs, "{engine:?}");
        let d = &r.divergences[0];
        assert_eq!(d.cause, StopCause::TruthOverflow);
        assert!((55..=75).contains(&d.step), "{engine:?}: {d:?}");
        assert!(
            d.reason.contains("outgrew double precision"),
            "{}",
            d.reason
        );
    }
    // The exact path has no state to overflow, but it follows the truth's second moment and
    // stops where the runs do.
    let e = exact_report(&p, &theta, p.mc());
    assert_eq!(e.verdict, Verdict::TruthOverflow);
    assert!((55..=75).contains(&e.divergences[0].step), "{e:?}");

    let out = Command::cargo_bin("autotune")
        .unwrap()
        .args(["check", path.to_str().unwrap(), "--set", "q_accel=0.5"])
        .args(["--set", "r_pos=1"])
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{text}");
    assert!(text.contains("verdict: truth overflow"), "{text}");
    assert!(text.contains("the truth model is unstable"), "{text}");
    // Bad input, so also the one-line error naming the file and the section to change.
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("error: ") && err.contains("unstable.toml: truth: the truth overflowed"),
        "{err}"
    );

    // Tuning cannot help: every candidate stops, and the problem file is what must change.
    let out = Command::cargo_bin("autotune")
        .unwrap()
        .args(["tune", path.to_str().unwrap(), "--max-evals", "40"])
        .args(["--out", dir.path().join("t.toml").to_str().unwrap()])
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{text}");
    assert!(text.contains("after truth overflow"), "{text}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("truth: the truth overflowed"), "{err}");
}

#[test]
fn a_truth_state_that_overflows_to_infinity_is_a_truth_overflow_not_inconclusive() {
    // The truth carries a third state, doubling every step and seen by nobody; the filter
    // has the two states of cv1d (filter.map). At step 1024 it overflows: the NEES would
    // be NaN, once reported as "inconclusive (too little data)".
    let text = include_str!("../../problems/cv1d.toml")
        .replacen(
            "[truth]\nF = [[1.0, 1.0],\n     [0.0, 1.0]]\nH = [[1.0, 0.0]]\nx0 = [0.0, 1.0]\nP0 = [[4.0, 0.0],\n      [0.0, 1.0]]",
            "[truth]\nF = [[1.0, 1.0, 0.0],\n     [0.0, 1.0, 0.0],\n     [0.0, 0.0, 2.0]]\nH = [[1.0, 0.0, 0.0]]\nx0 = [0.0, 1.0, 1.0]\nP0 = [[4.0, 0.0, 0.0],\n      [0.0, 1.0, 0.0],\n      [0.0, 0.0, 0.0]]",
            1,
        )
        .replacen(
            "[filter]\n",
            "[filter]\nmap = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\nF = [[1.0, 1.0], [0.0, 1.0]]\nH = [[1.0, 0.0]]\nx0 = [0.0, 1.0]\nP0 = [[4.0, 0.0], [0.0, 1.0]]\n",
            1,
        )
        .replacen("steps = 100", "steps = 1100", 1);
    assert!(text.contains("[0.0, 0.0, 2.0]") && text.contains("map = "));
    let p = Problem::from_toml(&text, Path::new("overflow.toml")).unwrap();
    let theta = [0.5, 1.0];
    let mc = p.mc().with_runs(64).unwrap();
    for engine in [Engine::Linear, Engine::Generic] {
        let r = check_with(
            &p,
            &theta,
            &mc,
            RunOptions {
                engine,
                progress: None,
                share: None,
            },
            autotune::Truth::Known,
        )
        .unwrap();
        assert_eq!(r.verdict, Verdict::TruthOverflow, "{engine:?}");
        let d = &r.divergences[0];
        assert_eq!((d.cause, d.step), (StopCause::TruthOverflow, 1024), "{d:?}");
        assert!(
            d.reason.contains("the truth state overflowed"),
            "{}",
            d.reason
        );
        assert!(r.nees.as_ref().unwrap().time_average.is_finite());
    }
}

#[test]
fn a_filter_far_too_sure_of_itself_reads_overconfident_not_truth_overflow() {
    // A random walk measured with unit noise, filtered with q = r = 1e-200: P ≈ 1e-200, so
    // the estimate is 1e100 standard deviations from zero, but the error is too (its NEES
    // about 1e200). The number is large, not meaningless: this is the textbook overconfident
    // filter, and the state has not outgrown double precision relative to its error.
    let text = r#"
        dt = 1.0
        [montecarlo]
        runs = 64
        steps = 50
        seed = 3
        [truth]
        F = [[1.0]]
        H = [[1.0]]
        x0 = [0.0]
        P0 = [[1.0]]
        Q = [{ kind = "diag", indices = [0], value = 1.0 }]
        R = [{ kind = "diag", indices = [0], value = 1.0 }]
        [filter]
        Q = [{ kind = "diag", indices = [0], param = "q" }]
        R = [{ kind = "diag", indices = [0], param = "r" }]
        [params.q]
        value = 1e-200
        lower = 1e-250
        [params.r]
        value = 1e-200
        lower = 1e-250
    "#;
    let p = Problem::from_toml(text, Path::new("sure.toml")).unwrap();
    let theta = p.params().values();
    for engine in [Engine::Linear, Engine::Generic] {
        let r = check_on(&p, &theta, engine);
        assert_eq!(r.verdict, Verdict::Overconfident, "{engine:?}: {r:?}");
        assert_eq!(r.diverged_runs, 0);
    }
    assert_eq!(
        exact_report(&p, &theta, p.mc()).verdict,
        Verdict::Overconfident
    );
}
