//! The consistency gate and its statistics: NEES and NIS, their exact expectations, the chi-
//! square intervals, the per-component and zero-mean tests.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;

mod chi2_reference;
mod consistency;
mod error_map;
mod expected;
mod gate;
mod meaningless_numbers;
mod nonlinear_filters;
mod properties;
mod sensor_schedule;
mod truth_map;
mod truth_tape;
