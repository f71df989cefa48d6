//! `tune`: search a consistent filter, write the tuned config and the report.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use indicatif::{ProgressBar, ProgressStyle};

use super::args::{McArgs, OneOf, flag_error, name_value, param_index};
use super::{AppError, paint_verdict, print_stdout};
use crate::experiment::{Experiment, Source};
use crate::input::FileError;
use crate::output::{Outputs, check_output_file, check_report_dir};
use crate::report::check::advice::recommendations;
use crate::report::check::html::tune_html;
use crate::report::tune::tuned::{rejected_config_toml, tuned_config_toml};
use crate::report::tune::{TuneReport, tune_markdown};
use crate::report::{fmt_fixed, fmt_g};
use crate::stats::{StatisticSummary, Verdict};
use crate::tune::{LocalSearch, Observer, Scoring, TuneError, TuneSettings, TuneStatus, tune};

/// The options of `tune`.
// The field docs are the command's help, where `<name>` is meant literally.
#[allow(rustdoc::invalid_html_tags)]
#[derive(Debug, Clone, clap::Args)]
pub struct TuneOptions {
    /// Where to write the tuned config (default: tuned/<name>.toml, or
    /// tuned/<name>.rejected.toml when the tuned filter fails its confirmation).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Write report.html, report.md and report.json into this directory.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    #[command(flatten)]
    mc: McArgs,
    /// Hold a parameter fixed, NAME or NAME=VALUE (repeatable).
    #[arg(long, value_name = "NAME[=VALUE]")]
    fix: Vec<String>,
    /// Set an objective weight, NAME=VALUE (mean, interval, per_step, components,
    /// whiteness, shape; repeatable).
    #[arg(long, value_name = "NAME=VALUE")]
    weight: Vec<String>,
    /// Score innovations only (ground truth not trusted).
    #[arg(long)]
    nis_only: bool,
    /// Evaluation budget of the search.
    #[arg(long, allow_negative_numbers = true)]
    max_evals: Option<usize>,
    /// Wall-time budget of the search, s.
    #[arg(long, allow_negative_numbers = true)]
    max_seconds: Option<f64>,
    /// How candidates are scored.
    #[arg(long, value_parser = OneOf::<Scoring>::new())]
    scoring: Option<Scoring>,
    /// Local search from the best global points: simplex (Nelder–Mead) or gauss_newton
    /// (Levenberg–Marquardt, for many expensive parameters).
    #[arg(long, value_parser = OneOf::<LocalSearch>::new())]
    local: Option<LocalSearch>,
    /// Seed of the first confirmation run.
    #[arg(long, allow_negative_numbers = true)]
    confirm_seed: Option<u64>,
    /// Number of fresh seeds the tuned filter is confirmed on (default 20; with
    /// --measurements the record is one draw, confirmed once).
    #[arg(long, allow_negative_numbers = true)]
    confirm_seeds: Option<usize>,
    /// Print the full report as JSON on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short, conflicts_with = "json")]
    quiet: bool,
}

/// Progress on stderr, only on a terminal; the search's notes on stderr unless quiet.
struct Progress {
    bar: Option<ProgressBar>,
    quiet: bool,
}

impl Observer for Progress {
    fn evaluation(&self, evals: usize, best: f64) {
        if let Some(b) = &self.bar {
            b.set_position(evals as u64);
            b.set_message(format!("best objective {best:.3e}"));
        }
    }

    fn phase(&self, name: &str) {
        if let Some(b) = &self.bar {
            b.set_prefix(name.to_string());
        }
    }

    fn note(&self, line: &str) {
        match &self.bar {
            Some(b) => b.println(format!("note: {line}")),
            None if !self.quiet => eprintln!("note: {line}"),
            None => {}
        }
    }
}

impl TuneOptions {
    /// `defaults` with the command line's settings applied.
    fn settings(&self, defaults: &TuneSettings) -> Result<TuneSettings, AppError> {
        let mut weights = Vec::with_capacity(self.weight.len());
        for kv in &self.weight {
            let (name, value) = kv
                .split_once('=')
                .ok_or_else(|| AppError::flag("--weight", format!("'{kv}' is not NAME=VALUE")))?;
            let v: f64 = value.trim().parse().map_err(|_| {
                AppError::flag("--weight", format!("{name}: '{value}' is not a number"))
            })?;
            weights.push((name.trim(), v));
        }
        let mut s = if weights.is_empty() {
            defaults.clone()
        } else {
            defaults
                .clone()
                .with_named_weights(weights)
                .map_err(flag_error("--weight"))?
        };
        if self.nis_only {
            s = s.with_nis_only(true);
        }
        if let Some(n) = self.max_evals {
            s = s.with_max_evals(n).map_err(flag_error("--max-evals"))?;
        }
        if let Some(v) = self.max_seconds {
            s = s.with_max_seconds(v).map_err(flag_error("--max-seconds"))?;
        }
        if let Some(x) = self.scoring {
            s = s.with_scoring(x);
        }
        if let Some(x) = self.local {
            s = s.with_local(x);
        }
        if let Some(k) = self.confirm_seeds {
            s = s
                .with_confirm_seeds(k)
                .map_err(flag_error("--confirm-seeds"))?;
        }
        Ok(s.with_confirm_seed(self.confirm_seed))
    }
}

