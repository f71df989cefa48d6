//! The command line as a library: `autotune check`, `tune`, `init` and `completions`.
//!
//! The `autotune` binary is [`main`] and nothing else. A Rust user's own model gets the same
//! `check` and `tune` commands, with every option, report, the advice and the tuned config,
//! from one call in its own `main`:
//!
//! ```no_run
//! # fn my_experiment() -> autotune::problem::Problem { unimplemented!() }
//! use autotune::tune::TuneSettings;
//! fn main() -> std::process::ExitCode {
//!     let model = my_experiment(); // e.g. autotune::experiment::Custom::builder(...).build()
//!     autotune::app::main_for(&model, &TuneSettings::default())
//! }
//! ```
//!
//! `my_model check --report out`, `my_model tune --out tuned/my_model.toml`, … then behave as
//! `autotune check problem.toml …` does. Exit codes: 0 consistent, 1 not, 2 bad input.

mod args;
mod check;
mod completions;
mod estimate;
mod estimate_full;
mod init;
mod nis;
mod simulate;
mod tune;

pub use check::CheckOptions;
pub use nis::NisArgs;
pub use tune::TuneOptions;

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

use crate::experiment::Experiment;
use crate::experiment::RecordedExperiment;
use crate::input::FileError;
use crate::output::WriteError;
use crate::problem::Problem;
use crate::tune::TuneSettings;

