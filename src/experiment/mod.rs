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
mod error;
mod hypotheses;
mod linear;
mod rebounded;
mod recorded;
mod rust_model;

pub use catalog::CatalogExperiment;
pub use error::{
    Ended, ExperimentError, RequestInfo, SeedContractViolation, StartFailure, Uncontained,
    WorkerError, WorkerFailure, WorkerRole,
};
pub use hypotheses::{Added, Changed, Hypothesis, Hypothesized, ReadThrough};
pub use linear::{FilterModel, LinearExperiment};
pub use rebounded::Rebounded;
pub use recorded::RecordsExperiment;
pub use rust_model::{RustModel, RustModelBuilder};

use std::path::PathBuf;

use nalgebra::DMatrix;

pub use crate::montecarlo::RunOptions;
use crate::montecarlo::{Engine, McConfig};
use crate::params::{ParamSpace, Target};
use crate::stats::Accumulator;

/// Where an experiment was defined, for reports and provenance.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// A problem file and the SHA-256 of its bytes (hex).
    File {
        /// The file as given.
        path: PathBuf,
        /// SHA-256 of its bytes, lowercase hex.
        sha256: String,
    },
    /// A Rust program that defines the model in code.
    Program {
        /// The program's name, as it is run (`cargo run --example custom_model`: `custom_model`).
        name: String,
    },
    /// Records of a Monte Carlo experiment that another program ran and wrote.
    Records {
        /// The records files, as given.
        files: Vec<PathBuf>,
    },
}

impl Source {
    /// How reports name the source: the file's path, or `<program> (Rust model)`.
    pub fn label(&self) -> String {
        match self {
            Source::File { path, .. } => path.display().to_string(),
            Source::Program { name } => format!("{name} (Rust model)"),
            Source::Records { files } => format!("records {}", join_paths(files)),
        }
    }

    /// The SHA-256 of the defining file, if the experiment comes from one.
    pub fn sha256(&self) -> Option<&str> {
        match self {
            Source::File { sha256, .. } => Some(sha256),
            Source::Program { .. } | Source::Records { .. } => None,
        }
    }

    /// The command that checks this experiment (a tuned config goes after `--config`).
    pub fn check_command(&self) -> String {
        match self {
            Source::File { path, .. } => format!("autotune check {}", path.display()),
            Source::Program { name } => format!("{name} check"),
            Source::Records { files } => format!("autotune check --records {}", join_paths(files)),
        }
    }
}

fn join_paths(files: &[PathBuf]) -> String {
    files
        .iter()
        .map(|f| f.display().to_string())
        .collect::<Vec<_>>()
        .join(" ")
}

/// What an experiment is called and where it comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Info {
    /// Name, used for output names (`tuned/<name>.toml`): letters, digits, `_` and `-`.
    pub name: String,
    /// One line saying what is modelled (may be empty).
    pub description: String,
    /// Where it is defined.
    pub source: Source,
}

/// What every experiment declares: its name and source, its named parameters, the names of
/// its state and measurement components, and its own Monte Carlo test.
#[derive(Debug, Clone, PartialEq)]
pub struct Definition {
    /// Name, description, source.
    pub info: Info,
    /// Named parameters: values are the configured filter (the tuner's start), bounds the
    /// search box.
    pub params: ParamSpace,
    /// State component names, n_x (of the error state the NEES is taken in).
    pub state_names: Vec<String>,
    /// Measurement component names, all sensors' components concatenated in sensor order.
    pub measurement_names: Vec<String>,
    /// The experiment's own Monte Carlo test (runs, steps, seed, α, lags).
    pub mc: McConfig,
}

/// The filter's noise covariances at some θ, for reports and tuned configs.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Covariances {
    /// Process noise covariance per step, n_x × n_x (state units squared).
    pub Q: DMatrix<f64>,
    /// Measurement noise covariance, n_z × n_z (measurement units squared; all sensors'
    /// components in sensor order).
    pub R: DMatrix<f64>,
}

/// A set of parameters, filter state components and measurement components that no matrix
/// of the truth or the filter couples to the rest: the filter's errors and innovations in
/// these components, and so their statistics, depend on these parameters alone. The tuner
/// searches each block's free parameters on the block's own statistics, so that a misfit in
/// one block is never compensated by moving another's parameters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Block {
    /// Parameter indices ([`Experiment::params`] order), ascending.
    pub params: Vec<usize>,
    /// Filter state component indices ([`Experiment::state_names`] order), ascending.
    pub states: Vec<usize>,
    /// Measurement component indices ([`Experiment::measurement_names`] order), ascending.
    pub measurements: Vec<usize>,
}

