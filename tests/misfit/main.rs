//! Conclusions under misfit: the explanation of a misfit on families of random problems, and
//! what the gate and the tuner say where the filter's structure is wrong.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;
#[path = "../common/families.rs"]
mod families;

mod explain;
mod explain_cli;
mod explain_code;
mod no_false_misfit;
mod separable;
mod structure_mismatch;
mod zero_mean;
mod zero_mean_misfit;