/// Why a command could not do its job (exit code 2). Each renders as one line naming the
/// file and field, or the flag.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// A bad input file.
    #[error(transparent)]
    File(#[from] FileError),
    /// A bad command-line option: the flag and what is wrong.
    #[error("{flag}: {message}")]
    Flag {
        /// The flag, e.g. `--runs`.
        flag: String,
        /// What is wrong.
        message: String,
    },
    /// Arguments clap refused (its first line, and where to find help).
    #[error("{0}")]
    Usage(String),
    /// An output that could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// A refusal that names its own subject (e.g. an existing file).
    #[error("{0}")]
    Refused(String),
    /// The experiment could not run: an external worker broke the protocol, records were
    /// malformed.
    #[error(transparent)]
    Experiment(#[from] crate::experiment::ExperimentError),
    /// Standard output failed (a closed pipe is not reported).
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

impl AppError {
    /// An error in option `flag`.
    pub fn flag(flag: &str, message: impl Into<String>) -> AppError {
        AppError::Flag {
            flag: flag.to_string(),
            message: message.into(),
        }
    }
}

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
    Check(ProblemCheck),
    /// Search the free Q/R parameters for a consistent filter; write a tuned config and a
    /// report; exit 0 if the tuned filter passes the confirmation, 1 if not.
    Tune(ProblemTune),
    /// Judge a filter's recorded innovations (a field log: PX4 ULog, CSV, JSON Lines) without
    /// ground truth: NIS per sensor against its chi-square interval, outliers, whiteness;
    /// exit 0 if consistent, 1 if not, 2 on bad input.
    Nis(nis::NisArgs),
    /// Draw measurements (and optionally the true states) from a linear problem's truth, to
    /// try `estimate` on data whose answer is known.
    Simulate(simulate::SimulateArgs),
    /// Estimate a linear problem's free Q/R parameters from recorded measurements alone:
    /// maximum likelihood with standard errors, or autocovariance least squares.
    Estimate(estimate::EstimateArgs),
    /// Write a commented starter problem file (NAME.toml) whose filter equals its truth, so
    /// `autotune check` passes on it; replace its parameter values with your own guesses.
    Init(init::InitArgs),
    /// Print a shell completion script on stdout, e.g.
    /// `autotune completions bash > ~/.local/share/bash-completion/completions/autotune`.
    Completions(completions::CompletionsArgs),
}

#[derive(Debug, clap::Args)]
struct ProblemCheck {
    /// Problem file (TOML).
    #[arg(required_unless_present = "records")]
    problem: Option<PathBuf>,
    /// Judge the records another program wrote instead of a problem file: CSV, NumPy
    /// (.npz, or .npy files named after their quantities) or JSON Lines; several files are
    /// one experiment (format: docs/external.md).
    #[arg(long, num_args = 1.., value_name = "FILE", conflicts_with_all = ["problem", "config", "runs", "steps", "seed", "set", "engine"])]
    records: Vec<PathBuf>,
    /// Judge the problem's filter on recorded measurements instead of its truth model: the
    /// filter runs over the record (CSV, JSON Lines, NumPy; docs/measurements.md) and is
    /// judged by its innovations alone. Linear problems.
    #[arg(long, value_name = "FILE", requires = "problem", conflicts_with_all = ["runs", "steps", "seed", "engine"])]
    measurements: Option<PathBuf>,
    #[command(flatten)]
    options: CheckOptions,
}

#[derive(Debug, clap::Args)]
struct ProblemTune {
    /// Problem file (TOML).
    problem: PathBuf,
    /// Tune against recorded measurements instead of the truth model: the filter runs over
    /// the record (CSV, JSON Lines, NumPy; docs/measurements.md) and candidates are scored by
    /// their innovations alone (NIS, per-component NIS, whiteness). Linear problems.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["runs", "steps", "seed"])]
    measurements: Option<PathBuf>,
    /// Start the search from an estimate from measurements alone: ml (maximum likelihood)
    /// or als (autocovariance least squares), on --init-record, or else on --measurements,
    /// or else on a record simulated from the problem's truth (its runs × steps, another
    /// seed); or from the problem's values (problem). Linear problems. Default: ml with
    /// --measurements, the problem's values without.
    #[arg(long, value_name = "METHOD", value_parser = ["ml", "als", "problem"])]
    init: Option<String>,
    /// The record --init estimates from.
    #[arg(long, value_name = "FILE", requires = "init")]
    init_record: Option<PathBuf>,
    #[command(flatten)]
    options: TuneOptions,
}

/// The commands a Rust model's own program has.
#[derive(Debug, Parser)]
#[command(version, about = "Check and tune this model's filter: Monte Carlo NEES/NIS consistency tests and a Q/R search (autotune).", long_about = None)]
struct ModelCli {
    #[command(subcommand)]
    command: ModelCommand,
}

#[derive(Debug, Subcommand)]
enum ModelCommand {
    /// Monte Carlo consistency test (NEES/NIS against chi-square intervals); exit 0 if
    /// consistent, 1 if not, 2 on bad input.
    Check(CheckOptions),
    /// Search the free Q/R parameters for a consistent filter; write a tuned config and a
    /// report; exit 0 if the tuned filter passes the confirmation, 1 if not.
    Tune(TuneOptions),
}

/// The `autotune` binary: parse the process's arguments, run, print any error on one line.
/// Ctrl-C (SIGINT), SIGTERM and SIGHUP stop any external workers, remove their scratch
/// directories and the temporary files of a write in progress, and exit 128 + the signal's
/// number (130, 143, 129).
pub fn main() -> ExitCode {
    remove_temporary_files_on_interrupt();
    finish(run(std::env::args_os()))
}

/// `autotune` with these arguments (the first is the program name).
pub fn run<I, T>(args: I) -> Result<ExitCode, AppError>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => return usage_error(e, "autotune"),
    };
    match cli.command {
        Command::Check(a) => match (a.problem, &a.measurements) {
            (Some(p), Some(f)) => {
                let problem = Problem::load(&p)?;
                let measured = estimate::measured_experiment(&problem, &p, f)?;
                check::run(&measured, a.options.nis_only())
            }
            (Some(p), None) => check::run(&Problem::load(&p)?, a.options),
            (None, _) => check::run(&RecordedExperiment::read(&a.records)?, a.options),
        },
        Command::Tune(a) => {
            let p = Problem::load(&a.problem)?;
            let init = match (&a.init, &a.measurements) {
                (Some(m), _) if m == "problem" => None,
                // One record is one draw: the search starts where the evidence is, the
                // maximum of the likelihood on it, unless --init says otherwise.
                (None, Some(f)) => {
                    match estimate::initial(&p, &a.problem, Some(f.as_path()), "ml") {
                        Ok(theta) => Some(theta),
                        Err(AppError::Refused(why)) => {
                            eprintln!("start: the problem's values ({why})");
                            None
                        }
                        Err(e) => return Err(e),
                    }
                }
                (None, None) => None,
                (Some(method), _) => {
                    let record = a.init_record.as_ref().or(a.measurements.as_ref());
                    Some(estimate::initial(
                        &p,
                        &a.problem,
                        record.map(|r| r.as_path()),
                        method,
                    )?)
                }
            };
            match &a.measurements {
                None => tune::run_from(&p, &p.tune, a.options, init),
                Some(f) => {
                    let measured = estimate::measured_experiment(&p, &a.problem, f)?;
                    let settings = p.tune.clone().with_nis_only(true);
                    tune::run_from(&measured, &settings, a.options, init)
                }
            }
        }
        Command::Nis(a) => nis::run(a),
        Command::Simulate(a) => simulate::run_simulate(a),
        Command::Estimate(a) => estimate::run_estimate(a),
        Command::Init(a) => init::run(a),
        Command::Completions(a) => completions::run(a, Cli::command(), "autotune"),
    }
}

