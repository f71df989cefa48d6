//! autotune: make Kalman filters statistically consistent.
//!
//! The library checks a filter by truth-model Monte Carlo (NEES and NIS against chi-square
//! intervals, [`stats`]) and tunes its noise covariances Q and R ([`tune`]). Everything
//! goes through one seam, [`experiment::Experiment`]: "the Monte Carlo sums of the filter at
//! parameter values θ". A problem file ([`problem`]), a catalog model ([`catalog`]) and a
//! Rust user's own truth model and filter ([`experiment::Custom`]) are each one
//! implementation; [`check`], [`tune`], [`report`] and the command line ([`app`]) take any
//! of them. docs/ARCHITECTURE.md draws the layers.
//!
//! Check a shipped problem's filter with the truth's noise values, then tune it from the
//! designer's guess:
//!
//! ```
//! use autotune::check::check;
//! use autotune::experiment::Experiment;
//! use autotune::problem::Problem;
//! use autotune::tune::{Silent, TuneSettings, tune};
//!
//! let p = Problem::load(std::path::Path::new("problems/cv1d.toml")).unwrap();
//! // Parameters in file order: q_accel ((m/s²)²), r_pos (m²).
//! let report = check(&p, &[0.5, 1.0], p.mc(), true).unwrap();
//! assert!(report.verdict.passes());
//!
//! let fixed = vec![false; p.params().params.len()];
//! let start = p.params().values();
//! let result = tune(&p, &start, &fixed, p.mc(), &TuneSettings::default(), &Silent).unwrap();
//! assert!((result.tuned[0] / 0.5 - 1.0).abs() < 1e-4);
//! ```

#![warn(missing_docs)]

// The BLAS and LAPACK that clarabel's semidefinite cone calls (the `sdp` feature): the
// system's shared OpenBLAS (Debian: libopenblas-dev).
#[cfg(feature = "sdp")]
#[link(name = "openblas")]
unsafe extern "C" {}

pub mod app;
pub mod catalog;
pub mod check;
pub mod commands;
pub mod estimate;
pub mod experiment;
pub mod explain;
pub mod external;
pub mod fieldlog;
pub mod filter;
pub mod input;
pub mod linalg;
pub mod measurement;
pub mod model;
pub mod montecarlo;
pub mod output;
pub mod params;
pub mod problem;
pub mod records;
pub mod report;
pub mod statespace;
pub mod stats;
pub mod tune;
pub mod userfile;

/// The random number generator of one Monte Carlo run (xoshiro256++: fast, seedable, and
/// with independent streams per seed).
pub type SimRng = rand::rngs::Xoshiro256PlusPlus;
