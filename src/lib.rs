//! autotune: make Kalman filters statistically consistent.
//!
//! The library checks a filter by truth-model Monte Carlo (NEES and NIS against chi-square
//! intervals) and tunes its noise covariances Q and R. Everything goes through one seam,
//! [`Experiment`]: "the Monte Carlo sums of the filter at parameter values θ". A problem file
//! ([`Problem`]), a linear model built in Rust ([`LinearExperiment::builder`]), a catalog
//! model, a worker program in another language and a Rust user's own truth model and filter
//! ([`RustModel`]) are each one implementation; [`check`], [`Tuner`], the [`commands`], the
//! renderers in [`report`] and the command line ([`app`]) take any of them. A running
//! filter's innovations are judged live by [`NisMonitor`].
//! docs/ARCHITECTURE.md draws the layers and lists this API.
//!
//! A linear model built in Rust, tuned from a guess 10× off, and its result checked on
//! several seeds (`examples/tune_linear.rs`, which the guide's API chapter shows):
//!
#![doc = concat!("```\n", include_str!("../examples/tune_linear.rs"), "```\n")]
//!
//! Check a shipped problem's filter with the truth's noise values:
//!
//! ```
//! use autotune::prelude::*;
//!
//! let p = Problem::load(std::path::Path::new("problems/cv1d.toml")).unwrap();
//! // Parameters in file order: q_accel ((m/s²)²), r_pos (m²).
//! let report = check(&p, &[0.5, 1.0], p.mc(), Truth::Known).unwrap();
//! assert!(report.verdict.passes());
//! ```
//!
//! Watch a running filter's innovations, the way a vehicle's status line would:
//!
//! ```
//! use autotune::prelude::*;
//!
//! let mut monitor = NisMonitor::new(NisSettings::default());
//! // Each update: sensor, time (s), innovation ν, and S (row-major, m × m).
//! monitor.update("gps", 0.1, &[0.3, -0.2], &[1.0, 0.0, 0.0, 1.0]).unwrap();
//! println!("{}", monitor.status());
//! ```

#![warn(missing_docs)]
#![cfg_attr(autotune_api, deny(unnameable_types))]

// The BLAS and LAPACK that clarabel's semidefinite cone calls (the `sdp` feature): the
// system's shared OpenBLAS (Debian: libopenblas-dev).
#[cfg(feature = "sdp")]
#[link(name = "openblas")]
unsafe extern "C" {}

pub mod app;
pub mod commands;
pub mod prelude;
pub mod report;

// The modules below the public API: private, their names re-exported below where a Rust
// user needs them.
mod capi;
mod catalog;
mod check;
pub mod cluster;
mod estimate;
mod experiment;
mod explain;
mod external;
mod fieldlog;
mod filter;
mod input;
mod linalg;
mod measurement;
mod model;
mod montecarlo;
mod output;
mod params;
mod problem;
mod records;
mod rng;
mod statespace;
mod stats;
mod tune;
mod userfile;

/// Every module below the public API, whole: for the crate's own tests, benches and
/// examples. Hidden from the documentation and not part of the API: it may change in any
/// release. (Always compiled, rather than behind a feature, so that the binary and the
/// tests are one build.)
#[doc(hidden)]
#[cfg(not(autotune_api))]
pub mod internals {
    pub mod catalog {
        pub use crate::catalog::*;
    }
    pub mod check {
        pub use crate::check::*;
    }
    pub mod estimate {
        pub use crate::estimate::*;
    }
    pub mod experiment {
        pub use crate::experiment::*;
    }
    pub mod explain {
        pub use crate::explain::*;
    }
    pub mod capi {
        pub use crate::capi::*;
    }
    pub mod external {
        pub use crate::external::*;
    }
    pub mod fieldlog {
        pub use crate::fieldlog::*;
    }
    pub mod filter {
        pub use crate::filter::*;
    }
    pub mod input {
        pub use crate::input::*;
    }
    pub mod linalg {
        pub use crate::linalg::*;
    }
    pub mod measurement {
        pub use crate::measurement::*;
    }
    pub mod rng {
        pub use crate::rng::*;
    }
    pub mod model {
        pub use crate::model::*;
    }
    pub mod montecarlo {
        pub use crate::montecarlo::*;
    }
    pub mod output {
        pub use crate::output::*;
    }
    pub mod params {
        pub use crate::params::*;
    }
    pub mod problem {
        pub use crate::problem::*;
    }
    pub mod records {
        pub use crate::records::*;
    }
    pub mod statespace {
        pub use crate::statespace::*;
    }
    pub mod stats {
        pub use crate::stats::*;
    }
    pub mod tune {
        pub use crate::tune::*;
    }
    pub mod userfile {
        pub use crate::userfile::*;
    }
}

