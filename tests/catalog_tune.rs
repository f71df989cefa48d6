//! Tuning the catalog problems from 10× off, in each free parameter and in both directions
//! (all ×10, all ×0.1): the tuned filter passes the consistency check on fresh seeds (the
//! tuner's confirmation, on a seed the search never saw), and where the filter shares the
//! truth's noise structure every free parameter lands within 30% of the truth.
//!
//! The search here is cheaper than the shipped `[tune]` settings (N runs per evaluation
//! instead of 2–4 N, 8 global points per parameter, a capped evaluation count) to keep the
//! suite short; the shipped configs in `tuned/` come from the full settings. With common
//! random numbers the tuned value's error is the Monte Carlo estimation error of N runs,
//! a few percent for these problems (measured: ctrv +1%/+4%, orbit2d +5%/−1%), so 30% has a
//! wide margin; a tuner that stopped early or a filter whose Q did not act would miss it by
//! the start's factor of 10. The confirmation itself fails a perfect filter with
//! probability at most α = 0.05 per run (fixed seeds here, so the outcome is reproducible).

mod common;

use autotune::experiment::Experiment;
use autotune::problem::Problem;
use autotune::stats::Verdict;
use autotune::tune::{Silent, TuneResult, TuneSettings, tune};
use common::{load, truth_values};

/// Tune `p` with every free parameter started at `factor` × its truth value (fixed ones at
/// the truth).
fn tune_from(p: &Problem, factor: f64, settings: &TuneSettings) -> TuneResult {
    let truth = truth_values(p);
    let fixed: Vec<bool> = p.params().params.iter().map(|q| q.fixed).collect();
    let start: Vec<f64> = truth
        .iter()
        .zip(&fixed)
        .map(|(&v, &f)| if f { v } else { v * factor })
        .collect();
    let r = tune(p, &start, &fixed, p.mc(), settings, &Silent).unwrap();
    eprintln!(
        "{} from x{factor}: {:?}, {} evals in {:.1} s, tuned {:?}, truth {:?}",
        p.name(),
        r.status,
        r.evaluations,
        r.seconds,
        r.tuned,
        truth
    );
    r
}

fn quick() -> TuneSettings {
    TuneSettings::default()
        .with_global_points(8)
        .and_then(|s| s.with_max_evals(120))
        .and_then(|s| s.with_max_seconds(600.0))
        .unwrap()
}

fn assert_recovers(name: &str, settings: &TuneSettings) {
    assert_recovers_from(name, settings, &[10.0, 0.1]);
}

fn assert_recovers_from(name: &str, settings: &TuneSettings, factors: &[f64]) {
    let p = load(name);
    let truth = truth_values(&p);
    let settings = settings
        .clone()
        .with_search_runs(settings.search_runs().unwrap_or(p.mc().runs()))
        .unwrap();
    for &factor in factors {
        let r = tune_from(&p, factor, &settings);
        assert_eq!(
            r.after.verdict,
            Verdict::Consistent,
            "{name} from x{factor}: confirmation on fresh seeds: {:?}",
            r.after.verdict
        );
        assert_ne!(r.confirm_seed, p.mc().seed());
        for (i, q) in p.params().params.iter().enumerate() {
            let ratio = r.tuned[i] / truth[i];
            assert!(
                (ratio - 1.0).abs() <= 0.3,
                "{name} from x{factor}: {} tuned {:e}, truth {:e}",
                q.name,
                r.tuned[i],
                truth[i]
            );
        }
    }
}

#[test]
fn ctrv_tunes_from_ten_times_off_both_ways() {
    assert_recovers("ctrv", &quick());
}

#[test]
fn orbit2d_tunes_from_ten_times_off_both_ways() {
    assert_recovers("orbit2d", &quick());
}

#[test]
fn ins_gnss_tunes_from_a_tenth() {
    // Six free parameters of a 15-state filter, about 1 s an evaluation: the shipped [tune]
    // settings (Gauss–Newton from the start, 12 global points, 2 N search runs), from all
    // ×0.1. The other direction, all ×10, is the shipped problem's own start: its result is
    // tuned/ins_gnss.toml, checked by `shipped_tuned_configs_land_within_30_percent` here
    // and `shipped_tuned_configs_pass_check` (tests/cli_tune.rs); one direction here keeps
    // the suite short. With N search runs instead of 2 N the tuned values land within 17%
    // but the confirmation fails (ANEES just under its interval): the estimate's noise.
    let p = load("ins_gnss");
    let settings = p.tune.clone();
    assert_eq!(settings.local(), autotune::tune::LocalSearch::GaussNewton);
    assert_recovers_from("ins_gnss", &settings, &[0.1]);
}
