//! Judging a filter at θ: an experiment's Monte Carlo sums put through the gate. `autotune
//! check`, the tuner's refinement and confirmation, and the explanations all judge through
//! [`judge`], so a filter passes the same tests wherever it is judged.

use crate::experiment::{Experiment, ExperimentError, RunOptions};
use crate::montecarlo::McConfig;
use crate::stats::{Accumulator, ConsistencyReport};

/// The gate applied to `sums`, the Monte Carlo sums of `experiment`'s filter under `mc`:
/// the full consistency report (time averages, components, whiteness, zero-mean tests and
/// the verdict at `mc`'s α). `use_nees = false` judges by NIS alone (no trusted ground
/// truth).
pub fn judge(
    experiment: &dyn Experiment,
    sums: &Accumulator,
    mc: &McConfig,
    use_nees: bool,
) -> ConsistencyReport {
    ConsistencyReport::from_accumulator(
        sums,
        &mc.gate_spec(use_nees),
        experiment.state_names(),
        experiment.measurement_names(),
    )
}

/// Check `experiment`'s filter at parameter values `theta` under `mc`: its Monte Carlo run
/// and [`judge`]d. Fails only when the experiment cannot run (see
/// [`Experiment::monte_carlo_with`]).
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
    let sums = experiment.monte_carlo_with(theta, mc, options)?;
    Ok(judge(experiment, &sums, mc, use_nees))
}

/// Told how a check's Monte Carlo goes: the command line draws a progress bar.
pub trait CheckProgress: Sync {
    /// The run is about to start: `runs` × `steps`, on the linear fast path or not (which
    /// steps about 100 times faster).
    fn start(&self, _runs: usize, _steps: usize, _fast_path: bool) {}
    /// `done` runs have finished.
    fn runs_done(&self, _done: usize) {}
    /// The run is over (finished or failed).
    fn finish(&self) {}
}

/// No progress reports.
impl CheckProgress for () {}

/// The Monte Carlo sums of `experiment`'s filter at `theta` on the `engine` path.
pub fn accumulate(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    engine: crate::montecarlo::Engine,
) -> Result<Accumulator, ExperimentError> {
    experiment.monte_carlo_with(
        theta,
        mc,
        RunOptions {
            engine,
            progress: None,
            share: None,
        },
    )
}
