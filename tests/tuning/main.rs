//! Tuning: the tuner recovers the truth's noise parameters, the command's outputs and words,
//! the search bounds, the advice, the shipped tuned configs.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;

mod advice;
mod bounds;
mod catalog_tune;
mod cli_tune;
mod tune;
mod tuned_configs;
