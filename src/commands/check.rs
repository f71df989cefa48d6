//! `check`: the Monte Carlo consistency gate on any experiment.

use std::path::{Path, PathBuf};

use super::{CommandError, McOverrides, OneOf};
use crate::check::{CheckProgress, SeedCheck, SeedChecks, Truth, check_seeds, judge};
use crate::cluster::shard::{self, CheckSetup, ShardFile};
use crate::cluster::share_sums;
use crate::experiment::{Experiment, RunOptions, Source};
use crate::input::FileError;
use crate::montecarlo::{Engine, McConfig, Share};
use crate::output::{Outputs, check_output_file, check_report_dir, write_file};
use crate::report::check::html::{check_html, check_markdown};
use crate::report::tuned::TunedConfig;
use crate::report::{CheckOutput, junit_xml};
use crate::rng::seed_at;
use crate::stats::{Accumulator, ConsistencyReport, Verdict};

/// The options of `check`.
#[derive(Debug, Clone, clap::Args)]
pub struct CheckOptions {
    /// Tuned config whose parameter values replace the problem file's.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Monte Carlo settings and parameter values in place of the experiment's.
    #[command(flatten)]
    pub mc: McOverrides,
    /// Judge by NIS alone (ground truth not trusted).
    #[arg(long)]
    pub nis_only: bool,
    /// Print the full statistics as JSON on stdout instead of the summary.
    #[arg(long)]
    pub json: bool,
    /// Write report.html, report.md and report.json into this directory.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Also write a JUnit XML report to this file.
    #[arg(long, value_name = "FILE")]
    pub junit: Option<PathBuf>,
    /// Monte Carlo path (auto picks the fastest valid one).
    #[arg(long, default_value = "auto", value_parser = OneOf::<Engine>::new())]
    pub engine: Engine,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short, conflicts_with = "json")]
    pub quiet: bool,
    /// Replace output files autotune did not write (by default only its own files, which
    /// carry its mark, are replaced; an input is never replaced).
    #[arg(long)]
    pub force: bool,
    /// Judge K independent seeds (the configured one and the K − 1 after it) as the tuner's
    /// confirmation does: exit 0 when as many pass as a consistent filter's would. The
    /// report, the JSON and the JUnit file are the first seed's.
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(2..=1000))]
    pub seeds: Option<u32>,
}

impl CheckOptions {
    /// The same options judging by NIS alone (an experiment without truth).
    pub fn with_nis_only(mut self) -> Self {
        self.nis_only = true;
        self
    }
}

/// What a check found, and what it wrote.
#[derive(Debug, Clone)]
pub struct CheckRun {
    /// The gate's report.
    pub report: ConsistencyReport,
    /// The parameter values the filter ran with, by name.
    pub params: Vec<(String, f64)>,
    /// The Monte Carlo settings it ran under.
    pub mc: McConfig,
    /// The report as JSON (what `--json` prints and `report.json` holds).
    pub json: String,
    /// Judged by the innovations alone because the experiment has no states (records or a
    /// worker without ground truth), not because `--nis-only` asked for it.
    pub no_states: bool,
    /// Judged by NIS alone because `--nis-only` asked for it (or the merged shards' check
    /// did).
    pub nis_only: bool,
    /// The checks on every seed `--seeds` asked for, the first seed's (`report`) first.
    pub seeds: Option<SeedChecks>,
}

impl CheckRun {
    /// Whether the filter passed (exit code 0): the gate on the one seed, or as many seeds
    /// as a consistent filter's would pass where `--seeds` asked for several.
    pub fn passes(&self) -> bool {
        match &self.seeds {
            Some(seeds) => seeds.passes(),
            None => self.report.verdict.passes(),
        }
    }
}

