//! The catalog's nonlinear models (CTRV, orbit, INS/GNSS): Jacobians, filters, and the shipped
//! problems through the real binary.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/mod.rs"]
mod common;

mod ctrv;
mod ins_gnss;
mod orbit2d;
mod shipped;
