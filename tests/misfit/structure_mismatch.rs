//! A filter whose model lacks what the truth has fails the default gate even at its best
//! noise values (issue 11: the held-out structure-mismatch cases).
//!
//! Two truths carry an acceleration that a nearly-constant-velocity filter (white-noise
//! acceleration, free `q_accel` and `r_pos`) omits, written with `filter.map`:
//! `tests/data/singer_vs_cv.toml` (first-order Gauss–Markov acceleration, τ = 20 s,
//! σ_a = 1 m/s²) and `tests/data/ca_vs_cv.toml` (white jerk, 0.01 m²/s⁵). No (q_accel,
//! r_pos) makes either consistent: at the tuner's best point the position error is larger
//! than P says, the velocity error smaller, and the innovations are correlated in time.
//!
//! Measured (tuned from the files' start, default settings; 100 seeds 1000–1099 of the
//! files' 100 runs × 200 steps): the full gate fails 100 of 100 for both files; the textbook
//! mean-only gate (ANEES and ANIS) 100 and 98. At the best points, singer_vs_cv reads
//! pos e²/P ≈ 1.35, vel e²/P ≈ 0.65, ν²/S ≈ 0.97, ρ₁ ≈ −0.16; ca_vs_cv 1.37, 0.65, 0.93, −0.21.

use std::path::{Path, PathBuf};

use autotune::internals::check::check;
use autotune::internals::experiment::Experiment;
use autotune::internals::problem::Problem;
use autotune::internals::stats::{GateMode, Verdict};
use autotune::internals::tune::{Silent, TuneSettings, TuneStatus, tune};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// Gate failures over 100 fresh seeds at the tuned point of `file`, and the tuned values.
fn failures_at_best_point(file: &str) -> (usize, Vec<f64>) {
    let p = Problem::load(&data(file)).unwrap();
    assert_eq!(p.mc().gate(), GateMode::Full, "the default gate");
    let start = p.params().values();
    let fixed = vec![false; start.len()];
    // No wall-time limit a test machine reaches (as in explain.rs).
    let settings = TuneSettings::default().with_max_seconds(3600.0).unwrap();
    let r = tune(&p, &start, &fixed, p.mc(), &settings, &Silent).unwrap();
    // The tuner itself finds no consistent value (its own confirmation on 20 seeds).
    assert_eq!(r.status, TuneStatus::Inconsistent, "{file}: {:?}", r.tuned);
    // And says so plainly (issue 11, item 3): no consistent value, what stays off, and a
    // richer model, not a confident number or "increase Q"; the richer model is the first
    // explanation, and its trial (a Gauss–Markov acceleration fitted) fits (issue 38).
    let explanations = autotune::internals::explain::explain(&p, &r, p.mc(), &settings).unwrap();
    assert_eq!(
        explanations.first().map(|e| (e.cause, e.fits())),
        Some((
            autotune::internals::explain::Cause::Model(
                autotune::internals::experiment::Hypothesis::MotionState
            ),
            true
        )),
        "{file}: {:#?}",
        explanations.iter().map(|e| e.line()).collect::<Vec<_>>()
    );
    let finding = autotune::report::advice::family_finding(&r, &explanations)
        .expect("an inconsistent family is reported")
        .join("\n");
    assert!(
        finding.contains("no value of the free parameters"),
        "{finding}"
    );
    assert!(finding.contains("components that stay off"), "{finding}");
    assert!(finding.contains("add the state the truth has"), "{finding}");
    let recs = autotune::report::advice::recommendations(&p, &r, &r.before);
    for rec in &recs {
        assert!(!rec.advice.contains("not identifiable"), "{}", rec.advice);
        assert!(
            rec.fixed || rec.advice.contains("no value of the free parameters"),
            "{}",
            rec.advice
        );
    }
    let mut failed = 0;
    for seed in 1000..1100 {
        let mc = p.mc().with_seed(seed);
        let report = check(&p, &r.tuned, &mc, autotune::Truth::Known).unwrap();
        assert_eq!(report.diverged_runs, 0, "{file} seed {seed}");
        if report.verdict != Verdict::Consistent {
            failed += 1;
        }
    }
    (failed, r.tuned)
}

#[test]
fn the_default_gate_fails_a_cv_filter_on_a_singer_target_at_its_best_noise() {
    // At least 95 of 100 seeds: a gate whose power here were 0.99 would fail this with
    // probability 6e-4 (binomial); measured 100 of 100.
    let (failed, tuned) = failures_at_best_point("singer_vs_cv.toml");
    assert!(failed >= 95, "failed {failed} of 100 at {tuned:?}");
}

#[test]
fn the_default_gate_fails_a_cv_filter_on_a_white_jerk_target_at_its_best_noise() {
    // As above; measured 100 of 100.
    let (failed, tuned) = failures_at_best_point("ca_vs_cv.toml");
    assert!(failed >= 95, "failed {failed} of 100 at {tuned:?}");
}
