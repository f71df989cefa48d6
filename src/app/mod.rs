//! The command line: `autotune check`, `tune`, `nis`, `estimate`, `simulate`, `init` and
//! `completions` parsed, dispatched to [`crate::commands`], printed and mapped to exit codes.
//!
//! The `autotune` binary is [`main`] and nothing else. A Rust user's own model gets the same
//! `check` and `tune` commands, with every option, report, the advice and the tuned config,
//! from one call in its own `main`:
//!
//! ```no_run
//! # fn my_experiment() -> autotune::Problem { unimplemented!() }
//! use autotune::TuneSettings;
//! fn main() -> std::process::ExitCode {
//!     let model = my_experiment(); // e.g. autotune::RustModel::builder(...).build()
//!     autotune::app::main_for(&model, &TuneSettings::default())
//! }
//! ```
//!
//! `my_model check --report out`, `my_model tune --out tuned/my_model.toml`, … then behave as
//! `autotune check problem.toml …` does. Exit codes: 0 consistent, 1 not, 2 bad input.

mod cli;
mod completions;
mod error;
mod interrupt;
mod launch;
#[cfg(feature = "mpi")]
mod mpi;
mod nis;
mod print;

pub use crate::commands::check::CheckOptions;
pub use crate::commands::tune::TuneOptions;
pub use cli::Cli;
pub use error::AppError;
pub use launch::main;
pub use nis::NisArgs;

use std::ffi::OsString;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches};

use crate::commands::estimate::{initial, measured_experiment};
use crate::commands::{self, CommandError};
use crate::experiment::{Experiment, RecordsExperiment};
use crate::problem::Problem;
use crate::report::check::summary::after_summary;
use crate::report::check_summary;
use crate::report::progress::{CheckBar, TuneProgress};
use crate::stats::Verdict;
use crate::tune::TuneSettings;
use cli::{Command, MergeArgs, ModelCli, ModelCommand, ProblemTune};
use print::{exit_code, finish, print_stdout, write_painted};

