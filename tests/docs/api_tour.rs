//! The guide's Rust API chapter (docs/src/api.md) shows its examples from this file, between
//! `ANCHOR:` marks (mdBook's `{{#include file:anchor}}`), so that each compiles against the
//! public API and runs here: nothing below reaches the crate's hidden internals module.

use std::path::Path;

use autotune::prelude::*;
use autotune::{
    Accumulator, Definition, ExperimentError, HeldAsCode, Observer, RunOptions, Sampling,
    Structure, TuneSpec, TuneStatus,
};
use nalgebra::{DMatrix, DVector};

type Result<T = ()> = std::result::Result<T, Box<dyn std::error::Error>>;

#[test]
fn the_tour_names_no_internals() {
    let text = include_str!("api_tour.rs");
    let needle = ["autotune::", "internals"].concat();
    assert!(
        !text.contains(&needle),
        "the tour uses the public API alone"
    );
}

// ANCHOR: experiment
/// Another program's filter behind the seam: here, one whose sums are cv1d's.
struct Elsewhere(LinearExperiment);

impl Experiment for Elsewhere {
    fn definition(&self) -> &Definition {
        self.0.definition()
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> std::result::Result<Accumulator, ExperimentError> {
        self.0.monte_carlo_with(theta, mc, options)
    }
}

// No capabilities: no targets, no exact sums, no filter held as code.
impl Structure for Elsewhere {}
impl HeldAsCode for Elsewhere {}
impl Sampling for Elsewhere {}
// ANCHOR_END: experiment

#[test]
fn an_experiment_of_ones_own() -> Result {
    let model = Elsewhere(cv1d()?);
    let report = check(&model, &[0.5, 1.0], model.mc(), Truth::Known)?;
    assert!(report.verdict.passes());
    assert!(model.target(0).is_none() && model.expected(&[0.5, 1.0], model.mc()).is_none());
    Ok(())
}

#[test]
fn a_problem_file() -> Result {
    // ANCHOR: problem
    let p = Problem::load(Path::new("problems/cv1d.toml"))?;
    assert_eq!(p.params().names(), ["q_accel", "r_pos"]);
    assert_eq!(p.params().values(), [0.1, 2.0]); // the designer's guess
    assert_eq!((p.mc().runs(), p.mc().steps()), (200, 100));
    // ANCHOR_END: problem
    Ok(())
}

/// cv1d built in Rust (problems/cv1d.toml, started at x0 = 0 with P0 = I).
fn cv1d() -> Result<LinearExperiment> {
    // ANCHOR: linear
    let model = LinearExperiment::builder("cv1d")
        .transition(DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]))
        .observation(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]))
        .initial(DVector::zeros(2), DMatrix::identity(2, 2))
        .truth_noise(dwna_block(1.0) * 0.5, DMatrix::identity(1, 1))
        .process_noise(ParamDef::new("q_accel", 0.1), dwna_block(1.0))
        .measurement_noise(ParamDef::new("r_pos", 2.0), DMatrix::identity(1, 1))
        .montecarlo(McConfig::new(200, 100)?.with_seed(2))
        .build()?;
    // ANCHOR_END: linear
    Ok(model)
}

#[test]
fn a_linear_model_refused_names_its_setting() {
    // ANCHOR: refused
    let refused = LinearExperiment::builder("cv1d")
        .transition(DMatrix::identity(2, 2))
        .observation(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]))
        .initial(DVector::zeros(2), DMatrix::zeros(2, 2)) // P0 must be definite
        .truth_noise(DMatrix::identity(2, 2), DMatrix::identity(1, 1))
        .build()
        .err()
        .unwrap();
    assert_eq!(refused.setting, "initial.P0");
    // ANCHOR_END: refused
}

#[test]
fn any_model_in_rust() -> Result {
    let lin = cv1d()?;
    // ANCHOR: rust_model
    // Any truth (a `TruthModel`) and any filter family θ ↦ `Filter` (KF, EKF, UKF or your
    // own); here the linear model's own parts.
    let truth = lin.truth.clone();
    let model = RustModel::builder("cv1d_rust", truth, move |theta: &[f64]| {
        lin.filter_at(theta)
    })
    .param(ParamDef::new("q_accel", 0.1), Target::process(&[0, 1]))
    .param(ParamDef::new("r_pos", 2.0), Target::measurement(&[0]))
    .montecarlo(McConfig::new(50, 100)?)
    .build()?;
    assert_eq!(model.state_names(), ["x0", "x1"]);
    // ANCHOR_END: rust_model
    let report = check(&model, &[0.5, 1.0], model.mc(), Truth::Known)?;
    assert!(report.verdict.passes());
    Ok(())
}

