//! What an experiment is, apart from how it runs: its name and source, its parameters and
//! components, its Monte Carlo settings, and the facts the tuner and the reports read of it
//! (the covariances at θ, its decoupled blocks, whether its truth can be replayed).

use std::path::PathBuf;

use nalgebra::DMatrix;

use crate::montecarlo::McConfig;
use crate::params::ParamSpace;

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
