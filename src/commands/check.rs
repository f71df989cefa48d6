//! `check`: the Monte Carlo consistency gate on any experiment.

use std::path::PathBuf;

use super::{CommandError, McOverrides, OneOf};
use crate::check::{CheckProgress, check_with};
use crate::experiment::{Experiment, RunOptions, Source};
use crate::input::FileError;
use crate::montecarlo::{Engine, McConfig};
use crate::output::{Outputs, check_output_file, check_report_dir};
use crate::report::check::html::{check_html, check_markdown};
use crate::report::tune::tuned::TunedConfig;
use crate::report::{CheckOutput, junit_xml};
use crate::stats::{ConsistencyReport, Verdict};

/// The options of `check`.
#[derive(Debug, Clone, clap::Args)]
pub struct CheckOptions {
    /// Tuned config whose parameter values replace the problem file's.
    #[arg(long)]
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
}

impl CheckRun {
    /// Whether the filter passed the gate (exit code 0).
    pub fn passes(&self) -> bool {
        self.report.verdict.passes()
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
    let a = options;
    let info = experiment.info();
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
                info.source.label()
            ),
        ));
    }
    // Every output location is checked before the work, so a bad one costs no run.
    if let Some(path) = &a.junit {
        check_output_file(path)?;
    }
    if let Some(dir) = &a.report {
        check_report_dir(dir)?;
    }
    progress.start(mc.runs(), mc.steps(), experiment.supports(Engine::Linear));
    let on_runs = |done: usize| progress.runs_done(done);
    let run = RunOptions {
        engine: a.engine,
        progress: Some(&on_runs),
    };
    // Records or a worker without states (no ground truth) are judged by their innovations
    // alone, as documented, rather than found inconclusive for want of a NEES.
    let no_states = experiment.state_names().is_empty();
    let report = check_with(experiment, &theta, &mc, run, !a.nis_only && !no_states);
    progress.finish();
    let report = report?;
    let params: Vec<(String, f64)> = experiment
        .params()
        .params
        .iter()
        .zip(&theta)
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
    let json = serde_json::to_string_pretty(&out).expect("the report serializes");
    // The files are written together: all of them, or none.
    let mut outputs = Outputs::new();
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
        mc,
        json,
        no_states,
    })
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
