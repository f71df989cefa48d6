//! `autotune check`.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use autotune::check::{Engine, check};
use autotune::problem::{Problem, ProblemError};
use autotune::report::{CheckOutput, junit_xml, summary_text, tuned::TunedConfig, write_atomic};

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
    /// Set a parameter, NAME=VALUE (repeatable; applied after --config).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
    /// Number of Monte Carlo runs N (overrides the file).
    #[arg(long)]
    runs: Option<usize>,
    /// Steps per run T (overrides the file).
    #[arg(long)]
    steps: Option<usize>,
    /// Base seed (overrides the file).
    #[arg(long)]
    seed: Option<u64>,
    /// Significance level α in (0, 1) (overrides the file).
    #[arg(long)]
    alpha: Option<f64>,
    /// Judge by NIS alone (ground truth not trusted).
    #[arg(long)]
    nis_only: bool,
    /// Print the full statistics as JSON on stdout instead of the summary.
    #[arg(long)]
    json: bool,
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

fn option_error(field: &str, message: String) -> ProblemError {
    ProblemError {
        file: PathBuf::from("<command line>"),
        field: field.into(),
        line: None,
        message,
    }
}

pub fn run(a: CheckArgs) -> anyhow::Result<ExitCode> {
    let problem = Problem::load(&a.problem)?;
    let theta = match &a.config {
        Some(c) => TunedConfig::load_values(c, &problem.params)?,
        None => problem.params.values(),
    };
    let mut theta = theta;
    for kv in &a.set {
        let (name, value) = kv
            .split_once('=')
            .ok_or_else(|| option_error("--set", format!("'{kv}' is not NAME=VALUE")))?;
        let i = problem.params.index(name.trim()).ok_or_else(|| {
            option_error(
                "--set",
                format!(
                    "unknown parameter '{name}' (known: {})",
                    problem.params.names().join(", ")
                ),
            )
        })?;
        let v: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v > 0.0)
            .ok_or_else(|| {
                option_error("--set", format!("{name}: '{value}' is not a number > 0"))
            })?;
        theta[i] = v;
    }
    let mut mc = problem.mc;
    if let Some(n) = a.runs {
        if n == 0 {
            return Err(option_error("--runs", "0 must be ≥ 1".into()).into());
        }
        mc.runs = n;
    }
    if let Some(t) = a.steps {
        if t == 0 {
            return Err(option_error("--steps", "0 must be ≥ 1".into()).into());
        }
        mc.steps = t;
    }
    if let Some(s) = a.seed {
        mc.seed = s;
    }
    if let Some(al) = a.alpha {
        if !(al > 0.0 && al < 1.0) {
            return Err(option_error("--alpha", format!("{al} must be in (0, 1)")).into());
        }
        mc.alpha = al;
    }
    let engine = match a.engine {
        EngineArg::Auto => Engine::Auto,
        EngineArg::Linear => Engine::Linear,
        EngineArg::Generic => Engine::Generic,
    };
    let report = check(&problem, &theta, &mc, engine, !a.nis_only);
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
    let mut stdout = std::io::stdout().lock();
    if a.json {
        let out = CheckOutput {
            problem: &problem.name,
            file: problem.path.display().to_string(),
            problem_hash: &problem.hash,
            seed: mc.seed,
            params,
            report: &report,
            version: env!("CARGO_PKG_VERSION"),
        };
        serde_json::to_writer_pretty(&mut stdout, &out)?;
        writeln!(stdout)?;
    } else if !a.quiet {
        write!(stdout, "{}", summary_text(&problem.name, &params, &report))?;
    }
    stdout.flush()?;
    Ok(if report.verdict.passes() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
