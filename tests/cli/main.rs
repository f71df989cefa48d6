//! The command line as users and CI meet it: exit codes, JSON and JUnit, bad input, outputs
//! that never replace inputs, reports, interrupts.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;

mod atomic_outputs;
mod bad_input;
mod check;
mod hardening;
mod init;
mod input_limits;
mod outputs;
mod report;