/// The whole command line for a model defined in Rust: `check` and `tune` with every option
/// `autotune` has (no problem file: the model is `experiment`; `tune` starts from `tune`'s
/// settings). Prints any error on one line; returns the exit code (0 consistent, 1 not,
/// 2 bad input).
///
/// Like `autotune`, it handles Ctrl-C, SIGTERM and SIGHUP (stopping workers, removing
/// scratch directories and temporary files, exit 128 + the signal's number), each unless
/// the program installed a handler of its own for it first.
pub fn main_for(experiment: &dyn Experiment, tune: &TuneSettings) -> ExitCode {
    remove_temporary_files_on_interrupt();
    finish(run_for(experiment, tune, std::env::args_os()))
}

/// Set while `nis --follow` runs: Ctrl-C then ends the follow (and prints its summary)
/// instead of the process.
pub(crate) static FOLLOWING: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);
/// Set by Ctrl-C during a follow.
pub(crate) static STOP_FOLLOWING: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

/// On SIGINT, SIGTERM or SIGHUP: stop the external workers (their whole process groups,
/// with a grace period) and remove their scratch directories, remove the temporary files of
/// any write in progress, so no `.NAME.tmp.PID` file outlives the process, and exit with
/// the signal's conventional code, 128 + its number (130 for Ctrl-C, 143 for SIGTERM, 129
/// for SIGHUP). Installed once per process, for each signal that has its default
/// disposition: a handler the program set before is left alone, and so is a signal the
/// process was started with ignored (`nohup`'s SIGHUP, a script's background job's
/// SIGINT): the user asked for it to be survived.
fn remove_temporary_files_on_interrupt() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let signals: Vec<libc::c_int> = [libc::SIGINT, libc::SIGTERM, libc::SIGHUP]
            .into_iter()
            .filter(|&s| has_default_disposition(s))
            .collect();
        if signals.is_empty() {
            return;
        }
        // signal-hook's iterator hands the signal's number to an ordinary thread, where the
        // cleanup may take locks, wait and exit.
        let Ok(mut caught) = signal_hook::iterator::Signals::new(&signals) else {
            return;
        };
        std::thread::spawn(move || {
            use std::sync::atomic::Ordering;
            for signal in caught.forever() {
                // A follow ends on the first signal with its summary; a second one, or any
                // other command, stops at once.
                if FOLLOWING.load(Ordering::SeqCst) && !STOP_FOLLOWING.swap(true, Ordering::SeqCst)
                {
                    continue;
                }
                crate::external::stop_workers_and_remove_scratch();
                crate::output::remove_temporary_files();
                std::process::exit(128 + signal);
            }
        });
    });
}

