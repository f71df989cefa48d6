//! A linear-Gaussian truth and Kalman filter as an [`super::Experiment`], from a problem
//! file or built in Rust (`builder`): the model (`model`) and how it answers the seam
//! (`seam`), apart so that the seam, which names the linear experiment, and the
//! experiment, which implements the seam, import no file of each other's.

mod builder;
mod model;
mod seam;

pub use builder::LinearModelBuilder;
#[cfg(test)]
pub(crate) use builder::cv1d_for_tests;
pub use model::{FilterModel, LinearExperiment};