/// `autotune` with these arguments (the first is the program name).
pub fn run<I, T>(args: I) -> Result<ExitCode, AppError>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let parsed = Cli::command().try_get_matches_from(args).and_then(|m| {
        note_inputs(&m);
        Cli::from_arg_matches(&m)
    });
    let cli = match parsed {
        Ok(c) => c,
        Err(e) => return usage_error(e, "autotune"),
    };
    match cli.command {
        Command::Check(a) => match (a.problem, &a.measurements) {
            (Some(p), Some(f)) => {
                let problem = Problem::load(&p)?;
                let measured = measured_experiment(&problem, &p, f, a.reference.as_deref())?;
                let options = if a.reference.is_some() {
                    a.options
                } else {
                    a.options.with_nis_only()
                };
                check(measured.as_ref(), options)
            }
            (Some(p), None) => match (a.shard, &a.sums_out) {
                (Some(share), Some(out)) => shard(&Problem::load(&p)?, &a.options, share, out),
                _ => check(&Problem::load(&p)?, a.options),
            },
            (None, _) => check(&RecordsExperiment::read(&a.records)?, a.options),
        },
        Command::Tune(a) => tune_problem(a),
        Command::Merge(a) => merge(a),
        Command::Nis(a) => nis::run(a),
        Command::Simulate(a) => {
            let text = commands::simulate::simulate(&a)?;
            print_stdout(|o| o.write_all(text.as_bytes()))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Estimate(a) => {
            let run = commands::estimate::estimate(&a)?;
            print_stdout(|o| o.write_all(run.output.as_bytes()))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Init(a) => {
            let text = commands::init::init(&a)?;
            print_stdout(|o| o.write_all(text.as_bytes()))?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Completions(a) => completions::run(a, Cli::command(), "autotune"),
    }
}

/// `tune` on a problem file: from the problem's values, or from an estimate on recorded
/// measurements (`--init`, and by default with `--measurements`), over the truth model or
/// over the record.
fn tune_problem(a: ProblemTune) -> Result<ExitCode, AppError> {
    let p = Problem::load(&a.problem)?;
    tune_problem_over(a, &p, &p)
}

/// [`tune_problem`] of the loaded problem `p`, its truth-model tune run on `over` (`p`
/// itself, or `p` shared among MPI ranks).
fn tune_problem_over(
    a: ProblemTune,
    p: &Problem,
    over: &dyn Experiment,
) -> Result<ExitCode, AppError> {
    commands::tune::check_outputs(p, &a.options)?;
    // The flag that asked for the start, for errors: --init, or --measurements (whose
    // record gives the default start).
    let asked_by = if a.init.is_some() {
        "--init"
    } else {
        "--measurements"
    };
    let start = |record: Option<&std::path::Path>, method: &str| {
        initial(p, &a.problem, record, method, asked_by).map(|s| {
            eprintln!("{}", s.note);
            s.theta
        })
    };
    let init = match (&a.init, &a.measurements) {
        (Some(m), _) if m == "problem" => None,
        // One record is one draw: the search starts where the evidence is, the maximum of
        // the likelihood on it, unless --init says otherwise.
        (None, Some(f)) => match start(Some(f.as_path()), "ml") {
            Ok(theta) => Some(theta),
            Err(e @ CommandError::Estimate { .. }) => {
                eprintln!("start: the problem's values ({e})");
                None
            }
            Err(e) => return Err(e.into()),
        },
        (None, None) => None,
        (Some(method), _) => {
            let record = a.init_record.as_ref().or(a.measurements.as_ref());
            Some(start(record.map(|r| r.as_path()), method)?)
        }
    };
    match &a.measurements {
        None => tune(over, &p.tune, a.options, init),
        Some(f) => {
            let measured = measured_experiment(p, &a.problem, f, a.reference.as_deref())?;
            let settings = p.tune.clone().with_nis_only(a.reference.is_none());
            tune(measured.as_ref(), &settings, a.options, init)
        }
    }
}

/// Run `check` on `experiment` and print its summary (or JSON): exit 0 if the filter
/// passes the gate, 1 if not; a truth that overflowed is an error after the report.
fn check(experiment: &dyn Experiment, o: CheckOptions) -> Result<ExitCode, AppError> {
    let run = if !o.quiet && std::io::stderr().is_terminal() {
        commands::check::check(experiment, &o, &CheckBar::new())?
    } else {
        commands::check::check(experiment, &o, &())?
    };
    print_check(experiment, &o, &run)
}

/// A check's summary or JSON on stdout, and its exit code.
fn print_check(
    experiment: &dyn Experiment,
    o: &CheckOptions,
    run: &commands::check::CheckRun,
) -> Result<ExitCode, AppError> {
    print_stdout(|stdout| {
        if o.json {
            stdout.write_all(run.json.as_bytes())?;
            writeln!(stdout)?;
        } else if !o.quiet {
            let name = &experiment.info().name;
            let mut text =
                check_summary(name, &run.params, &run.report, run.no_states, run.nis_only);
            text.push_str(&after_summary(
                run.seeds.as_ref(),
                o.config.is_some(),
                run.passes(),
                run.mc.alpha(),
            ));
            write_painted(stdout, &text, run.passes())?;
        }
        Ok(())
    })?;
    if run.report.verdict == Verdict::TruthOverflow {
        return Err(commands::check::truth_overflow(experiment, &run.report).into());
    }
    Ok(exit_code(run.passes()))
}

/// One shard of `check`: its chunks' sums written to `out`, a line on stdout.
fn shard(
    experiment: &dyn Experiment,
    o: &CheckOptions,
    share: crate::montecarlo::Share,
    out: &std::path::Path,
) -> Result<ExitCode, AppError> {
    let run = if !o.quiet && std::io::stderr().is_terminal() {
        commands::check::check_shard(experiment, o, share, out, &CheckBar::new())?
    } else {
        commands::check::check_shard(experiment, o, share, out, &())?
    };
    if !o.quiet {
        print_stdout(|stdout| writeln!(stdout, "{}", run.summary(&experiment.info().name)))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// `merge`: the shards judged as one check, printed as `check` prints.
fn merge(a: MergeArgs) -> Result<ExitCode, AppError> {
    let o = CheckOptions {
        config: None,
        mc: Default::default(),
        nis_only: false,
        json: a.json,
        report: a.report,
        junit: a.junit,
        engine: Default::default(),
        quiet: a.quiet,
        force: a.force,
        seeds: None,
    };
    let (problem, run) = commands::check::merge(&a.shards, &o)?;
    print_check(&problem, &o, &run)
}

/// Run `tune` on `experiment` from `defaults` and print its summary (or JSON): exit 0 if
/// the tuned filter passes its confirmation, 1 if not.
fn tune(
    experiment: &dyn Experiment,
    defaults: &TuneSettings,
    o: TuneOptions,
    init: Option<Vec<f64>>,
) -> Result<ExitCode, AppError> {
    let max_evals = o.settings(defaults).map_or(0, |s| s.max_evals());
    let progress = TuneProgress::new(
        max_evals,
        !o.quiet && std::io::stderr().is_terminal(),
        o.quiet,
    );
    let run = commands::tune::tune(experiment, defaults, &o, init, &progress);
    progress.finish();
    let run = run?;
    print_stdout(|stdout| {
        if o.json {
            writeln!(stdout, "{}", run.json)?;
        } else if !o.quiet {
            let text = crate::report::tune::tune_summary(
                &experiment.info().name,
                &run.result,
                &run.settings,
                &run.recommendations,
                &run.explanations,
                &run.config,
                run.report_dir.as_deref(),
            );
            write_painted(stdout, &text, run.consistent())?;
        }
        Ok(())
    })?;
    // A truth that overflows is the problem file's fault, as in `check`.
    if run.result.after.verdict == Verdict::TruthOverflow {
        return Err(commands::check::truth_overflow(experiment, &run.result.after).into());
    }
    Ok(exit_code(run.consistent()))
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
    interrupt::install();
    finish(run_for(experiment, tune, std::env::args_os()))
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
    let parsed = cmd.try_get_matches_from(args).and_then(|m| {
        note_inputs(&m);
        ModelCli::from_arg_matches(&m)
    });
    let cli = match parsed {
        Ok(c) => c,
        Err(e) => return usage_error(e, &program),
    };
    match cli.command {
        ModelCommand::Check(o) => check(experiment, o),
        ModelCommand::Tune(o) => self::tune(experiment, tune, o, None),
    }
}

/// The arguments (by their ids) whose values are files or directories a command writes:
/// `--out`, `--truth`, `--junit`, `--report`, `--sums-out`. Every other argument whose
/// value is a path names an input (`tests/cli/outputs.rs` holds every command's path arguments
/// to this: each is an output here or an input, and no output may name an input).
pub const OUTPUT_ARGS: [&str; 5] = ["out", "truth", "junit", "report", "sums_out"];

/// Note the file every input argument names (a path-valued argument not in
/// [`OUTPUT_ARGS`]) as an input of this process, before any work: no output may replace
/// it, however named ([`crate::input::note_input`]).
fn note_inputs(m: &clap::ArgMatches) {
    if let Some((_, sub)) = m.subcommand() {
        note_inputs(sub);
    }
    for id in m.ids() {
        if OUTPUT_ARGS.contains(&id.as_str()) {
            continue;
        }
        if let Ok(Some(paths)) = m.try_get_many::<PathBuf>(id.as_str()) {
            paths.for_each(|p| crate::input::note_input(p));
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verify_cli() {
        Cli::command().debug_assert();
        ModelCli::command().debug_assert();
    }

    #[test]
    fn a_check_and_a_merge_answer_with_their_exit_codes() {
        // The designer's guess of problems/cv1d.toml is inconsistent: exit 1, on 20 runs.
        let args = [
            "autotune",
            "check",
            "problems/cv1d.toml",
            "--quiet",
            "--runs",
            "20",
        ];
        assert_eq!(run(args).unwrap(), ExitCode::from(1));
        let args = [
            "autotune",
            "check",
            "problems/cv1d.toml",
            "--quiet",
            "--runs",
            "20",
            "--set",
            "q_accel=0.5",
            "--set",
            "r_pos=1.0",
        ];
        assert_eq!(run(args).unwrap(), ExitCode::SUCCESS);
        // Shards that are not there: a bad input, not a check.
        let merged = run(["autotune", "merge", "no/such/shard.json", "--quiet"]);
        assert!(matches!(merged, Err(AppError::Command(_))), "{merged:?}");
    }
}
