//! `autotune tune`.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use autotune::problem::Problem;
use autotune::report::advice::recommendations;
use autotune::report::html::tune_html;
use autotune::report::tune::{TuneReport, tune_markdown};
use autotune::report::tuned::tuned_config_toml;
use autotune::report::{fmt_g, write_atomic, write_report_dir};
use autotune::tune::{LocalSearch, Observer, Scoring, TuneSettings, TuneStatus, tune};
use indicatif::{ProgressBar, ProgressStyle};

use super::{McArgs, name_value, option_error};

#[derive(Debug, clap::Args)]
pub struct TuneArgs {
    /// Problem file (TOML).
    problem: PathBuf,
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
    #[arg(long)]
    max_evals: Option<usize>,
    /// Wall-time budget of the search, s.
    #[arg(long)]
    max_seconds: Option<f64>,
    /// How candidates are scored: auto, exact, monte_carlo.
    #[arg(long)]
    scoring: Option<String>,
    /// Local search from the best global points: simplex (Nelder–Mead) or gauss_newton
    /// (Levenberg–Marquardt, for many expensive parameters).
    #[arg(long)]
    local: Option<String>,
    /// Seed of the confirmation runs.
    #[arg(long)]
    confirm_seed: Option<u64>,
    /// Print the full report as JSON on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short)]
    quiet: bool,
}

/// Progress on stderr, only on a terminal.
struct Progress {
    bar: Option<ProgressBar>,
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
}