/// Run `tune` on `experiment`, starting from the settings `defaults` (a problem file's
/// `[tune]`).
pub fn run(
    experiment: &dyn Experiment,
    defaults: &TuneSettings,
    a: TuneOptions,
) -> Result<ExitCode, AppError> {
    run_from(experiment, defaults, a, None)
}

/// [`run`] starting from `init` (one value per parameter, e.g. an estimate from recorded
/// measurements) instead of the parameters' configured values; `--set` and `--fix` still
/// apply on top, and a value outside a parameter's bounds is moved to the bound.
pub fn run_from(
    experiment: &dyn Experiment,
    defaults: &TuneSettings,
    a: TuneOptions,
    init: Option<Vec<f64>>,
) -> Result<ExitCode, AppError> {
    let info = experiment.info();
    let params = experiment.params();
    let settings = a.settings(defaults)?.with_from_estimate(init.is_some());
    let mut start = match init {
        Some(v) => v
            .iter()
            .zip(&params.params)
            .map(|(&x, p)| x.clamp(p.lower, p.upper))
            .collect(),
        None => params.values(),
    };
    // Which flag gave each value that is not the file's, for the bounds check below.
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
            return Err(AppError::flag(
                given[i].unwrap_or("--set"),
                format!(
                    "{} = {} is outside its bounds [{}, {}]",
                    p.name, start[i], p.lower, p.upper
                ),
            ));
        }
    }
    let mc = a.mc.apply(*experiment.mc())?;
    settings
        .search_runs_for(mc.runs())
        .map_err(|e| runs_error(e, experiment, a.mc.runs_given()))?;
    let tuned_path = PathBuf::from("tuned").join(format!("{}.toml", info.name));
    let rejected_path = tuned_path.with_file_name(format!("{}.rejected.toml", info.name));
    // Every output location is checked before the search, so a bad one costs no work;
    // without --out the config goes to one of two places, decided by the confirmation.
    match &a.out {
        Some(out) => check_output_file(out)?,
        None => {
            check_output_file(&tuned_path)?;
            check_output_file(&rejected_path)?;
        }
    }
    if let Some(dir) = &a.report {
        check_report_dir(dir)?;
    }

    let bar = (!a.quiet && std::io::stderr().is_terminal()).then(|| {
        let b = ProgressBar::new(settings.max_evals() as u64);
        b.set_style(
            ProgressStyle::with_template(
                "{prefix:>7} [{bar:30}] {pos}/{len} evals, {elapsed} (ETA {eta}) {msg}",
            )
            .expect("a valid template")
            .progress_chars("=> "),
        );
        b
    });
    let progress = Progress {
        bar,
        quiet: a.quiet,
    };
    let result = tune(experiment, &start, &fixed, &mc, &settings, &progress)
        .map_err(|e| tune_error(e, experiment, a.scoring.is_some()))?;
    // A misfit is explained before anything is written: its trials are searches too.
    let explanations = if crate::explain::needed(&result) {
        progress.phase("explain");
        crate::explain::explain(experiment, &result, &mc, &settings)
            .map_err(|e| tune_error(e, experiment, a.scoring.is_some()))?
    } else {
        Vec::new()
    };
    if let Some(b) = &progress.bar {
        b.finish_and_clear();
    }

    let consistent = result.status == TuneStatus::Consistent;
    // A run that did not confirm never replaces the config CI gates on; it goes beside it,
    // and a rejected config a later run supersedes is removed.
    let mut outputs = Outputs::new();
    let out = match &a.out {
        Some(out) => out.clone(),
        None if consistent => {
            outputs.remove_stale(&rejected_path);
            tuned_path
        }
        None => rejected_path,
    };
    let mut recs = recommendations(experiment, &result, &result.before);
    crate::report::check::advice::amend_for_explanation(&mut recs, &explanations);
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
    let json = serde_json::to_string_pretty(&report).expect("the report serializes");
    if let Some(dir) = &a.report {
        outputs.report_dir(
            dir,
            &tune_html(experiment, &result, &recs, &explanations),
            &tune_markdown(experiment, &result, &recs, &explanations),
            &json,
        );
    }
    outputs.commit()?;
    let code = if consistent {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    };
    print_stdout(|stdout| {
        if a.json {
            writeln!(stdout, "{json}")?;
        } else if !a.quiet {
            let scoring = if result.confirmation.recorded {
                "each scored on the recorded measurements".to_string()
            } else {
                format!("{} scoring", format!("{:?}", result.scoring).to_lowercase())
            };
            writeln!(
                stdout,
                "autotune tune {}: {} evaluations ({scoring}) in {:.2} s, {} diverged",
                info.name, result.evaluations, result.seconds, result.diverged_evaluations
            )?;
            if result.status == TuneStatus::BudgetExhausted {
                writeln!(
                    stdout,
                    "  the search stopped on its budget (--max-evals {}, --max-seconds {}): the values below are the best found so far",
                    settings.max_evals(),
                    settings.max_seconds()
                )?;
            }
            for r in &recs {
                writeln!(
                    stdout,
                    "  {}  [{} → {}]",
                    r.advice,
                    fmt_g(r.initial),
                    fmt_g(r.tuned)
                )?;
            }
            if result.confirmation.recorded {
                writeln!(
                    stdout,
                    "  (how precisely one record determines each value: `autotune estimate --method ml` gives standard errors)"
                )?;
            }
            if let Some(lines) =
                crate::report::check::advice::family_finding(&result, &explanations)
            {
                for l in lines {
                    writeln!(stdout, "  {l}")?;
                }
            }
            let line = |s: &StatisticSummary| {
                if s.steps_with_data == 0 {
                    return format!("A{} no data {}", s.name, s.verdict.label());
                }
                format!(
                    "A{} {} in [{}, {}] {}",
                    s.name,
                    fmt_fixed(s.time_average, 4),
                    fmt_fixed(s.interval.lower, 4),
                    fmt_fixed(s.interval.upper, 4),
                    s.verdict.label()
                )
            };
            let mut parts: Vec<String> = result.after.nees.iter().map(line).collect();
            parts.push(line(&result.after.nis));
            // The averages above can each be consistent while the gate fails on another
            // of its tests (per component, whiteness): say which, so that "fail the gate"
            // and "consistent" never stand on one line unexplained.
            if !result.after.verdict.passes() {
                parts.push(format!(
                    "the gate fails: {}",
                    result.after.verdict.describe()
                ));
            }
            if result.confirmation.recorded {
                writeln!(
                    stdout,
                    "  confirmation: {}: {}",
                    result.confirmation.text(),
                    parts.join("; ")
                )?;
            } else {
                writeln!(
                    stdout,
                    "  confirmation ({} runs × {} steps, seeds from {}): {}; first seed: {}",
                    result.runs,
                    result.steps,
                    result.confirm_seed,
                    result.confirmation.text(),
                    parts.join("; ")
                )?;
            }
            writeln!(stdout, "  wrote {}", out.display())?;
            if let Some(dir) = &a.report {
                writeln!(
                    stdout,
                    "  wrote {}/report.html, report.md, report.json",
                    dir.display()
                )?;
            }
            // The status rests on every confirmation seed, not on the first one's report
            // shown above: say what it rests on when the two could seem to disagree.
            let c = &result.confirmation;
            let stopped = matches!(
                result.after.verdict,
                Verdict::Diverged | Verdict::IllConditioned | Verdict::TruthOverflow
            );
            let after = if c.seeds > 1
                && !stopped
                && (c.passed < c.seeds || !result.after.verdict.passes())
            {
                format!(
                    "{} of {} fresh seeds consistent ({})",
                    c.passed,
                    c.seeds,
                    if c.holds() {
                        "as a consistent filter would be"
                    } else {
                        "fewer than a consistent filter"
                    }
                )
            } else {
                result.after.verdict.describe().to_string()
            };
            let verdict = format!(
                "verdict: before {}, after {after}",
                result.before.verdict.label(),
            );
            writeln!(stdout, "{}", paint_verdict(&verdict, consistent))?;
        }
        Ok(())
    })?;
    // A truth that overflows is the problem file's fault, as in `check`.
    if result.after.verdict == Verdict::TruthOverflow {
        return Err(super::check::truth_overflow(experiment, &result.after));
    }
    Ok(code)
}

/// The confirmation's run count `runs` is too large for the search's default 4 N runs:
/// an error of `--runs` if given, else of the problem file's `montecarlo.runs`.
fn runs_error(e: crate::input::SettingError, experiment: &dyn Experiment, flag: bool) -> AppError {
    match &experiment.info().source {
        Source::File { path, .. } if !flag => {
            FileError::from_setting(path, "montecarlo.", e).into()
        }
        _ => AppError::flag("--runs", e.message),
    }
}

/// A setting the tuner refused for this experiment, named where it was given: the flag,
/// or the problem file's `[tune]` field.
fn tune_error(e: TuneError, experiment: &dyn Experiment, from_flag: bool) -> AppError {
    match (e, &experiment.info().source) {
        (TuneError::Setting(s), _) if from_flag => {
            AppError::flag(&format!("--{}", s.setting.replace('_', "-")), s.message)
        }
        (TuneError::Setting(s), Source::File { path, .. }) => {
            FileError::from_setting(path, "tune.", s).into()
        }
        (TuneError::Experiment(e), _) => e.into(),
        (e, _) => AppError::Refused(e.to_string()),
    }
}
