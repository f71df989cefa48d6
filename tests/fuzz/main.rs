//! The fuzzers: the loaders, the field-log readers, the records, measurement records and
//! workers, the shard format and the C ABI.
//!
//! One test binary per subject: each file below was a test binary of its own, which cost a
//! link each and ran its tests apart from the others'.

/// The binary's allocator, as the `autotune` binary's (Cargo.toml's `mimalloc` feature):
/// the suites that tune and explain allocate small matrices step by step.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "../common/fuzz_runner.rs"]
mod fuzz_runner;
#[path = "../common/fuzzing.rs"]
mod fuzzing;

mod fieldlog;
mod inputs;
mod loaders;
mod shards;
