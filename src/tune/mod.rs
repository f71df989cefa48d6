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
//!   resolve, and the status; `tuner`: the [`Tuner`] a Rust user configures and runs.
//! - `settings` and `spec`: the validated [`TuneSettings`], and [`TuneSpec`], the same
//!   settings as a problem file's `[tune]` and the command line's flags give them.
//!
//! Under exact scoring the candidates of the global stage and the local starts run in
//! parallel; their evaluations are booked in point and start order, so the result and its
//! history do not depend on the thread count.

mod budget;
pub mod certify;
mod choices;
mod cost;
mod error;
mod global;
mod levenberg_marquardt;
mod local;
pub mod objective;
mod plan;
mod refine;
mod result;
mod separable;
mod settings;
mod setup;
mod simplex;
mod spec;
mod stages;
mod terms;
#[cfg(test)]
pub(crate) mod tests;
mod tuner;

pub use crate::check::band_low;
pub use crate::rng::seed_at;
pub use choices::{LocalSearch, Scoring};
pub use error::TuneError;
pub use objective::{Objective, Terms, Weights};
pub use plan::Plan;
pub use result::{
    Certificate, CertifiedStart, Confirmation, Observer, Resolution, Silent, TuneResult,
    TuneStatus, Widening,
};
pub use settings::TuneSettings;
pub use setup::default_confirm_seed;
pub use spec::TuneSpec;
pub use tuner::{Tunable, Tuner};

use crate::experiment::Experiment;
use crate::montecarlo::McConfig;

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
    let result = stages::search(model, start, fixed, mc, settings, observer)?;
    // One record is one deterministic test: restarts would search the same data again.
    if settings.certify() && !model.seed_free() && certify::needed(&result) {
        observer.phase("certify");
        return certify::certify(model, fixed, mc, settings, result);
    }
    Ok(result)
}
