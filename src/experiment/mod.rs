//! The seam every consistency check and tuning run goes through: an [`Experiment`] gives the
//! Monte Carlo sums of a filter family at parameter values θ, with the names, parameters and
//! targets that the statistics, the tuner and the reports need.
//!
//! Every source of a filter to judge is one implementation:
//! - a problem file's linear `[truth]`/`[filter]` ([`LinearExperiment`]) or catalog `[model]`
//!   ([`CatalogExperiment`]), both built by [`crate::problem::Problem`];
//! - a Rust user's own truth model and filter ([`RustModel`], built with [`RustModel::builder`]);
//! - records another program wrote ([`RecordsExperiment`]);
//! - a worker program in another language ([`crate::external::ExternalExperiment`]).
//!
//! [`crate::check`], [`crate::tune`], [`crate::report`] and [`crate::app`] take
//! `&dyn Experiment` and nothing more concrete.

mod catalog;
mod definition;
mod described;
mod error;
mod held;
mod hypotheses;
mod linear;
mod rebounded;
mod recorded;
mod rust_model;

pub use catalog::CatalogExperiment;
pub use definition::{Block, Covariances, Definition, Info, Source, TruthReuse};
pub use error::{
    Ended, ExperimentError, RequestInfo, SeedContractViolation, StartFailure, Uncontained,
    WorkerError, WorkerFailure, WorkerRole,
};
pub use hypotheses::{Added, Changed, Hypothesis, Hypothesized, ReadThrough};
#[cfg(test)]
pub(crate) use linear::cv1d_for_tests;
pub use linear::{FilterModel, LinearExperiment, LinearModelBuilder};
pub use rebounded::Rebounded;
pub use recorded::RecordsExperiment;
pub use rust_model::{RustModel, RustModelBuilder};

pub use crate::montecarlo::RunOptions;
use crate::montecarlo::{Engine, McConfig};
use crate::params::{ParamSpace, Target};
use crate::stats::Accumulator;

/// A filter family and the truth it is tested against, seen through what the statistics
/// need: named parameters θ, component names, and the Monte Carlo sums at θ.
///
/// An implementation writes two methods, [`Experiment::definition`] and
/// [`Experiment::monte_carlo_with`]; the rest of this trait reads the definition. What an
/// experiment can offer beyond its sums it opts into through three capability traits, each
/// with a default for every method (an experiment that offers none writes
/// `impl Structure for X {}`, `impl HeldAsCode for X {}` and `impl Sampling for X {}`):
/// - [`Structure`]: what autotune may know of the model (each parameter's target, Q and R at
///   θ, decoupled blocks, the truth's values, exact expected sums, the linear form);
/// - [`HeldAsCode`]: the filter and the truth as code (a replay over a recording, a record
///   drawn from the truth, readings corrected on their way to the filter);
/// - [`Sampling`]: how the sums are drawn (seed-free recorded sums, shares of chunks, truth
///   reused between evaluations).
///
/// Implementations must honour the engine's reproducibility contract: the same θ, settings
/// and seed give the same sums on any number of threads (common random numbers: the tuner
/// evaluates every candidate on the same seed).
pub trait Experiment: Sync + Structure + HeldAsCode + Sampling {
    /// Name, source, parameters, component names and Monte Carlo test.
    fn definition(&self) -> &Definition;

    /// Name, description and source.
    fn info(&self) -> &Info {
        &self.definition().info
    }

    /// The named parameters: values are the configured filter (the tuner's start), bounds
    /// the search box.
    fn params(&self) -> &ParamSpace {
        &self.definition().params
    }

    /// State component names, n_x.
    fn state_names(&self) -> &[String] {
        &self.definition().state_names
    }

    /// Measurement component names, all sensors' components in sensor order.
    fn measurement_names(&self) -> &[String] {
        &self.definition().measurement_names
    }

    /// The experiment's own Monte Carlo test.
    fn mc(&self) -> &McConfig {
        &self.definition().mc
    }

    /// The Monte Carlo sums of the filter with parameters `theta` (one value per parameter,
    /// in [`Experiment::params`] order) against the truth, under `mc`. Fails only when the
    /// experiment cannot run at all (an external worker broke the protocol); the built-in
    /// experiments never fail.
    ///
    /// With a share in `options` ([`RunOptions::share`]), only that share's chunks are
    /// computed and each chunk's sums go to its sink; an experiment that cannot split its
    /// evaluation ([`Sampling::splits`] is false) may ignore the share.
    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError>;

    /// [`Experiment::monte_carlo_with`] on the fastest valid path, without progress.
    fn monte_carlo(&self, theta: &[f64], mc: &McConfig) -> Result<Accumulator, ExperimentError> {
        self.monte_carlo_with(theta, mc, RunOptions::default())
    }
}

/// What autotune may know of an experiment's model beyond its sums ([`Experiment`]'s first
/// capability): the defaults know nothing.
pub trait Structure {
    /// Whether the experiment can run on `engine` (all can run [`Engine::Auto`] and
    /// [`Engine::Generic`]; only linear problems have the linear fast path).
    fn supports(&self, engine: Engine) -> bool {
        engine != Engine::Linear
    }

