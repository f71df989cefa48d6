//! Simulators outside the process: records files, long-lived workers in other languages,
//! workers that sum their own records, and a Rust user's own model.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;

mod external;
mod first_use;
mod records;
mod replay;
mod rust_model;
mod scratch;
mod worker_sums;
