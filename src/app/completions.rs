//! `autotune completions`: shell completion scripts, generated from the command definition
//! by `clap_complete`.

use std::io::Write;
use std::process::ExitCode;

use clap_complete::Shell;

use super::error::AppError;
use crate::commands::OneOf;

#[derive(Debug, clap::Args)]
pub struct CompletionsArgs {
    /// Shell to generate the script for.
    #[arg(value_parser = OneOf::<Shell>::new())]
    shell: Shell,
}

pub fn run(a: CompletionsArgs, mut cmd: clap::Command, bin: &str) -> Result<ExitCode, AppError> {
    // Into a buffer first: the generators panic on a failed write, and a closed pipe
    // (`autotune completions bash | head`) is not an error.
    let mut script = Vec::new();
    clap_complete::generate(a.shell, &mut cmd, bin, &mut script);
    let mut stdout = std::io::stdout().lock();
    stdout.write_all(&script)?;
    stdout.flush()?;
    Ok(ExitCode::SUCCESS)
}
