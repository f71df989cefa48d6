//! `tune`: search a consistent filter, explain a misfit, write the tuned (or rejected)
//! config and the report.

use std::path::PathBuf;

use super::options::{name_value, param_index};
use super::{CommandError, McOverrides};
use crate::experiment::{Experiment, Source};
use crate::explain::Explanation;
use crate::input::FileError;
use crate::montecarlo::McConfig;
use crate::output::{Outputs, check_output_file, check_report_dir};
use crate::report::advice::{Recommendation, amend_for_explanation, recommendations};
use crate::report::tune::html::tune_html;
use crate::report::tune::{TuneReport, tune_markdown};
use crate::report::tuned::{rejected_config_toml, tuned_config_toml};
use crate::tune::{
    Observer, TuneError, TuneResult, TuneSettings, TuneSpec, TuneStatus, tune as search,
};

/// The options of `tune`.
// The field docs are the command's help, where `<name>` is meant literally.
#[allow(rustdoc::invalid_html_tags)]
#[derive(Debug, Clone, clap::Args)]
pub struct TuneOptions {
    /// Where to write the tuned config (default: tuned/<name>.toml, or
    /// tuned/<name>.rejected.toml when the tuned filter fails its confirmation).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Write report.html, report.md and report.json into this directory.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Monte Carlo settings and parameter values in place of the experiment's.
    #[command(flatten)]
    pub mc: McOverrides,
    /// Hold a parameter fixed, NAME or NAME=VALUE (repeatable).
    #[arg(long, value_name = "NAME[=VALUE]")]
    pub fix: Vec<String>,
    /// The search's settings, over the problem file's `[tune]`.
    #[command(flatten)]
    pub settings: TuneSpec,
    /// Print the full report as JSON on stdout instead of the summary.
    #[arg(long)]
    pub json: bool,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short, conflicts_with = "json")]
    pub quiet: bool,
    /// Replace output files autotune did not write (by default only its own files, which
    /// carry its mark, are replaced; an input is never replaced).
    #[arg(long)]
    pub force: bool,
}

impl TuneOptions {
    /// `defaults` (a problem file's `[tune]`) with the command line's settings laid over
    /// them; a refusal names the flag.
    pub fn settings(&self, defaults: &TuneSettings) -> Result<TuneSettings, CommandError> {
        self.settings
            .apply(defaults.clone())
            .map_err(|e| CommandError::option(&TuneSpec::flag(&e.setting), e.message))
    }
}

/// What a tuning run found, and what it wrote.
#[derive(Debug, Clone)]
pub struct TuneRun {
    /// The search, its confirmation and resolution.
    pub result: TuneResult,
    /// The per-parameter advice (amended by the first explanation of a misfit).
    pub recommendations: Vec<Recommendation>,
    /// Why no Q and R fit, ranked; empty when the tuned filter is consistent.
    pub explanations: Vec<Explanation>,
    /// The settings the search ran with.
    pub settings: TuneSettings,
    /// Where the tuned (or rejected) config was written.
    pub config: PathBuf,
    /// The report directory written, if asked for.
    pub report_dir: Option<PathBuf>,
    /// The report as JSON (what `--json` prints and `report.json` holds).
    pub json: String,
}

impl TuneRun {
    /// Whether the tuned filter passed its confirmation (exit code 0).
    pub fn consistent(&self) -> bool {
        self.result.status == TuneStatus::Consistent
    }
}

/// The parameters' start values and which are held fixed: `init` (one value per
/// parameter, e.g. an estimate from recorded measurements, moved into each parameter's
/// bounds) or the configured values, with `--set` and `--fix` applied on top.
fn start(
    experiment: &dyn Experiment,
    a: &TuneOptions,
    init: Option<Vec<f64>>,
) -> Result<(Vec<f64>, Vec<bool>), CommandError> {
    let params = experiment.params();
    let mut start = match init {
        Some(v) => v
            .iter()
            .zip(&params.params)
            .map(|(&x, p)| x.clamp(p.lower, p.upper))
            .collect(),
        None => params.values(),
    };
    // Which option gave each value that is not the file's, for the bounds check below.
    let mut given: Vec<Option<&str>> = vec![None; start.len()];
    for i in a.mc.set_params(params, &mut start)? {
        given[i] = Some("--set");
    }
    let mut fixed: Vec<bool> = params.params.iter().map(|p| p.fixed).collect();
    for f in &a.fix {
        let i = if f.contains('=') {
            let (i, v) = name_value(params, "--fix", f)?;
            start[i] = v;
            given[i] = Some("--fix");
            i
        } else {
            param_index(params, "--fix", f)?
        };
        fixed[i] = true;
    }
    for (i, p) in params.params.iter().enumerate() {
        if !(p.lower..=p.upper).contains(&start[i]) {
            return Err(CommandError::option(
                given[i].unwrap_or("--set"),
                format!(
                    "{} = {} is outside its bounds [{}, {}]",
                    p.name, start[i], p.lower, p.upper
                ),
            ));
        }
    }
    Ok((start, fixed))
}

/// Where the config goes: `--out`, else `tuned/<name>.toml` when the tuned filter is
/// consistent and `tuned/<name>.rejected.toml` when not.
fn config_paths(experiment: &dyn Experiment) -> (PathBuf, PathBuf) {
    let name = &experiment.info().name;
    let tuned = PathBuf::from("tuned").join(format!("{name}.toml"));
    let rejected = tuned.with_file_name(format!("{name}.rejected.toml"));
    (tuned, rejected)
}

