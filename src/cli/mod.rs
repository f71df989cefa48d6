//! Argument parsing and wiring.

mod check;
mod completions;
mod init;
mod tune;

use std::path::PathBuf;
use std::process::ExitCode;

use autotune::problem::{McConfig, Problem, ProblemError};
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
    /// Search the free Q/R parameters for a consistent filter; write a tuned config and a
    /// report; exit 0 if the tuned filter passes the confirmation, 1 if not.
    Tune(tune::TuneArgs),
    /// Write a commented starter problem file (NAME.toml) whose filter equals its truth, so
    /// `autotune check` passes on it; replace its parameter values with your own guesses.
    Init(init::InitArgs),
    /// Print a shell completion script on stdout, e.g.
    /// `autotune completions bash > ~/.local/share/bash-completion/completions/autotune`.
    Completions(completions::CompletionsArgs),
}

/// Monte Carlo overrides shared by the commands.
#[derive(Debug, clap::Args)]
pub struct McArgs {
    /// Number of Monte Carlo runs N (overrides the file).
    #[arg(long)]
    runs: Option<usize>,
    /// Steps per run T (overrides the file).
    #[arg(long)]
    steps: Option<usize>,
    /// Base seed (overrides the file).
    #[arg(long)]
    seed: Option<u64>,
    /// Significance level α in (0, 1) (overrides the file).
    #[arg(long)]
    alpha: Option<f64>,
    /// Set a parameter, NAME=VALUE (repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
}

/// An error in a command-line option, reported like a problem-file field.
pub fn option_error(field: &str, message: String) -> ProblemError {
    ProblemError {
        file: PathBuf::from("<command line>"),
        field: field.into(),
        line: None,
        message,
    }
}

/// Parse `NAME=VALUE` with VALUE a finite number > 0 naming one of the problem's parameters.
pub fn name_value(problem: &Problem, flag: &str, kv: &str) -> Result<(usize, f64), ProblemError> {
    let (name, value) = kv
        .split_once('=')
        .ok_or_else(|| option_error(flag, format!("'{kv}' is not NAME=VALUE")))?;
    let i = problem.params.index(name.trim()).ok_or_else(|| {
        option_error(
            flag,
            format!(
                "unknown parameter '{name}' (known: {})",
                problem.params.names().join(", ")
            ),
        )
    })?;
    let v = parse_positive(flag, name, value)?;
    Ok((i, v))
}

fn parse_positive(flag: &str, name: &str, value: &str) -> Result<f64, ProblemError> {
    value
        .trim()
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite() && *v > 0.0)
        .ok_or_else(|| option_error(flag, format!("{name}: '{value}' is not a number > 0")))
}

/// Whether to colour stdout: only on a terminal, and never when `NO_COLOR` is set to
/// anything non-empty (<https://no-color.org>).
pub fn colour_enabled() -> bool {
    use std::io::IsTerminal;
    std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty()) && std::io::stdout().is_terminal()
}

/// `line` in bold green (pass) or bold red (fail) when colour is enabled.
pub fn paint_verdict(line: &str, pass: bool) -> String {
    if colour_enabled() {
        let code = if pass { "1;32" } else { "1;31" };
        format!("\x1b[{code}m{line}\x1b[0m")
    } else {
        line.to_string()
    }
}

use autotune::problem::MAX_STEPS;

impl McArgs {
    /// The problem's Monte Carlo settings with the overrides applied.
    pub fn apply(&self, mut mc: McConfig) -> Result<McConfig, ProblemError> {
        if let Some(n) = self.runs {
            if n == 0 {
                return Err(option_error("--runs", "0 must be ≥ 1".into()));
            }
            mc.runs = n;
        }
        if let Some(t) = self.steps {
            if t == 0 || t > MAX_STEPS {
                return Err(option_error(
                    "--steps",
                    format!("{t} must be in 1..={MAX_STEPS}"),
                ));
            }
            mc.steps = t;
            mc.lags = mc.lags.min(t - 1);
        }
        if let Some(s) = self.seed {
            mc.seed = s;
        }
        if let Some(a) = self.alpha {
            if !(a > 0.0 && a < 1.0) {
                return Err(option_error("--alpha", format!("{a} must be in (0, 1)")));
            }
            mc.alpha = a;
        }
        Ok(mc)
    }

    /// `theta` with the `--set` values applied.
    pub fn set_params(&self, problem: &Problem, theta: &mut [f64]) -> Result<(), ProblemError> {
        for kv in &self.set {
            let (i, v) = name_value(problem, "--set", kv)?;
            theta[i] = v;
        }
        Ok(())
    }
}

/// Parse arguments and run; the exit code says consistent (0) or not (1).
pub fn run() -> anyhow::Result<ExitCode> {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
                e.print()?;
                return Ok(ExitCode::SUCCESS);
            }
            // One line, like every other input error; `--help` has the rest.
            let text = e.render().to_string();
            let first = text.lines().next().unwrap_or("invalid arguments").trim();
            let first = first.strip_prefix("error: ").unwrap_or(first);
            anyhow::bail!("{first} (see 'autotune --help')");
        }
    };
    match cli.command {
        Command::Check(a) => check::run(a),
        Command::Tune(a) => tune::run(a),
        Command::Init(a) => init::run(a),
        Command::Completions(a) => completions::run(a),
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
