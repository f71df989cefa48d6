//! The documentation cannot go stale: the guide's examples, the man pages, and the layout
//! docs/ARCHITECTURE.md draws.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod api_tour;
mod architecture;
mod file_graph;
mod file_size;
mod guide;
mod man;