/// Where an experiment's truth comes from at each evaluation, for the tune's report: a
/// truth the parameters do not enter can be simulated once per seed set and replayed to
/// every candidate, one that they may enter cannot.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TruthReuse {
    /// θ enters only the filter: a seed set's truth is taped on its second evaluation and
    /// replayed to later ones ([`crate::montecarlo::TruthCache`]).
    Taped {
        /// Evaluations that replayed a tape.
        replayed: usize,
        /// Evaluations that simulated their truth.
        simulated: usize,
        /// A seed set's tape would have exceeded the cache's limit, so its truth was
        /// simulated at each of its evaluations.
        too_large: bool,
        /// The cache's limit, bytes.
        limit: usize,
    },
    /// Simulated at every evaluation, for the reason given.
    Simulated {
        /// Why, in words.
        why: String,
    },
    /// No truth is simulated: the filter runs over recorded measurements.
    Recorded,
}

impl TruthReuse {
    /// [`TruthReuse::Taped`] from a cache's usage, counted from `before` (its usage when
    /// the evaluations of interest began).
    pub fn taped(
        cache: &crate::montecarlo::TruthCache,
        before: crate::montecarlo::TapeUsage,
    ) -> Self {
        let now = cache.usage();
        TruthReuse::Taped {
            replayed: now.replayed - before.replayed,
            simulated: now.simulated - before.simulated,
            too_large: now.too_large,
            limit: cache.limit(),
        }
    }

    /// One line for a report: "replayed from tapes at 10 of 34 evaluations (…)".
    pub fn text(&self) -> String {
        match self {
            TruthReuse::Taped {
                replayed,
                simulated,
                too_large,
                limit,
            } => {
                let mut t = format!(
                    "replayed from tapes at {replayed} of {} evaluations (the parameters enter only the filter: a seed set's truth is simulated at its first two evaluations, the second taping it, and replayed at the rest; each fresh confirmation seed is evaluated once)",
                    replayed + simulated
                );
                if *too_large {
                    t.push_str(&format!(
                        "; a seed set whose tape would exceed {} MiB was simulated at every evaluation",
                        limit >> 20
                    ));
                }
                t
            }
            TruthReuse::Simulated { why } => format!("simulated at every evaluation: {why}"),
            TruthReuse::Recorded => {
                "none simulated: the filter runs over recorded measurements".to_string()
            }
        }
    }
}

/// A filter family and the truth it is tested against, seen through what the statistics
/// need: named parameters θ, component names, and the Monte Carlo sums at θ.
///
/// Implementations must honour the engine's reproducibility contract: the same θ, settings
/// and seed give the same sums on any number of threads (common random numbers: the tuner
/// evaluates every candidate on the same seed).
pub trait Experiment: Sync {
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
    /// evaluation ([`Experiment::splits`] is false) may ignore the share.
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
    /// where [`Experiment::monte_carlo_corrected`] is offered; `None` otherwise.
    fn innovation_scales(&self, _theta: &[f64], _mc: &McConfig) -> Option<Vec<f64>> {
        None
    }

    /// Whether an evaluation splits into shares of its chunks ([`RunOptions::share`]), which
    /// the shards and the MPI ranks compute apart: true for every simulated experiment, false
    /// for sums that were recorded whole.
    fn splits(&self) -> bool {
        !self.seed_free()
    }

    /// Whether the sums are the same for every seed: a filter run over one recorded data
    /// set rather than a simulation. The tuner then confirms on that record once instead of
    /// on fresh seeds, and reports no seed-to-seed resolution (it would be zero).
    fn seed_free(&self) -> bool {
        false
    }

    /// Where the truth of an evaluation has come from since `since` (a usage read before
    /// the evaluations of interest, from [`Experiment::tape_usage`]). The default: the
    /// experiment simulates its own truth at every evaluation.
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> TruthReuse {
        TruthReuse::Simulated {
            why: "the experiment simulates its own truth".to_string(),
        }
    }

    /// The truth cache's usage now, for [`Experiment::truth_reuse`]; the default (no
    /// cache) is empty.
    fn tape_usage(&self) -> crate::montecarlo::TapeUsage {
        crate::montecarlo::TapeUsage::default()
    }
}
