//! Field logs judged without truth: `autotune nis` on CSV, JSON Lines and PX4 ULog, its
//! statistics and reports, and the live monitor.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;
#[path = "../support/mod.rs"]
mod support;

mod html;
mod live_monitor;
mod nis;
mod px4;
mod px4_fixtures;
mod px4_statements;
mod statistics;