/// Run `check` on `experiment` with `options`: its Monte Carlo at the configured (or
/// overridden) parameter values, the gate, and the JUnit and report files asked for,
/// written together. A truth that overflowed is an error after the report is written
/// ([`truth_overflow`]): nothing about the filter was tested.
pub fn check(
    experiment: &dyn Experiment,
    options: &CheckOptions,
    progress: &dyn CheckProgress,
) -> Result<CheckRun, CommandError> {
    let (theta, mc) = prepare(experiment, options)?;
    progress.start(mc.runs(), mc.steps(), experiment.supports(Engine::Linear));
    let on_runs = |done: usize| progress.runs_done(done);
    let run = RunOptions {
        engine: options.engine,
        progress: Some(&on_runs),
        share: None,
    };
    let sums = experiment.monte_carlo_with(&theta, &mc, run);
    progress.finish();
    let mut run = conclude(experiment, options, &theta, &mc, &sums?)?;
    if let Some(k) = options.seeds {
        run.seeds = Some(later_seeds(
            experiment,
            options,
            &theta,
            &mc,
            &run.report,
            k,
        )?);
    }
    Ok(run)
}

/// The checks on `k` seeds from `mc`'s: the first is `first` (the check just made), the
/// others the seeds after it, as [`crate::check::check_seeds`] draws them.
fn later_seeds(
    experiment: &dyn Experiment,
    options: &CheckOptions,
    theta: &[f64],
    mc: &McConfig,
    first: &ConsistencyReport,
    k: u32,
) -> Result<SeedChecks, CommandError> {
    let truth = judged_by(experiment, options.nis_only);
    let next = mc.with_seed(seed_at(mc.seed(), 1));
    let mut seeds = check_seeds(experiment, theta, &next, truth, k as usize - 1)?;
    seeds.checks.insert(
        0,
        SeedCheck {
            seed: mc.seed(),
            report: first.clone(),
        },
    );
    Ok(seeds)
}

/// The parameter values and Monte Carlo settings `options` ask for on `experiment`, once
/// the engine and every output location are found usable: a bad one costs no run.
fn prepare(
    experiment: &dyn Experiment,
    options: &CheckOptions,
) -> Result<(Vec<f64>, McConfig), CommandError> {
    let a = options;
    let mut theta = match &a.config {
        Some(c) => TunedConfig::load_values(c, experiment)?,
        None => experiment.params().values(),
    };
    a.mc.set_params(experiment.params(), &mut theta)?;
    let mc = a.mc.apply(*experiment.mc())?;
    if !experiment.supports(a.engine) {
        return Err(CommandError::option(
            "--engine linear",
            format!(
                "{} has no linear fast path (its filter is nonlinear); use auto or generic",
                experiment.info().source.label()
            ),
        ));
    }
    check_outputs(a)?;
    Ok((theta, mc))
}

/// Check the files `--junit` and `--report` name, before any work.
fn check_outputs(a: &CheckOptions) -> Result<(), CommandError> {
    if let Some(path) = &a.junit {
        check_output_file(path, a.force).map_err(|e| e.of_flag("--junit"))?;
    }
    if let Some(dir) = &a.report {
        check_report_dir(dir, a.force).map_err(|e| e.of_flag("--report"))?;
    }
    Ok(())
}

/// What a check judges by: NEES and NIS, unless asked for NIS alone (`nis_only`) or the
/// experiment has no states. Records or a worker without states (no ground truth) are judged
/// by their innovations alone, as documented, rather than found inconclusive for want of a
/// NEES.
fn judged_by(experiment: &dyn Experiment, nis_only: bool) -> Truth {
    let no_states = experiment.state_names().is_empty();
    Truth::from_use_nees(!nis_only && !no_states)
}

/// The gate on `sums` (the Monte Carlo sums of `experiment` at `theta` under `mc`), and
/// the JUnit and report files `options` ask for, written together.
fn conclude(
    experiment: &dyn Experiment,
    options: &CheckOptions,
    theta: &[f64],
    mc: &McConfig,
    sums: &Accumulator,
) -> Result<CheckRun, CommandError> {
    let a = options;
    let info = experiment.info();
    let report = judge(experiment, sums, mc, judged_by(experiment, a.nis_only));
    let params: Vec<(String, f64)> = experiment
        .params()
        .params
        .iter()
        .zip(theta)
        .map(|(p, &v)| (p.name.clone(), v))
        .collect();
    let out = CheckOutput {
        problem: &info.name,
        file: info.source.label(),
        problem_hash: info.source.sha256(),
        seed: mc.seed(),
        params: params.clone(),
        report: &report,
        version: env!("CARGO_PKG_VERSION"),
    };
    let json = crate::output::marked_json(&out);
    // The files are written together: all of them, or none.
    let mut outputs = Outputs::replacing(a.force);
    if let Some(path) = &a.junit {
        outputs.file(path, junit_xml(&info.name, &report));
    }
    if let Some(dir) = &a.report {
        outputs.report_dir(
            dir,
            &check_html(experiment, &params, &report),
            &check_markdown(experiment, &params, &report),
            &json,
        );
    }
    outputs.commit()?;
    Ok(CheckRun {
        report,
        params,
        mc: *mc,
        json,
        no_states: experiment.state_names().is_empty(),
        nis_only: a.nis_only,
        seeds: None,
    })
}

