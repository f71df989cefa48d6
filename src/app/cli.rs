//! The command line's grammar: every command and its arguments, as clap parses them; what
//! each does is in [`super`] and [`crate::commands`].

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use crate::commands::check::CheckOptions;
use crate::commands::estimate::EstimateOptions;
use crate::commands::init::InitOptions;
use crate::commands::simulate::SimulateOptions;
use crate::commands::tune::TuneOptions;

/// Tune Kalman filter noise covariances until the filter is statistically consistent.
#[derive(Debug, Parser)]
#[command(name = "autotune", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub(super) command: Command,
}

// Parsed once per process: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub(super) enum Command {
    /// Monte Carlo consistency test (NEES/NIS against chi-square intervals); exit 0 if
    /// consistent, 1 if not, 2 on bad input.
    Check(ProblemCheck),
    /// Search the free Q/R parameters for a consistent filter; write a tuned config and a
    /// report; exit 0 if the tuned filter passes the confirmation, 1 if not.
    Tune(ProblemTune),
    /// Merge the sums files of every shard of a check (`check --shard I/N --sums-out FILE`)
    /// and judge them as one check: the same verdict, exit code, JSON and reports; exit 2 if
    /// the shards are not all there or not of one problem and settings.
    Merge(MergeArgs),
    /// Judge a filter's recorded innovations (a field log: PX4 ULog, CSV, JSON Lines) without
    /// ground truth: NIS per sensor against its chi-square interval, outliers, whiteness;
    /// exit 0 if consistent, 1 if not, 2 on bad input.
    Nis(super::nis::NisArgs),
    /// Draw measurements (and optionally the true states) from a problem's truth (a linear
    /// problem's or a catalog model's), to try `estimate` and `--measurements` on data whose
    /// answer is known.
    Simulate(SimulateOptions),
    /// Estimate a problem's free Q/R parameters from recorded measurements alone: maximum
    /// likelihood with standard errors (any filter autotune holds as code), or
    /// autocovariance least squares (a linear problem).
    Estimate(EstimateOptions),
    /// Write a commented starter problem file (NAME.toml) whose filter equals its truth, so
    /// `autotune check` passes on it; replace its parameter values with your own guesses.
    Init(InitOptions),
    /// Print a shell completion script on stdout, e.g.
    /// `autotune completions bash > ~/.local/share/bash-completion/completions/autotune`.
    Completions(super::completions::CompletionsArgs),
}

#[derive(Debug, clap::Args)]
pub(super) struct ProblemCheck {
    /// Problem file (TOML).
    #[arg(required_unless_present = "records")]
    pub(super) problem: Option<PathBuf>,
    /// Judge the records another program wrote instead of a problem file: CSV, NumPy
    /// (.npz, or .npy files named after their quantities) or JSON Lines; several files are
    /// one experiment (format: docs/src/records.md).
    #[arg(long, num_args = 1.., value_name = "FILE", conflicts_with_all = ["problem", "config", "runs", "steps", "seed", "set", "engine"])]
    pub(super) records: Vec<PathBuf>,
    /// Judge the problem's filter on recorded measurements instead of its truth model: the
    /// filter runs over the record (CSV, JSON Lines, NumPy; docs/src/measurements.md) and is
    /// judged by its innovations. A linear problem, a catalog model, or a worker that
    /// replays.
    #[arg(long, value_name = "FILE", requires = "problem", conflicts_with_all = ["runs", "steps", "seed", "engine"])]
    pub(super) measurements: Option<PathBuf>,
    /// The reference states recorded beside --measurements (RTK, motion capture, a
    /// simulator's log; x_1 … x_n a step, as `simulate --truth` writes them): NEES is judged
    /// too. A filter autotune holds (a linear problem or a catalog model).
    #[arg(long = "truth", value_name = "FILE", requires = "measurements")]
    pub(super) reference: Option<PathBuf>,
    /// Compute only shard I of N of the Monte Carlo (0-based: 0/3, 1/3 and 2/3 are the
    /// three shards of three; chunk c of 64 runs is shard c mod N's) and write its sums to
    /// --sums-out, for `autotune merge` to judge with the others (docs/src/cluster.md).
    #[arg(long, value_name = "I/N", value_parser = parse_share, requires = "sums_out", conflicts_with_all = ["records", "measurements", "report", "junit", "json"])]
    pub(super) shard: Option<crate::montecarlo::Share>,
    /// The shard's sums file (JSON; format: docs/src/cluster.md).
    #[arg(long, value_name = "FILE", requires = "shard")]
    pub(super) sums_out: Option<PathBuf>,
    #[command(flatten)]
    pub(super) options: CheckOptions,
}

