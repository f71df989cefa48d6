//! autotune: make Kalman filters statistically consistent.
//!
//! The library checks a filter by truth-model Monte Carlo (NEES and NIS against chi-square
//! intervals, [`stats`]), and tunes its noise covariances Q and R. Data flows one way:
//! [`problem`] file → ([`model`], [`filter`], [`params`]) → [`montecarlo`] → [`stats`] →
//! [`report`]. Each piece is usable on its own: a Rust user can supply a truth model or a
//! filter through [`model::TruthModel`] and [`filter::Filter`].
//!
//! Check a shipped problem's filter with the truth's noise values, then tune it from the
//! designer's guess:
//!
//! ```
//! use autotune::check::{Engine, check};
//! use autotune::problem::Problem;
//! use autotune::tune::{Silent, TuneSettings, tune};
//!
//! let p = Problem::load(std::path::Path::new("problems/cv1d.toml")).unwrap();
//! // Parameters in file order: q_accel ((m/s²)²), r_pos (m²).
//! let report = check(&p, &[0.5, 1.0], &p.mc, Engine::Auto, true);
//! assert!(report.verdict.passes());
//!
//! let fixed = vec![false; p.params.params.len()];
//! let result = tune(&p, &p.params.values(), &fixed, &p.mc, &TuneSettings::default(), &Silent).unwrap();
//! assert!((result.tuned[0] / 0.5 - 1.0).abs() < 0.01);
//! ```

#![warn(missing_docs)]

pub mod check;
pub mod filter;
pub mod linalg;
pub mod model;
pub mod montecarlo;
pub mod params;
pub mod problem;
pub mod report;
pub mod stats;
pub mod tune;

/// The random number generator of one Monte Carlo run (xoshiro256++: fast, seedable, and
/// with independent streams per seed).
pub type SimRng = rand::rngs::Xoshiro256PlusPlus;