/// What a shard of a check computed and where its sums went.
#[derive(Debug, Clone)]
pub struct ShardRun {
    /// The share computed.
    pub share: Share,
    /// Its chunks.
    pub chunks: Vec<usize>,
    /// Runs in them.
    pub runs: usize,
    /// Runs of the whole check.
    pub of_runs: usize,
    /// The file written.
    pub sums_out: PathBuf,
}

impl ShardRun {
    /// One line for the terminal.
    pub fn summary(&self, name: &str) -> String {
        let chunks = match self.chunks.as_slice() {
            [] => "no chunks".to_string(),
            [one] => format!("chunk {one}"),
            many => format!(
                "chunks {}",
                many.iter()
                    .map(|c| c.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        };
        format!(
            "{name}: shard {}/{}: {chunks} ({} of {} runs); sums in {} (merge every shard's file with `autotune merge`)",
            self.share.index(),
            self.share.count(),
            self.runs,
            self.of_runs,
            self.sums_out.display()
        )
    }
}

/// Run one shard of `check` on `experiment` (a problem file's): only `share`'s chunks of
/// the Monte Carlo, their sums written to `sums_out` with the settings that made them, for
/// `autotune merge` to judge with every other shard's.
pub fn check_shard(
    experiment: &dyn Experiment,
    options: &CheckOptions,
    share: Share,
    sums_out: &Path,
    progress: &dyn CheckProgress,
) -> Result<ShardRun, CommandError> {
    let (theta, mc) = prepare(experiment, options)?;
    let setup = CheckSetup {
        experiment,
        theta: &theta,
        mc: &mc,
        engine: options.engine,
        nis_only: options.nis_only,
    };
    let Some(settings) = setup.settings() else {
        return Err(CommandError::option(
            "--shard",
            format!(
                "{}: only a problem file's check runs in shards (merge reads the file again)",
                experiment.info().source.label()
            ),
        ));
    };
    check_output_file(sums_out, options.force).map_err(|e| e.of_flag("--sums-out"))?;
    progress.start(
        share.runs_of(mc.runs()),
        mc.steps(),
        experiment.supports(Engine::Linear),
    );
    let on_runs = |done: usize| progress.runs_done(done);
    let run = RunOptions {
        engine: options.engine,
        progress: Some(&on_runs),
        share: None,
    };
    let parts = share_sums(experiment, &theta, &mc, run, share);
    progress.finish();
    let parts = parts?;
    let file = ShardFile::new(settings, share, &parts);
    write_file(sums_out, file.to_json().as_bytes(), options.force)
        .map_err(|e| e.of_flag("--sums-out"))?;
    Ok(ShardRun {
        share,
        chunks: parts.iter().map(|(c, _)| *c).collect(),
        runs: share.runs_of(mc.runs()),
        of_runs: mc.runs(),
        sums_out: sums_out.to_path_buf(),
    })
}

/// `autotune merge`: the shard files' sums merged in chunk order and judged as `check`
/// judges, with the problem file the shards name read again (its SHA-256 must be theirs).
/// `options` gives the outputs (`--json`, `--report`, `--junit`); the settings come from
/// the shards. Returns the experiment (for the summary) with the run.
pub fn merge(
    files: &[PathBuf],
    options: &CheckOptions,
) -> Result<(crate::problem::Problem, CheckRun), CommandError> {
    let refused = |r: shard::MergeRefusal| FileError::new(&r.file, "shard", r.why.to_string());
    let heads = files
        .iter()
        .map(|f| shard::read_head(f))
        .collect::<Result<Vec<_>, _>>()
        .map_err(refused)?;
    let ordered = shard::plan(&heads).map_err(refused)?;
    let s = &heads[0].settings;
    // The problem the shards name: an error about it says which shard file named it.
    let problem = crate::problem::Problem::load(&s.file).map_err(|e| {
        FileError::new(
            &heads[0].path,
            "settings.file",
            format!("the problem file it names: {e}"),
        )
    })?;
    if problem.info().source.sha256() != Some(s.sha256.as_str()) {
        return Err(FileError::new(
            &s.file,
            "sha256",
            "the problem file changed since the shards were computed (its SHA-256 is not theirs)",
        )
        .into());
    }
    let setup = s
        .setup(&problem)
        .map_err(|why| FileError::new(&heads[0].path, "settings", why.to_string()))?;
    let options = CheckOptions {
        nis_only: s.nis_only,
        engine: setup.engine,
        ..options.clone()
    };
    check_outputs(&options)?;
    let sums = shard::merge_stream(&ordered, s).map_err(refused)?;
    let run = conclude(&problem, &options, &setup.theta, &setup.mc, &sums)?;
    Ok((problem, run))
}

/// A truth that overflowed over the horizon (the report's verdict
/// [`Verdict::TruthOverflow`]) as the bad input it is: one line naming the file and the
/// section that must change, or the program or records.
pub fn truth_overflow(experiment: &dyn Experiment, report: &ConsistencyReport) -> CommandError {
    debug_assert_eq!(report.verdict, Verdict::TruthOverflow);
    let first = report
        .divergences
        .first()
        .map(|d| format!(" (first: run {}, {})", d.run, d.reason))
        .unwrap_or_default();
    let message = format!(
        "the truth overflowed in {} of {} runs{first}; use fewer steps or a stable model",
        report.diverged_runs, report.runs
    );
    match &experiment.info().source {
        Source::File { path, .. } => {
            // A linear problem's truth is its [truth]; a catalog model's, its [model].
            let field = if experiment.supports(Engine::Linear) {
                "truth"
            } else {
                "model"
            };
            FileError::new(path, field, message).into()
        }
        Source::Program { name } => CommandError::TruthOverflow {
            subject: name.clone(),
            message,
        },
        Source::Records { .. } => CommandError::TruthOverflow {
            subject: experiment.info().source.label(),
            message,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tune::tests::Mock;

    fn options(seeds: Option<u32>) -> CheckOptions {
        CheckOptions {
            config: None,
            mc: McOverrides::default(),
            nis_only: false,
            json: false,
            report: None,
            junit: None,
            engine: Engine::Auto,
            quiet: true,
            force: false,
            seeds,
        }
    }

    #[test]
    fn seeds_are_judged_together_from_the_first_checks_seed() {
        // The mock starts at θ = 1: consistent where its truth is 1, not where it is 2.
        let good = Mock::new(&[1.0], &[&[1.0]]);
        let one = check(&good, &options(None), &()).unwrap();
        assert!(one.seeds.is_none() && one.passes());
        let run = check(&good, &options(Some(4)), &()).unwrap();
        let seeds = run.seeds.as_ref().unwrap();
        let first = good.mc().seed();
        let got: Vec<u64> = seeds.checks.iter().map(|c| c.seed).collect();
        assert_eq!(got, [first, first + 1, first + 2, first + 3]);
        assert_eq!(seeds.checks[0].report.verdict, run.report.verdict);
        assert!(run.passes());
        let bad = Mock::new(&[2.0], &[&[1.0]]);
        let run = check(&bad, &options(Some(4)), &()).unwrap();
        assert_eq!(run.seeds.as_ref().unwrap().passed(), 0);
        assert!(!run.passes());
    }

    #[test]
    fn a_check_judges_by_nees_where_there_are_states_and_it_is_not_told_otherwise() {
        let with_states = Mock::new(&[1.0], &[&[1.0]]);
        assert_eq!(judged_by(&with_states, false), Truth::Known);
        assert_eq!(judged_by(&with_states, true), Truth::Unknown);
        let no_states = Mock::new(&[1.0], &[&[1.0]]).measuring();
        assert!(no_states.state_names().is_empty());
        assert_eq!(judged_by(&no_states, false), Truth::Unknown);
        assert_eq!(judged_by(&no_states, true), Truth::Unknown);
    }
}