pub fn run(a: TuneArgs) -> anyhow::Result<ExitCode> {
    let problem = Problem::load(&a.problem)?;
    let mut settings = TuneSettings::default();
    settings
        .apply_spec(&problem.tune)
        .map_err(|e| autotune::problem::ProblemError {
            file: problem.path.clone(),
            field: match &e {
                autotune::tune::TuneError::Setting { field, .. } => field.clone(),
            },
            line: None,
            message: match &e {
                autotune::tune::TuneError::Setting { message, .. } => message.clone(),
            },
        })?;
    for kv in &a.weight {
        let (name, value) = kv
            .split_once('=')
            .ok_or_else(|| option_error("--weight", format!("'{kv}' is not NAME=VALUE")))?;
        let v: f64 = value
            .trim()
            .parse()
            .map_err(|_| option_error("--weight", format!("{name}: '{value}' is not a number")))?;
        settings
            .weights
            .set(name.trim(), v)
            .map_err(|m| option_error("--weight", m))?;
    }
    if a.nis_only {
        settings.nis_only = true;
    }
    if let Some(n) = a.max_evals {
        if n == 0 {
            return Err(option_error("--max-evals", "0 must be ≥ 1".into()).into());
        }
        settings.max_evals = n;
    }
    if let Some(s) = a.max_seconds {
        if !(s.is_finite() && s > 0.0) {
            return Err(option_error("--max-seconds", format!("{s} must be > 0")).into());
        }
        settings.max_seconds = s;
    }
    if let Some(s) = &a.scoring {
        settings.scoring = Scoring::parse(s).ok_or_else(|| {
            option_error(
                "--scoring",
                format!("unknown scoring '{s}' (known: auto, exact, monte_carlo)"),
            )
        })?;
    }
    if let Some(s) = &a.local {
        settings.local = LocalSearch::parse(s).ok_or_else(|| {
            option_error(
                "--local",
                format!("unknown local search '{s}' (known: simplex, gauss_newton)"),
            )
        })?;
    }
    settings.confirm_seed = a.confirm_seed;

    let mut start = problem.params.values();
    a.mc.set_params(&problem, &mut start)?;
    let mut fixed: Vec<bool> = problem.params.params.iter().map(|p| p.fixed).collect();
    for f in &a.fix {
        let i = if f.contains('=') {
            let (i, v) = name_value(&problem, "--fix", f)?;
            start[i] = v;
            i
        } else {
            problem.params.index(f.trim()).ok_or_else(|| {
                option_error(
                    "--fix",
                    format!(
                        "unknown parameter '{f}' (known: {})",
                        problem.params.names().join(", ")
                    ),
                )
            })?
        };
        fixed[i] = true;
    }
    for (i, p) in problem.params.params.iter().enumerate() {
        if !(p.lower..=p.upper).contains(&start[i]) {
            return Err(option_error(
                "--set",
                format!(
                    "{} = {} is outside its bounds [{}, {}]",
                    p.name, start[i], p.lower, p.upper
                ),
            )
            .into());
        }
    }
    let mc = a.mc.apply(problem.mc)?;
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("tuned").join(format!("{}.toml", problem.name)));

    let bar = (!a.quiet && std::io::stderr().is_terminal()).then(|| {
        let b = ProgressBar::new(settings.max_evals as u64);
        b.set_style(
            ProgressStyle::with_template(
                "{prefix:>7} [{bar:30}] {pos}/{len} evals, {elapsed} (ETA {eta}) {msg}",
            )
            .expect("a valid template")
            .progress_chars("=> "),
        );
        b
    });
    let progress = Progress { bar };
    let result = tune(&problem, &start, &fixed, &mc, &settings, &progress)
        .map_err(|e| option_error("tune", e.to_string()))?;
    if let Some(b) = &progress.bar {
        b.finish_and_clear();
    }

    // A run that did not confirm never replaces the config CI gates on; it goes beside it.
    let out = if a.out.is_none() && result.status != TuneStatus::Consistent {
        out.with_file_name(format!("{}.rejected.toml", problem.name))
    } else {
        out
    };
    let recs = recommendations(&problem, &result, &result.before);
    write_atomic(&out, tuned_config_toml(&problem, &result).as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    let report = TuneReport {
        problem: &problem.name,
        file: problem.path.display().to_string(),
        problem_hash: &problem.hash,
        version: env!("CARGO_PKG_VERSION"),
        result: &result,
        recommendations: &recs,
    };
    let json = serde_json::to_string_pretty(&report)?;
    if let Some(dir) = &a.report {
        write_report_dir(
            dir,
            &tune_html(&problem, &result, &recs),
            &tune_markdown(&problem, &result, &recs),
            &json,
        )
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    }
    let mut stdout = std::io::stdout().lock();
    if a.json {
        writeln!(stdout, "{json}")?;
    } else if !a.quiet {
        writeln!(
            stdout,
            "autotune tune {}: {} evaluations ({} scoring) in {:.2} s, {} diverged",
            problem.name,
            result.evaluations,
            format!("{:?}", result.scoring).to_lowercase(),
            result.seconds,
            result.diverged_evaluations
        )?;
        if result.status == TuneStatus::BudgetExhausted {
            writeln!(
                stdout,
                "  the search stopped on its budget (--max-evals {}, --max-seconds {}): the values below are the best found so far",
                settings.max_evals, settings.max_seconds
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
        let line = |s: &autotune::stats::StatisticSummary| {
            format!(
                "A{} {:.4} in [{:.4}, {:.4}] {}",
                s.name,
                s.time_average,
                s.interval.lower,
                s.interval.upper,
                s.verdict.label()
            )
        };
        let mut parts: Vec<String> = result.after.nees.iter().map(line).collect();
        parts.push(line(&result.after.nis));
        writeln!(
            stdout,
            "  confirmation on fresh seeds ({} runs × {} steps, seed {}): {}",
            result.runs,
            result.steps,
            result.confirm_seed,
            parts.join("; ")
        )?;
        writeln!(stdout, "  wrote {}", out.display())?;
        if let Some(dir) = &a.report {
            writeln!(
                stdout,
                "  wrote {}/report.html, report.md, report.json",
                dir.display()
            )?;
        }
        let verdict = format!(
            "verdict: before {}, after {}",
            result.before.verdict.label(),
            result.after.verdict.describe()
        );
        writeln!(
            stdout,
            "{}",
            super::paint_verdict(&verdict, result.status == TuneStatus::Consistent)
        )?;
    }
    stdout.flush()?;
    Ok(if result.status == TuneStatus::Consistent {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
