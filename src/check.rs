//! The consistency check: run an experiment's Monte Carlo at given parameter values and
//! summarize it against the chi-square intervals.

use crate::experiment::{Experiment, ExperimentError, RunOptions};
use crate::montecarlo::McConfig;
use crate::stats::ConsistencyReport;

/// Check `experiment`'s filter at parameter values `theta` under `mc`: the full consistency
/// report. `use_nees = false` judges by NIS alone (no trusted ground truth). Fails only when
/// the experiment cannot run (see [`Experiment::monte_carlo_with`]).
pub fn check(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    use_nees: bool,
) -> Result<ConsistencyReport, ExperimentError> {
    check_with(experiment, theta, mc, RunOptions::default(), use_nees)
}

/// [`check`] on a chosen engine path, with progress.
pub fn check_with(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    options: RunOptions<'_>,
    use_nees: bool,
) -> Result<ConsistencyReport, ExperimentError> {
    let acc = experiment.monte_carlo_with(theta, mc, options)?;
    Ok(ConsistencyReport::from_accumulator(
        &acc,
        &mc.gate_spec(use_nees),
        experiment.state_names(),
        experiment.measurement_names(),
    ))
}

/// The Monte Carlo sums of `experiment`'s filter at `theta` on the `engine` path.
pub fn accumulate(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    engine: crate::montecarlo::Engine,
) -> Result<crate::stats::Accumulator, ExperimentError> {
    experiment.monte_carlo_with(
        theta,
        mc,
        RunOptions {
            engine,
            progress: None,
        },
    )
}
