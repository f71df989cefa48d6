//! `check`: the Monte Carlo consistency gate on any experiment.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use indicatif::{ProgressBar, ProgressStyle};

use super::args::{McArgs, OneOf};
use super::{AppError, paint_verdict, print_stdout};
use crate::check::check_with;
use crate::experiment::{Experiment, RunOptions, Source};
use crate::input::FileError;
use crate::montecarlo::Engine;
use crate::output::{Outputs, check_output_file, check_report_dir};
use crate::report::check::html::{check_html, check_markdown};
use crate::report::tune::tuned::TunedConfig;
use crate::report::{CheckOutput, junit_xml, summary_text};
use crate::stats::{ConsistencyReport, Verdict};

/// The options of `check`.
#[derive(Debug, Clone, clap::Args)]
pub struct CheckOptions {
    /// Tuned config whose parameter values replace the problem file's.
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    mc: McArgs,
    /// Judge by NIS alone (ground truth not trusted).
    #[arg(long)]
    nis_only: bool,
    /// Print the full statistics as JSON on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Write report.html, report.md and report.json into this directory.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Also write a JUnit XML report to this file.
    #[arg(long, value_name = "FILE")]
    junit: Option<PathBuf>,
    /// Monte Carlo path (auto picks the fastest valid one).
    #[arg(long, default_value = "auto", value_parser = OneOf::<Engine>::new())]
    engine: Engine,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short, conflicts_with = "json")]
    quiet: bool,
}

impl CheckOptions {
    /// The same options judging by NIS alone (an experiment without truth).
    pub(super) fn nis_only(mut self) -> Self {
        self.nis_only = true;
        self
    }
}

/// Run `check` on `experiment`.
pub fn run(experiment: &dyn Experiment, a: CheckOptions) -> Result<ExitCode, AppError> {
    let info = experiment.info();
    let mut theta = match &a.config {
        Some(c) => TunedConfig::load_values(c, experiment)?,
        None => experiment.params().values(),
    };
    a.mc.set_params(experiment.params(), &mut theta)?;
    let mc = a.mc.apply(*experiment.mc())?;
    if !experiment.supports(a.engine) {
        return Err(AppError::flag(
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
    // A progress bar with ETA on stderr, only on a terminal and only for runs long enough
    // to be worth one; the linear fast path steps about 100 times faster than the others.
    let long = if experiment.supports(crate::montecarlo::Engine::Linear) {
        20_000_000
    } else {
        200_000
    };
    let bar = (!a.quiet
        && std::io::stderr().is_terminal()
        && mc.runs().saturating_mul(mc.steps()) >= long)
        .then(|| {
            let b = ProgressBar::new(mc.runs() as u64);
            b.set_style(
                ProgressStyle::with_template(
                    "check [{bar:30}] {pos}/{len} runs, {elapsed} (ETA {eta})",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            b
        });
    let on_runs = |done: usize| {
        if let Some(b) = &bar {
            b.set_position(done as u64);
        }
    };
    let options = RunOptions {
        engine: a.engine,
        progress: Some(&on_runs),
    };
    // Records or a worker without states (no ground truth) are judged by their innovations
    // alone, as documented, rather than found inconclusive for want of a NEES.
    let no_states = experiment.state_names().is_empty();
    let report = check_with(experiment, &theta, &mc, options, !a.nis_only && !no_states);
    let report = match report {
        Ok(r) => r,
        Err(e) => {
            if let Some(b) = &bar {
                b.finish_and_clear();
            }
            return Err(e.into());
        }
    };
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
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
    let code = if report.verdict.passes() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    };
    print_stdout(|stdout| {
        if a.json {
            stdout.write_all(json.as_bytes())?;
            writeln!(stdout)?;
        } else if !a.quiet {
            let text = summary_text(&info.name, &params, &report);
            for (i, line) in text.lines().enumerate() {
                if i == 1 && no_states && !a.nis_only {
                    writeln!(
                        stdout,
                        "  no states (no ground truth): judged by the innovations alone, NEES absent"
                    )?;
                }
                if line.starts_with("verdict:") {
                    writeln!(stdout, "{}", paint_verdict(line, report.verdict.passes()))?;
                } else {
                    writeln!(stdout, "{line}")?;
                }
            }
        }
        Ok(())
    })?;
    if report.verdict == Verdict::TruthOverflow {
        return Err(truth_overflow(experiment, &report));
    }
    Ok(code)
}

/// A truth that overflows over the horizon as the bad input it is (exit 2, one line naming
/// the file and the section that must change), after the report that shows it: nothing
/// about the filter was tested.
pub(super) fn truth_overflow(experiment: &dyn Experiment, report: &ConsistencyReport) -> AppError {
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
        Source::Program { name } => AppError::Refused(format!("{name}: {message}")),
        Source::Records { .. } => {
            AppError::Refused(format!("{}: {message}", experiment.info().source.label()))
        }
    }
}