/// Check every output location `options` name (or imply: without `--out`, the config goes
/// to one of two places, decided by the confirmation), so that a bad one costs no work:
/// call it before anything else is computed (the command line does, before an estimate of
/// the start).
pub fn check_outputs(
    experiment: &dyn Experiment,
    options: &TuneOptions,
) -> Result<(), CommandError> {
    let a = options;
    match &a.out {
        Some(out) => check_output_file(out, a.force).map_err(|e| e.of_flag("--out"))?,
        None => {
            let (tuned_path, rejected_path) = config_paths(experiment);
            check_output_file(&tuned_path, a.force)?;
            check_output_file(&rejected_path, a.force)?;
        }
    }
    if let Some(dir) = &a.report {
        check_report_dir(dir, a.force).map_err(|e| e.of_flag("--report"))?;
    }
    Ok(())
}

/// Run `tune` on `experiment` from the settings `defaults` (a problem file's `[tune]`) with
/// `options` on top, starting from `init` (one value per parameter) where given instead of
/// the parameters' configured values. A misfit is explained before anything is written;
/// the config and the report files are written together. `observer` is told the search's
/// progress.
pub fn tune(
    experiment: &dyn Experiment,
    defaults: &TuneSettings,
    options: &TuneOptions,
    init: Option<Vec<f64>>,
    observer: &dyn Observer,
) -> Result<TuneRun, CommandError> {
    let a = options;
    let info = experiment.info();
    let settings = a.settings(defaults)?.with_from_estimate(init.is_some());
    let (start, fixed) = start(experiment, a, init)?;
    let mc = a.mc.apply(*experiment.mc())?;
    settings
        .search_runs_for(mc.runs())
        .map_err(|e| runs_error(e, experiment, a.mc.runs_given()))?;
    let (tuned_path, rejected_path) = config_paths(experiment);
    check_outputs(experiment, a)?;
    let (result, explanations) =
        search_and_explain(experiment, &start, &fixed, &mc, &settings, a, observer)?;
    let consistent = result.status == TuneStatus::Consistent;
    // A run that did not confirm never replaces the config CI gates on; it goes beside it,
    // and a rejected config a later run supersedes is removed.
    let mut outputs = Outputs::replacing(a.force);
    let out = match &a.out {
        Some(out) => out.clone(),
        None if consistent => {
            outputs.remove_stale(&rejected_path);
            tuned_path
        }
        None => rejected_path,
    };
    let mut recs = recommendations(experiment, &result, &result.before);
    amend_for_explanation(&mut recs, &explanations);
    outputs.file(
        &out,
        if consistent {
            tuned_config_toml(experiment, &result)
        } else {
            rejected_config_toml(experiment, &result, &explanations)
        },
    );
    let report = TuneReport {
        problem: &info.name,
        file: info.source.label(),
        problem_hash: info.source.sha256(),
        version: env!("CARGO_PKG_VERSION"),
        result: &result,
        recommendations: &recs,
        explanations: &explanations,
    };
    let json = crate::output::marked_json(&report);
    if let Some(dir) = &a.report {
        outputs.report_dir(
            dir,
            &tune_html(experiment, &result, &recs, &explanations),
            &tune_markdown(experiment, &result, &recs, &explanations),
            &json,
        );
    }
    outputs.commit()?;
    Ok(TuneRun {
        result,
        recommendations: recs,
        explanations,
        settings,
        config: out,
        report_dir: a.report.clone(),
        json,
    })
}

/// The search, and where the tuned filter fails, the explanations of the misfit (their
/// trials are searches too).
fn search_and_explain(
    experiment: &dyn Experiment,
    start: &[f64],
    fixed: &[bool],
    mc: &McConfig,
    settings: &TuneSettings,
    a: &TuneOptions,
    observer: &dyn Observer,
) -> Result<(TuneResult, Vec<Explanation>), CommandError> {
    let from_flag = a.settings.scoring.is_some();
    let result = search(experiment, start, fixed, mc, settings, observer)
        .map_err(|e| tune_error(e, experiment, from_flag))?;
    let explanations = if crate::explain::needed(&result) {
        observer.phase("explain");
        crate::explain::explain(experiment, &result, mc, settings)
            .map_err(|e| tune_error(e, experiment, from_flag))?
    } else {
        Vec::new()
    };
    Ok((result, explanations))
}

/// The confirmation's run count `runs` is too large for the search's default 4 N runs:
/// an error of `--runs` if given, else of the problem file's `montecarlo.runs`.
fn runs_error(
    e: crate::input::SettingError,
    experiment: &dyn Experiment,
    flag: bool,
) -> CommandError {
    match &experiment.info().source {
        Source::File { path, .. } if !flag => {
            FileError::from_setting(path, "montecarlo.", e).into()
        }
        _ => CommandError::option("--runs", e.message),
    }
}

/// A setting the tuner refused for this experiment, named where it was given: the option,
/// or the problem file's `[tune]` field.
fn tune_error(e: TuneError, experiment: &dyn Experiment, from_flag: bool) -> CommandError {
    match (e, &experiment.info().source) {
        (TuneError::Setting(s), _) if from_flag => {
            CommandError::option(&format!("--{}", s.setting.replace('_', "-")), s.message)
        }
        (TuneError::Setting(s), Source::File { path, .. }) => {
            FileError::from_setting(path, "tune.", s).into()
        }
        (TuneError::Experiment(e), _) => e.into(),
        (e, _) => CommandError::Tune(e),
    }
}