/// `I/N` as a share: 0 ≤ I < N.
fn parse_share(s: &str) -> Result<crate::montecarlo::Share, String> {
    let bad = || format!("'{s}' is not I/N with 0 <= I < N (e.g. 0/3, 1/3, 2/3)");
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let (i, n) = (
        i.trim().parse().map_err(|_| bad())?,
        n.trim().parse().map_err(|_| bad())?,
    );
    crate::montecarlo::Share::new(i, n).map_err(|_| bad())
}

#[derive(Debug, clap::Args)]
pub(super) struct MergeArgs {
    /// Every shard's sums file, in any order.
    #[arg(required = true, value_name = "FILE")]
    pub(super) shards: Vec<PathBuf>,
    /// Print the full statistics as JSON on stdout instead of the summary.
    #[arg(long)]
    pub(super) json: bool,
    /// Write report.html, report.md and report.json into this directory.
    #[arg(long, value_name = "DIR")]
    pub(super) report: Option<PathBuf>,
    /// Also write a JUnit XML report to this file.
    #[arg(long, value_name = "FILE")]
    pub(super) junit: Option<PathBuf>,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short, conflicts_with = "json")]
    pub(super) quiet: bool,
    /// Replace output files autotune did not write (by default only its own files, which
    /// carry its mark, are replaced; an input is never replaced).
    #[arg(long)]
    pub(super) force: bool,
}

#[derive(Debug, clap::Args)]
pub(super) struct ProblemTune {
    /// Problem file (TOML).
    pub(super) problem: PathBuf,
    /// Tune against recorded measurements instead of the truth model: the filter runs over
    /// the record (CSV, JSON Lines, NumPy; docs/src/measurements.md) and candidates are scored by
    /// their innovations (NIS, per-component NIS, whiteness). A linear problem, a catalog
    /// model, or a worker that replays.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["runs", "steps", "seed"])]
    pub(super) measurements: Option<PathBuf>,
    /// The reference states recorded beside --measurements (x_1 … x_n a step, as
    /// `simulate --truth` writes them): candidates are scored by their errors (NEES) too.
    #[arg(long = "truth", value_name = "FILE", requires = "measurements")]
    pub(super) reference: Option<PathBuf>,
    /// Start the search from an estimate from measurements alone: ml (maximum likelihood)
    /// or als (autocovariance least squares), on --init-record, or else on --measurements,
    /// or else on a record simulated from the problem's truth (its runs × steps, another
    /// seed); or from the problem's values (problem). Linear problems. Default: ml with
    /// --measurements, the problem's values without.
    #[arg(long, value_name = "METHOD", value_parser = ["ml", "als", "problem"])]
    pub(super) init: Option<String>,
    /// The record --init estimates from.
    #[arg(long, value_name = "FILE", requires = "init")]
    pub(super) init_record: Option<PathBuf>,
    #[command(flatten)]
    pub(super) options: TuneOptions,
}

/// The commands a Rust model's own program has.
#[derive(Debug, Parser)]
#[command(version, about = "Check and tune this model's filter: Monte Carlo NEES/NIS consistency tests and a Q/R search (autotune).", long_about = None)]
pub(super) struct ModelCli {
    #[command(subcommand)]
    pub(super) command: ModelCommand,
}

#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub(super) enum ModelCommand {
    /// Monte Carlo consistency test (NEES/NIS against chi-square intervals); exit 0 if
    /// consistent, 1 if not, 2 on bad input.
    Check(CheckOptions),
    /// Search the free Q/R parameters for a consistent filter; write a tuned config and a
    /// report; exit 0 if the tuned filter passes the confirmation, 1 if not.
    Tune(TuneOptions),
}
