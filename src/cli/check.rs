//! `autotune check`.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use autotune::check::{Engine, accumulate_with_progress};
use autotune::problem::Problem;
use autotune::report::html::{check_html, check_markdown};
use autotune::report::{
    CheckOutput, junit_xml, summary_text, tuned::TunedConfig, write_atomic, write_report_dir,
};
use autotune::stats::ConsistencyReport;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum EngineArg {
    Auto,
    Linear,
    Generic,
}

#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// Problem file (TOML).
    problem: PathBuf,
    /// Tuned config whose parameter values replace the problem file's.
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    mc: super::McArgs,
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
    #[arg(long, value_enum, default_value = "auto")]
    engine: EngineArg,
    /// Print nothing; the exit code is the answer.
    #[arg(long, short)]
    quiet: bool,
}

pub fn run(a: CheckArgs) -> anyhow::Result<ExitCode> {
    let problem = Problem::load(&a.problem)?;
    let theta = match &a.config {
        Some(c) => TunedConfig::load_values(c, &problem.name, &problem.params)?,
        None => problem.params.values(),
    };
    let mut theta = theta;
    a.mc.set_params(&problem, &mut theta)?;
    let mc = a.mc.apply(problem.mc)?;
    let engine = match a.engine {
        EngineArg::Auto => Engine::Auto,
        EngineArg::Linear => Engine::Linear,
        EngineArg::Generic => Engine::Generic,
    };
    if engine == Engine::Linear && problem.linear().is_none() {
        anyhow::bail!(
            "{}: --engine linear: the problem is a nonlinear catalog model; use auto or generic",
            problem.path.display()
        );
    }
    // A progress bar with ETA on stderr, only on a terminal and only for runs long enough
    // to be worth one.
    // Nonlinear filters step about 100 times slower than the linear fast path.
    let long = if problem.linear().is_some() {
        20_000_000
    } else {
        200_000
    };
    let bar =
        (!a.quiet && std::io::stderr().is_terminal() && mc.runs * mc.steps >= long).then(|| {
            let b = ProgressBar::new(mc.runs as u64);
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
    let acc = accumulate_with_progress(&problem, &theta, &mc, engine, Some(&on_runs));
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let report = ConsistencyReport::from_accumulator(
        &acc,
        mc.alpha,
        &problem.state_names,
        &problem.measurement_names,
        !a.nis_only,
    );
    let params: Vec<(String, f64)> = problem
        .params
        .params
        .iter()
        .zip(&theta)
        .map(|(p, &v)| (p.name.clone(), v))
        .collect();

    if let Some(path) = &a.junit {
        write_atomic(path, junit_xml(&problem.name, &report).as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let out = CheckOutput {
        problem: &problem.name,
        file: problem.path.display().to_string(),
        problem_hash: &problem.hash,
        seed: mc.seed,
        params: params.clone(),
        report: &report,
        version: env!("CARGO_PKG_VERSION"),
    };
    let json = serde_json::to_string_pretty(&out)?;
    if let Some(dir) = &a.report {
        write_report_dir(
            dir,
            &check_html(&problem, &params, &report),
            &check_markdown(&problem, &params, &report),
            &json,
        )
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    }
    let mut stdout = std::io::stdout().lock();
    if a.json {
        stdout.write_all(json.as_bytes())?;
        writeln!(stdout)?;
    } else if !a.quiet {
        let text = summary_text(&problem.name, &params, &report);
        for line in text.lines() {
            if line.starts_with("verdict:") {
                writeln!(
                    stdout,
                    "{}",
                    super::paint_verdict(line, report.verdict.passes())
                )?;
            } else {
                writeln!(stdout, "{line}")?;
            }
        }
    }
    stdout.flush()?;
    Ok(if report.verdict.passes() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
