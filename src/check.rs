//! The consistency check: build the filter a problem describes at given parameter values,
//! run the Monte Carlo engine, and summarize.

use crate::montecarlo::{self, Accumulator};
use crate::problem::{McConfig, Problem, System};
use crate::stats::ConsistencyReport;

/// Which Monte Carlo path to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Engine {
    /// The fastest path valid for the problem (the linear fast path for linear problems,
    /// the generic one for catalog models).
    #[default]
    Auto,
    /// Precompute the data-independent covariance recursion once; batch runs (linear
    /// problems only: a catalog model runs the generic path).
    Linear,
    /// One run at a time through the [`crate::model::TruthModel`] and
    /// [`crate::filter::Filter`] traits.
    Generic,
}

/// Run the Monte Carlo sums for `problem`'s filter at parameter values `theta`.
pub fn accumulate(problem: &Problem, theta: &[f64], mc: &McConfig, engine: Engine) -> Accumulator {
    accumulate_with_progress(problem, theta, mc, engine, None)
}

/// [`accumulate`], reporting the runs completed as the engine goes.
pub fn accumulate_with_progress(
    problem: &Problem,
    theta: &[f64],
    mc: &McConfig,
    engine: Engine,
    progress: montecarlo::Progress<'_>,
) -> Accumulator {
    let settings = mc.engine();
    match &problem.system {
        System::Linear(l) => {
            let kf = l.filter_at(theta);
            match engine {
                Engine::Auto | Engine::Linear => {
                    montecarlo::run_linear_with_progress(&l.truth, &kf, &settings, progress)
                }
                Engine::Generic => {
                    montecarlo::run_generic_with_progress(&l.truth, &kf, &settings, progress)
                }
            }
        }
        // Nonlinear filters have data-dependent gains: only the generic path applies.
        System::Catalog { model, .. } => montecarlo::run_generic_with_progress(
            model.truth(),
            &model.filter(theta),
            &settings,
            progress,
        ),
    }
}

/// Check `problem`'s filter at parameter values `theta`: the full consistency report.
/// `use_nees = false` judges by NIS alone (no trusted ground truth).
pub fn check(
    problem: &Problem,
    theta: &[f64],
    mc: &McConfig,
    engine: Engine,
    use_nees: bool,
) -> ConsistencyReport {
    let acc = accumulate(problem, theta, mc, engine);
    ConsistencyReport::from_accumulator(
        &acc,
        mc.alpha,
        &problem.state_names,
        &problem.measurement_names,
        use_nees,
    )
}