#[test]
fn judging_once_and_on_several_seeds() -> Result {
    let model = cv1d()?;
    // ANCHOR: check
    let report = check(&model, &[0.1, 2.0], model.mc(), Truth::Known)?;
    assert_eq!(report.verdict, Verdict::Overconfident);
    let anees = report.nees.as_ref().map(|s| s.time_average);
    assert!(anees.unwrap() > 2.0); // the target is n_x = 2
    // Without a trusted truth (the NIS alone), as on field data:
    let nis_only = check(&model, &[0.1, 2.0], model.mc(), Truth::Unknown)?;
    assert!(nis_only.nees.is_none());
    // ANCHOR_END: check
    // ANCHOR: seeds
    let checks = check_seeds(&model, &[0.5, 1.0], model.mc(), Truth::Known, 20)?;
    assert_eq!(checks.band_low(), 16); // Bin(20, 0.95): 16 or more in 99 of 100 draws
    assert!(checks.passed() >= 16 && checks.passes());
    // ANCHOR_END: seeds
    Ok(())
}

#[test]
fn tuning() -> Result {
    let model = cv1d()?;
    // ANCHOR: tune
    let result = model
        .tuner(TuneSettings::default())
        .from(&[1.0, 1.0]) // default: the model's configured values
        .fix("r_pos")? // default: the parameters the model marks fixed
        .run(&Silent)?;
    assert_eq!(result.status, TuneStatus::Consistent);
    assert_eq!(result.tuned[1], 1.0); // held
    assert!((result.tuned[0] / 0.5 - 1.0).abs() < 0.05);
    assert!(result.confirmation.holds()); // fresh seeds agree
    // ANCHOR_END: tune
    Ok(())
}

#[test]
fn settings_validated_once() -> Result {
    // ANCHOR: settings
    // One setter at a time, each refusing a bad value at once:
    let settings = TuneSettings::default()
        .with_max_evals(300)?
        .with_starts(2)?;
    // Or the whole set as a problem file's [tune] or the flags give it, checked together:
    let spec = TuneSpec {
        max_evals: Some(300),
        starts: Some(2),
        ..TuneSpec::default()
    };
    assert_eq!(spec.apply(TuneSettings::default())?, settings);
    let refused = TuneSettings::default().with_starts(0).err().unwrap();
    assert_eq!(refused.setting, "starts");
    // ANCHOR_END: settings
    Ok(())
}

#[test]
fn watching_a_search() -> Result {
    let model = cv1d()?;
    // ANCHOR: observer
    struct Count(std::sync::atomic::AtomicUsize);
    impl Observer for Count {
        fn evaluation(&self, _evals: usize, _best: f64) {
            self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    }
    let count = Count(Default::default());
    let result = model.tuner(TuneSettings::default()).run(&count)?;
    assert!(count.0.into_inner() >= result.evaluations);
    // ANCHOR_END: observer
    Ok(())
}

#[test]
fn the_command_line_as_a_function() -> Result {
    // ANCHOR: app
    // What `autotune check problems/cv1d.toml --quiet` does, from a program: the exit code
    // is 1 (the designer's guess is inconsistent).
    let code = autotune::app::run(["autotune", "check", "problems/cv1d.toml", "--quiet"])?;
    assert_eq!(code, std::process::ExitCode::from(1));
    // ANCHOR_END: app
    Ok(())
}

#[test]
fn a_running_filter() -> Result {
    // ANCHOR: monitor
    let mut monitor = NisMonitor::new(NisSettings::default());
    for k in 0..100 {
        let nu = if k % 2 == 0 { 0.9 } else { -1.1 };
        monitor.update("gps", k as f64 * 0.1, &[nu], &[1.0])?; // ν (m values), S (m × m)
    }
    println!("{}", monitor.status());
    // ANCHOR_END: monitor
    Ok(())
}