// The seam, and a problem file as one implementation of it.
pub use experiment::{
    Block, Covariances, Definition, Experiment, ExperimentError, HeldAsCode, Info,
    LinearExperiment, LinearModelBuilder, RunOptions, Sampling, Source, Structure,
};
pub use problem::{Problem, ProblemKind};

// A model defined in Rust: its truth, its filter, its parameters.
pub use experiment::{RustModel, RustModelBuilder};
pub use filter::{
    Ekf, Estimate, Filter, FilterError, Innovation, PredictResult, SystemModel, Ukf, UpdateResult,
    check_measurement,
};
pub use linalg::psd_factor;
pub use measurement::Measurement;
pub use model::{LinearGaussianModel, TruthModel, sample_gaussian};
pub use params::{NoiseKind, ParamDef, ParamSpace, Target, cwna_block, dwna_block};

// Judging a filter: the Monte Carlo settings and sums, the gate and its report.
pub use check::{
    CheckProgress, SeedCheck, SeedChecks, Truth, check, check_seeds, check_with, judge,
};
pub use montecarlo::{Engine, McConfig};
pub use stats::{
    Accumulator, ComponentStat, ConsistencyReport, Diagnosis, Divergence, GateMode, Interval,
    StatisticSummary, Verdict, WhitenessStat,
};

// Tuning.
pub use tune::{
    LocalSearch, Observer, Scoring, Silent, Tunable, TuneError, TuneResult, TuneSettings, TuneSpec,
    TuneStatus, Tuner,
};

// Field logs judged without truth, and live monitoring.
pub use fieldlog::{
    MonitorError, MonitorStatus, NisMonitor, NisReport, NisSettings, SensorStatus, Window,
    WindowStatus,
};

// A worker program that sums its own records (the C ABI and the Python package wrap it).
pub use external::{ChunkError, WorkerChunk};
pub use records::{Layout, SensorLayout, SensorRecord, StateLayout, StateRecord, StepRecord};

// Errors of bad input.
pub use input::{FileError, SettingError};

// The types the items above carry in their fields, results and errors: each nameable, so
// that a program can store, match and pass on whatever the API hands it.
pub use estimate::als::AlsEstimate;
pub use estimate::ml::MlEstimate;
pub use estimate::{
    EstimateError, GateRanges, LikelihoodRanges, MeasurementRecord, NotDefinite,
    Range as EstimateRange, RangeEnd, Sequence,
};
pub use experiment::{
    Ended, FilterModel, Hypothesis, RequestInfo, SeedContractViolation, StartFailure, TruthReuse,
    Uncontained, WorkerError, WorkerFailure, WorkerRole,
};
pub use explain::{Cause, Explanation, Trial};
pub use external::{ExternalExperiment, WorkerCommand};
pub use fieldlog::{
    CentredWhiteness, Dropped, EventKind, Histogram, LogSource, MeanTest, NisAverage, NotFused,
    NotJudged, Overall, ParamAdvice, Px4Channel, Px4Event, Px4Info, Px4Instance, ReadOptions,
    SensorPlot, SensorReport, SeriesPoint, Status as FollowStatus, WindowSummary,
};
pub use filter::{Correction, CovarianceUpdate};
pub use model::NotPsd;
pub use montecarlo::{TapeUsage, TruthCache, TruthTape};
pub use output::WriteError;
pub use params::{Coef, CovModel, CovTerm};
pub use records::{LayoutError, RecordError, SensorShapeError, ShapeError, WireError};
pub use statespace::LinearGaussian;
pub use stats::{Finding, GateSpec, StopCause, SumVariance, Suspect, WhitenessTest};
pub use tune::objective::PerTerm;
pub use tune::{Certificate, CertifiedStart, Confirmation, Plan, Resolution, Terms, Widening};

// The random number generator of one Monte Carlo run.
pub use rng::SimRng;
