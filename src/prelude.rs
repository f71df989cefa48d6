//! The names most programs need, in one import: `use autotune::prelude::*;`.
//!
//! Judging ([`check`], [`check_seeds`]) and tuning ([`Tuner`]) any [`Experiment`] (a
//! [`Problem`] file, a linear model built with [`LinearExperiment::builder`], or any model
//! defined in Rust with [`RustModel`]), and watching a running filter with [`NisMonitor`].

pub use crate::check::{check, check_seeds};
pub use crate::params::{cwna_block, dwna_block};
pub use crate::{
    Experiment, LinearExperiment, McConfig, NisMonitor, NisSettings, ParamDef, Problem, RustModel,
    Silent, Target, Truth, Tunable, TuneSettings, Tuner, Verdict,
};