/// Whether `signal` has its default disposition (SIG_DFL) in this process: neither ignored
/// nor handled by a handler someone installed before.
fn has_default_disposition(signal: libc::c_int) -> bool {
    // SAFETY: a null new action only reads the current one into `old`, which is a plain
    // C struct for which all-zero bytes are a valid value.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(signal, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_DFL
    }
}

/// [`main_for`] with these arguments (the first is the program name).
pub fn run_for<I, T>(
    experiment: &dyn Experiment,
    tune: &TuneSettings,
    args: I,
) -> Result<ExitCode, AppError>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let program = match &experiment.info().source {
        crate::experiment::Source::Program { name } => name.clone(),
        crate::experiment::Source::File { .. } | crate::experiment::Source::Records { .. } => {
            experiment.info().name.clone()
        }
    };
    let cmd = ModelCli::command()
        .name(program.clone())
        .bin_name(program.clone());
    let parsed = cmd
        .try_get_matches_from(args)
        .and_then(|m| ModelCli::from_arg_matches(&m));
    let cli = match parsed {
        Ok(c) => c,
        Err(e) => return usage_error(e, &program),
    };
    match cli.command {
        ModelCommand::Check(o) => check::run(experiment, o),
        ModelCommand::Tune(o) => tune::run(experiment, tune, o),
    }
}

/// Help and version go to stdout with exit 0; any other parse error becomes one line.
fn usage_error(e: clap::Error, program: &str) -> Result<ExitCode, AppError> {
    use clap::error::ErrorKind;
    if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
        e.print()?;
        return Ok(ExitCode::SUCCESS);
    }
    let text = e.render().to_string();
    let mut lines = text.lines();
    let first = lines.next().unwrap_or("invalid arguments").trim();
    let first = first.strip_prefix("error: ").unwrap_or(first);
    // clap lists missing arguments on the lines after the first, up to a blank line.
    let missing: Vec<&str> = if e.kind() == ErrorKind::MissingRequiredArgument {
        lines
            .take_while(|l| !l.trim().is_empty())
            .map(str::trim)
            .collect()
    } else {
        Vec::new()
    };
    let first = if missing.is_empty() {
        first.to_string()
    } else {
        format!("{} {}", first, missing.join(", "))
    };
    Err(AppError::Usage(format!("{first} (see '{program} --help')")))
}

/// Print on stdout with `f`. A closed pipe (`autotune check … | head`) ends the printing
/// without an error, so the command still exits with its verdict's code; any other failure
/// of stdout is an error.
fn print_stdout(
    f: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> Result<(), AppError> {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    match f(&mut stdout).and_then(|()| stdout.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}

/// Print an error as `error: …` on stderr and map it to exit code 2. A closed stdout pipe
/// is not an error here: `check` and `tune` print through [`print_stdout`] and keep their
/// verdict's code, and what else prints (help, `init`, `completions`) has done its work.
fn finish(result: Result<ExitCode, AppError>) -> ExitCode {
    match result {
        Ok(code) => code,
        Err(AppError::Io(e)) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

/// Whether to colour stdout: only on a terminal, and never when `NO_COLOR` is set to
/// anything non-empty (<https://no-color.org>).
fn colour_enabled() -> bool {
    use std::io::IsTerminal;
    std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty()) && std::io::stdout().is_terminal()
}

/// `line` in bold green (pass) or bold red (fail) when colour is enabled.
fn paint_verdict(line: &str, pass: bool) -> String {
    if colour_enabled() {
        let code = if pass { "1;32" } else { "1;31" };
        format!("\x1b[{code}m{line}\x1b[0m")
    } else {
        line.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verify_cli() {
        Cli::command().debug_assert();
        ModelCli::command().debug_assert();
    }
}