    /// The exact expected sums, where the model allows computing them in closed form (a
    /// filter whose covariance stops being positive definite gives sums marked diverged);
    /// `None` when it does not.
    fn expected(&self, _theta: &[f64], _mc: &McConfig) -> Option<Accumulator> {
        None
    }

    /// What parameter `i` drives (process or measurement noise, and which components); the
    /// advice reads those components' statistics and the Gauss–Newton search matches them
    /// first. `None` when unknown.
    fn target(&self, _i: usize) -> Option<Target> {
        None
    }

    /// The filter's Q and R at `theta`, where they are single matrices (linear filters).
    fn covariances(&self, _theta: &[f64]) -> Option<Covariances> {
        None
    }

    /// The experiment's decoupled blocks, where its structure is known and there are at
    /// least two; `None` when it is one block or unknown (the default).
    fn blocks(&self) -> Option<Vec<Block>> {
        None
    }

    /// The parameter values equal to the truth's noise, where the experiment knows them.
    fn truth_values(&self) -> Option<Vec<f64>> {
        None
    }

    /// The linear-Gaussian truth and Kalman filter this experiment is, where it is one: what
    /// estimating Q and R from recorded measurements alone needs (the likelihood and ALS
    /// work on the filter's matrices). `None`, the default, for every other experiment.
    fn linear(&self) -> Option<&LinearExperiment> {
        None
    }
}

/// An experiment's filter and truth as code ([`Experiment`]'s second capability): the
/// defaults hold neither (a worker's, a records file's).
pub trait HeldAsCode {
    /// The filter at `theta` as code, for a replay over recorded measurements
    /// ([`crate::estimate::FilterReplay`]: `check` and `tune` with `--measurements`, the
    /// likelihood of a record). `None`, the default, where autotune does not hold the filter
    /// (a worker's, a records file's).
    fn replay_filter(&self, _theta: &[f64]) -> Option<Box<dyn crate::filter::Filter + '_>> {
        None
    }

    /// The truth model as code, for drawing a record from it (`autotune simulate`). `None`,
    /// the default, where autotune does not hold the truth (a worker's, a records file's).
    fn simulation_truth(&self) -> Option<&dyn crate::model::TruthModel> {
        None
    }

    /// [`Experiment::monte_carlo_with`] with the filter reading every measurement through
    /// `correction`, where autotune feeds the filter its readings (catalog and Rust-model
    /// filters): what the sensor-side hypotheses of [`crate::explain`] change on a filter
    /// held as code. `None`, the default, where it does not (a worker's filter reads its
    /// own; a linear problem's hypotheses change its matrices instead).
    fn monte_carlo_corrected(
        &self,
        _theta: &[f64],
        _mc: &McConfig,
        _options: RunOptions<'_>,
        _correction: &crate::filter::Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        None
    }

    /// Each measurement component's innovation standard deviation at `theta` over one
    /// run of `mc` (in the component's units; [`crate::montecarlo::innovation_scales`]),
    /// where [`HeldAsCode::monte_carlo_corrected`] is offered; `None` otherwise.
    fn innovation_scales(&self, _theta: &[f64], _mc: &McConfig) -> Option<Vec<f64>> {
        None
    }
}

/// How an experiment's sums are drawn ([`Experiment`]'s third capability): the defaults
/// simulate every evaluation afresh, seed by seed, in shares of chunks.
pub trait Sampling {
    /// Whether an evaluation splits into shares of its chunks ([`RunOptions::share`]), which
    /// the shards and the MPI ranks compute apart: true for every simulated experiment, false
    /// for sums that were recorded whole.
    fn splits(&self) -> bool {
        !self.seed_free()
    }

    /// Whether an evaluation also splits into shares of every chunk's runs
    /// ([`crate::montecarlo::Share::runs`]): true where the engine sums a chunk run after
    /// run (the generic engine of a model held as code), so that each run's own sums added
    /// in run order are the chunk's sums bit for bit. False, the default, where a chunk is
    /// summed otherwise (the linear fast path sums each step over a batch of runs; a worker
    /// answers a chunk's sums).
    fn splits_runs(&self) -> bool {
        false
    }

    /// Whether the sums are the same for every seed: a filter run over one recorded data
    /// set rather than a simulation. The tuner then confirms on that record once instead of
    /// on fresh seeds, and reports no seed-to-seed resolution (it would be zero).
    fn seed_free(&self) -> bool {
        false
    }

    /// Where the truth of an evaluation has come from since `since` (a usage read before
    /// the evaluations of interest, from [`Sampling::tape_usage`]). The default: the
    /// experiment simulates its own truth at every evaluation.
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> TruthReuse {
        TruthReuse::Simulated {
            why: "the experiment simulates its own truth".to_string(),
        }
    }

    /// The truth cache's usage now, for [`Sampling::truth_reuse`]; the default (no
    /// cache) is empty.
    fn tape_usage(&self) -> crate::montecarlo::TapeUsage {
        crate::montecarlo::TapeUsage::default()
    }
}
