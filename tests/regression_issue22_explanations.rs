//! When no Q and R fit, autotune names what is wrong (issue 22): one problem file per kind
//! of misfit under tests/data/misfit/, each tuned on 20 seeds; the first explanation must
//! name the planted cause, and where the file can express the change its trial must reach
//! consistency.
//!
//! Tolerance: at least 18 of 20 seeds (the issue's bar). A trial that reaches consistency
//! passes its confirmation (10 fresh seeds, a consistent filter passes at least 7 with 99%
//! probability), so a right explanation fails a seed with probability about 0.01, and 3 or
//! more failures in 20 have probability about 1e-3; a wrong ranking fails every seed.

use std::path::{Path, PathBuf};

use autotune::internals::experiment::Experiment;
use autotune::internals::explain::{Cause, Explanation, explain};
use autotune::internals::problem::Problem;
use autotune::internals::tune::{Silent, TuneResult, TuneStatus, tune};
use rayon::prelude::*;

fn misfit(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/misfit")
        .join(name)
}

/// Tune `file` with its own settings from its own values on the problem's seed `seed`, and
/// explain the result.
fn explained(file: &str, seed: u64) -> (Problem, TuneResult, Vec<Explanation>) {
    let p = Problem::load(&misfit(file)).unwrap();
    let mc = p.mc().with_seed(seed);
    let start = p.params().values();
    let fixed: Vec<bool> = p.params().params.iter().map(|q| q.fixed).collect();
    let r = tune(&p, &start, &fixed, &mc, &p.tune, &Silent).unwrap();
    let e = explain(&p, &r, &mc, &p.tune).unwrap();
    (p, r, e)
}

/// Over 20 seeds, how often the first explanation is `cause` with a trial that reached
/// consistency (`tried`), or with no trial (`!tried`); and the first failing seed's story.
fn first_is(file: &str, cause: Cause, tried: bool) -> (usize, String) {
    first_of(file, cause, tried, 20)
}

/// [`first_is`] over `seeds` seeds.
fn first_of(file: &str, cause: Cause, tried: bool, seeds: u64) -> (usize, String) {
    // Seeds side by side (a misfit's 50 runs are one chunk, one core); their verdicts and
    // stories in seed order.
    let judged: Vec<(bool, String)> = (0..seeds)
        .into_par_iter()
        .map(|seed| {
            let (_, r, e) = explained(file, 1000 + seed);
            // A run needs explaining when it found no consistent value, or needed a bound
            // widened.
            let ok = r.status != TuneStatus::Consistent || !r.widened.is_empty();
            let good = ok
                && e.first().is_some_and(|x| {
                    x.cause == cause
                        && if tried {
                            x.trial.as_ref().is_some_and(|t| t.consistent())
                        } else {
                            x.trial.is_none()
                        }
                });
            let story = format!(
                "seed {}: status {:?}, tuned {:?}\n{}",
                1000 + seed,
                r.status,
                r.tuned,
                e.iter().map(|x| x.line()).collect::<Vec<_>>().join("\n")
            );
            (good, story)
        })
        .collect();
    let hits = judged.iter().filter(|(good, _)| *good).count();
    let story = judged
        .into_iter()
        .find(|(good, _)| !good)
        .map(|(_, s)| s)
        .unwrap_or_default();
    eprintln!("{file}: first explanation {cause:?} on {hits} of {seeds} seeds");
    (hits, story)
}

#[test]
fn issue22_a_sensor_offset_is_named_first_and_its_offset_trial_fits() {
    let (hits, story) = first_is("sensor_offset.toml", Cause::SensorBias, true);
    assert!(hits >= 18, "{hits} of 20\n{story}");
}

#[test]
fn issue22_the_offset_trial_recovers_the_planted_offset() {
    // The truth's sensor reads 1.5 m high; the fitted offset's standard error over 50 runs ×
    // 100 steps is a few centimetres (measured 1.49–1.52 over seeds), so 0.1 m is generous
    // and still fails any fit that is not the bias.
    let (_, _, e) = explained("sensor_offset.toml", 1000);
    let t = e[0].trial.as_ref().unwrap();
    let (_, off) = t.values.iter().find(|(n, _)| n == "offset_p").unwrap();
    assert!((off - 1.5).abs() < 0.1, "{off}");
}

#[test]
fn issue22_a_half_time_step_is_named_first_and_its_time_step_trial_fits() {
    let (hits, story) = first_is("half_dt.toml", Cause::TimeStep, true);
    assert!(hits >= 18, "{hits} of 20\n{story}");
    // The trial finds the factor 2 the file planted (F was built for 0.5 s of a 1 s step).
    let (_, _, e) = explained("half_dt.toml", 1000);
    let t = e[0].trial.as_ref().unwrap();
    let (_, s) = t.values.iter().find(|(n, _)| n == "dt_scale").unwrap();
    assert!((s - 2.0).abs() < 0.1, "{s}");
}

