//! autotune: make Kalman filters statistically consistent.
//!
//! The library checks a filter by truth-model Monte Carlo (NEES and NIS against chi-square
//! intervals, [`stats`]), and tunes its noise covariances Q and R. Data flows one way:
//! [`problem`] file → ([`model`], [`filter`], [`params`]) → [`montecarlo`] → [`stats`] →
//! [`report`]. Each piece is usable on its own: a Rust user can supply a truth model or a
//! filter through [`model::TruthModel`] and [`filter::Filter`].

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
