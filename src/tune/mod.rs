//! The tuner: searches an experiment's free noise parameters for the filter whose
//! consistency statistics sit at their targets, then confirms the winner on fresh Monte
//! Carlo seeds.
//!
//! The method, one file per step:
//! - `cost`: the search space is the logarithm of each free parameter inside its bounds,
//!   and a candidate scores [`Objective`] J ([`objective`]) on either the exact
//!   expected statistics (linear problems whose filter has the truth's F and H: noise-free
//!   and cheap) or a Monte Carlo run with common random numbers (every candidate sees the
//!   same draws, so the score is a deterministic function of the parameters).
//! - `budget`: every evaluation goes through one wrapper that counts it against a budget
//!   in evaluations and seconds, books the best point, the history and the diverged
//!   candidates, and tells the [`Observer`]. A candidate whose filter diverges scores +∞
//!   and the search goes on.
//! - `global`: a Latin hypercube of quasi-random points in the log box, and the choice of
//!   the best few mutually distinct points as local starts.
//! - `local`, `simplex`, `levenberg_marquardt`: a local search from each start
//!   ([`LocalSearch`]): Nelder–Mead (argmin), each restarted once to polish, or
//!   Levenberg–Marquardt on J's residuals, first on each parameter's own components (the
//!   moment equations) and then on the whole objective.
//! - `separable`: where the experiment names decoupled blocks, each block's free
//!   parameters searched on that block's own statistics (a correct axis is never moved to
//!   compensate a wrong one); and a parameter that ends on a search bound after a converged
//!   search gets that bound widened once (log space) and one more local search.
//! - `refine`: after the search, the gate's own deviates (`check::judge` at θ) and their
//!   sensitivity to the parameters, Levenberg–Marquardt steps on them over more runs
//!   (Monte Carlo scoring), the confirmation on fresh seeds, and the resolution: how
//!   precisely the gate's data pin each parameter down (a sandwich covariance of the
//!   deviates over the confirmation seeds).
//! - `stages`: [`tune`] itself, stage by stage: set up, search, widen, refine, confirm,
//!   resolve, and the status.
//! - `settings` and `spec`: the validated [`TuneSettings`], and [`TuneSpec`], the same
//!   settings as a problem file's `[tune]` and the command line's flags give them.
//!
//! Under exact scoring the candidates of the global stage and the local starts run in
//! parallel; their evaluations are booked in point and start order, so the result and its
//! history do not depend on the thread count.

mod budget;
pub mod certify;
mod cost;
mod global;
mod levenberg_marquardt;
mod local;
pub mod objective;
mod refine;
mod result;
mod separable;
mod settings;
mod simplex;
mod spec;
mod stages;
#[cfg(test)]
pub(crate) mod tests;

pub use certify::{Certificate, CertifiedStart};
pub use objective::{Objective, Terms, Weights};
pub use refine::{Confirmation, band_low, seed_at};
pub use result::{Observer, Resolution, Silent, TuneResult, TuneStatus, Widening};
pub use settings::{LocalSearch, Plan, Scoring, TuneSettings};
pub use spec::TuneSpec;

use self::cost::Cost;
use self::stages::Tuning;
use crate::experiment::{Experiment, ExperimentError};
use crate::input::SettingError;
use crate::montecarlo::McConfig;

/// Errors that stop a tuning run before it starts.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TuneError {
    /// A setting does not suit this experiment.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// The start or the fixed flags do not match the parameters.
    #[error("{start} start values and {fixed} fixed flags for {params} parameters")]
    Shape {
        /// Start values given.
        start: usize,
        /// Fixed flags given.
        fixed: usize,
        /// Parameters of the experiment.
        params: usize,
    },
    /// The experiment itself failed (an external worker broke the protocol).
    #[error(transparent)]
    Experiment(#[from] ExperimentError),
}

/// The seed of the confirmation runs when none is given: a fixed mix of the search seed,
/// never equal to it.
pub fn default_confirm_seed(seed: u64) -> u64 {
    // Flipping bits 0 and 40 changes the seed and keeps it below 2^63 when it was (TOML
    // files store seeds as signed 64-bit integers).
    seed ^ 0x0000_0100_0000_0001
}

/// Whether the search scores exactly: asked for, or chosen by `Auto` where the experiment
/// has exact sums.
fn exact_scoring(
    model: &dyn Experiment,
    start: &[f64],
    mc: &McConfig,
    scoring: Scoring,
) -> Result<bool, TuneError> {
    let probe = McConfig::new(1, 1)?.with_seed(mc.seed());
    let available = model.expected(start, &probe).is_some();
    match scoring {
        Scoring::Auto => Ok(available),
        Scoring::Exact if !available => Err(SettingError::new(
            "scoring",
            "exact scoring needs a linear problem (its truth's and filter's matrices)",
        )
        .into()),
        Scoring::Exact => Ok(true),
        Scoring::MonteCarlo => Ok(false),
    }
}

/// Tune `model` from parameter values `start`, holding the parameters marked in `fixed`,
/// with the Monte Carlo test `mc` (the confirmation's; the search may use more runs).
pub fn tune(
    model: &dyn Experiment,
    start: &[f64],
    fixed: &[bool],
    mc: &McConfig,
    settings: &TuneSettings,
    observer: &dyn Observer,
) -> Result<TuneResult, TuneError> {
    let mut run = Tuning::set_up(model, start, fixed, mc, settings, observer)?;
    let mut found = run.search(observer);
    run.widen(&mut found, observer);
    run.failed()?;
    let refined = run.refine(&found, observer);
    let confirmed = run.confirm(&refined, observer);
    let resolution = run.resolution(&found, &refined, &confirmed);
    let supported = run.supported(&confirmed);
    run.failed()?;
    let result = run.result(found, refined, confirmed, resolution, supported);
    // One record is one deterministic test: restarts would search the same data again.
    if settings.certify() && !model.seed_free() && certify::needed(&result) {
        observer.phase("certify");
        return certify::certify(model, fixed, mc, settings, result);
    }
    Ok(result)
}

/// Per parameter (problem order), whether `theta`'s value lies within 0.05 log units (5%)
/// of a bound of `cost`'s box; false for fixed parameters.
fn bound_flags(cost: &Cost<'_>, theta: &[f64], fixed: &[bool]) -> Vec<bool> {
    let y: Vec<f64> = cost.free().iter().map(|&i| theta[i].ln()).collect();
    let mut flags = vec![false; fixed.len()];
    for (k, &i) in cost.free().iter().enumerate() {
        flags[i] = y[k].is_finite() && cost.near_bound(k, &y);
    }
    flags
}
