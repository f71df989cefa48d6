//! The `autotune` command line: a thin client of the library ([`autotune::app`]).

/// The binary's allocator (Cargo.toml's `mimalloc` feature, on by default says why).
#[cfg(feature = "mimalloc")]
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    autotune::app::main()
}