#[test]
fn issue22_a_wrong_fixed_r_is_named_first_and_freeing_it_fits_near_the_truth() {
    let (hits, story) = first_is("fixed_r.toml", Cause::FixedParameter, true);
    assert!(hits >= 18, "{hits} of 20\n{story}");
    let (_, _, e) = explained("fixed_r.toml", 1000);
    assert_eq!(e[0].subject, "r_pos");
    let t = e[0].trial.as_ref().unwrap();
    let (_, r) = t.values.iter().find(|(n, _)| n == "r_pos").unwrap();
    // The truth is 4 m²; 50 runs × 100 steps pin r to a few percent.
    assert!((r / 4.0 - 1.0).abs() < 0.15, "{r}");
    assert!(e[0].line().contains("fixed at 16"), "{}", e[0].line());
}

#[test]
fn issue22_a_missing_acceleration_state_is_named_first_after_the_time_step_trial_fails() {
    let (hits, story) = first_is("missing_accel.toml", Cause::MissingState, false);
    assert!(hits >= 18, "{hits} of 20\n{story}");
}

#[test]
fn issue22_decoupled_axes_with_one_wrong_name_the_wrong_axis_and_a_missing_state() {
    // The x sensor's offset is drawn afresh in every run (σ = 2 m): zero-mean over runs, so
    // no constant offset fits, and the filter lacks a bias state on x alone. The y and z
    // axes are right, so the explanation must be about x only. Its cause cannot be tried
    // (no trial count to meet), and each seed costs three searches of six parameters, so 10
    // seeds: a ranking that were right with probability 0.9 would still pass 9 of 10 with
    // probability 0.74; measured 20 of 20 on seeds 1000–1019.
    let (hits, story) = first_of("decoupled_axes.toml", Cause::MissingState, false, 10);
    assert!(hits >= 9, "{hits} of 10\n{story}");
    let (_, _, e) = explained("decoupled_axes.toml", 1000);
    assert!(e[0].subject.ends_with("around x, vx"), "{}", e[0].subject);
}

#[test]
fn issue22_a_parameter_at_its_bound_is_named_first_and_widening_fits() {
    let (hits, story) = first_is("at_bound.toml", Cause::SearchBounds, true);
    assert!(hits >= 18, "{hits} of 20\n{story}");
}

#[test]
fn issue22_a_misfit_writes_a_rejected_config_that_starts_with_its_explanations() {
    use assert_cmd::cargo::CommandCargoExt;
    let dir = tempfile::tempdir().unwrap();
    let out = std::process::Command::cargo_bin("autotune")
        .unwrap()
        .current_dir(dir.path())
        .arg("tune")
        .arg(misfit("fixed_r.toml"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert!(!dir.path().join("tuned/fixed_r.toml").exists());
    let text = std::fs::read_to_string(dir.path().join("tuned/fixed_r.rejected.toml")).unwrap();
    assert!(text.starts_with("# REJECTED"), "{text}");
    // The first explanation, with its trial's result, comes before any value.
    let first = text
        .find("1. a fixed parameter that is wrong (r_pos)")
        .expect(&text);
    assert!(first < text.find("[params]").unwrap(), "{text}");
    assert!(
        stdout.contains("1. a fixed parameter that is wrong (r_pos)"),
        "{stdout}"
    );
    // Still a config `check --config` reads, to reproduce the finding.
    let check = std::process::Command::cargo_bin("autotune")
        .unwrap()
        .current_dir(dir.path())
        .arg("check")
        .arg(misfit("fixed_r.toml"))
        .arg("--config")
        .arg("tuned/fixed_r.rejected.toml")
        .output()
        .unwrap();
    assert_eq!(check.status.code(), Some(1), "{check:?}");
}

/// A problem seen through the seam without [`Experiment::alter`]: what a catalog model, a
/// Rust model or a worker looks like to the explanations.
struct Unalterable<'a>(&'a Problem);

impl Experiment for Unalterable<'_> {
    fn definition(&self) -> &autotune::internals::experiment::Definition {
        self.0.definition()
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &autotune::internals::montecarlo::McConfig,
        options: autotune::internals::experiment::RunOptions<'_>,
    ) -> Result<
        autotune::internals::stats::Accumulator,
        autotune::internals::experiment::ExperimentError,
    > {
        self.0.monte_carlo_with(theta, mc, options)
    }

    fn target(&self, i: usize) -> Option<autotune::internals::params::Target> {
        self.0.target(i)
    }
}

#[test]
fn issue22_where_the_filter_cannot_be_changed_the_explanations_say_what_to_change_untried() {
    let p = Problem::load(&misfit("half_dt.toml")).unwrap();
    let e = Unalterable(&p);
    let mc = *p.mc();
    let start = p.params().values();
    let r = tune(&e, &start, &[false, false], &mc, &p.tune, &Silent).unwrap();
    assert_eq!(r.status, TuneStatus::Inconsistent);
    let ex = explain(&e, &r, &mc, &p.tune).unwrap();
    assert!(ex.iter().all(|x| x.trial.is_none()), "{ex:#?}");
    let step = ex
        .iter()
        .find(|x| x.cause == Cause::TimeStep)
        .expect("time step");
    assert!(
        step.untried
            .as_deref()
            .unwrap()
            .contains("not one autotune can change"),
        "{step:#?}"
    );
    assert!(step.remedy.contains("time step"), "{step:#?}");
    let lines = autotune::report::check::advice::family_finding(&r, &ex)
        .unwrap()
        .join("\n");
    assert!(
        lines.contains("the data do not decide between them"),
        "{lines}"
    );
}
