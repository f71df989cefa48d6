//! The `autotune` command line: a thin client of the library ([`autotune::app`]).

fn main() -> std::process::ExitCode {
    autotune::app::main()
}
