//! Argument parsing and wiring.

mod check;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Tune Kalman filter noise covariances until the filter is statistically consistent.
#[derive(Debug, Parser)]
#[command(name = "autotune", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Monte Carlo consistency test (NEES/NIS against chi-square intervals); exit 0 if
    /// consistent, 1 if not, 2 on bad input.
    Check(check::CheckArgs),
}

/// Parse arguments and run; the exit code says consistent (0) or not (1).
pub fn run() -> anyhow::Result<ExitCode> {
    let cli = Cli::parse();
    match cli.command {
        Command::Check(a) => check::run(a),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn verify_cli() {
        Cli::command().debug_assert();
    }
}
