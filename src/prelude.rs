//! The names most programs need, in one import: `use autotune::prelude::*;`.
//!
//! Judging and tuning any [`Experiment`] (a [`Problem`] file, or a model defined in Rust
//! with [`Custom`]), and watching a running filter with [`NisMonitor`].

pub use crate::{
    Custom, Experiment, McConfig, NisMonitor, NisSettings, Problem, Silent, TuneSettings, Verdict,
    check, tune,
};
