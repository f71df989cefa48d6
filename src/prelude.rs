//! The names most programs need, in one import: `use autotune::prelude::*;`.
//!
//! Judging and tuning any [`Experiment`] (a [`Problem`] file, or a model defined in Rust
//! with [`RustModel`]), and watching a running filter with [`NisMonitor`].

pub use crate::{
    Experiment, McConfig, NisMonitor, NisSettings, Problem, RustModel, Silent, TuneSettings,
    Verdict, check, tune,
};
