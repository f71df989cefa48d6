//! `estimate`: Q and R estimated from recorded measurements alone, and the pieces `tune`
//! uses to run on a record (`--measurements`) or to start from an estimate (`--init`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use super::args::name_value;
use super::{AppError, print_stdout};
use crate::estimate::als::{self, AlsModel, FullMatrix};
use crate::estimate::{MeasuredExperiment, Measurements, ml, read_measurements, simulate};
use crate::experiment::{Experiment, LinearExperiment};
use crate::input::FileError;
use crate::problem::Problem;
use crate::report::tuned::estimated_config_toml;
use crate::report::{Outputs, check_output_file, fmt_g};

/// The arguments of `estimate`.
#[derive(Debug, Clone, clap::Args)]
pub struct EstimateArgs {
    /// Problem file (TOML) whose linear [filter] has the parameters to estimate.
    problem: PathBuf,
    /// The recorded measurements: .csv, .jsonl, .npy or .npz (docs/measurements.md).
    #[arg(long, value_name = "FILE")]
    measurements: PathBuf,
    /// Estimation method: ml (maximum likelihood over the filter's innovations) or als
    /// (autocovariance least squares from the innovations of the filter at the start values).
    #[arg(long, default_value = "ml", value_parser = ["ml", "als"])]
    method: String,
    /// ALS: autocovariance lags L (0 … L − 1).
    #[arg(long, default_value_t = 15)]
    lags: usize,
    /// ALS: passes, each with the gain of the filter at the previous estimate (1: the start
    /// values' gain only).
    #[arg(long, default_value_t = 2)]
    passes: usize,
    /// ALS: estimate Q (the covariance of the problem's process noise inputs), R, or both
    /// (qr) as full matrices constrained positive semidefinite, instead of the problem's
    /// parameters (a build with the `sdp` feature).
    #[arg(long, value_name = "q|r|qr", value_parser = ["q", "r", "qr"])]
    full: Option<String>,
    /// Start a parameter at NAME=VALUE instead of the problem's value (repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
    /// L-BFGS iteration limit.
    #[arg(long, default_value_t = 200)]
    max_iterations: u64,
    /// Also write the estimate as a config `autotune check PROBLEM --config FILE` reads.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Print the estimate as JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// Write `theta` as a config to `out`, with where it came from.
fn write_config(
    p: &Problem,
    out: &std::path::Path,
    theta: &[f64],
    method: &str,
    record: &std::path::Path,
    score: (&str, f64),
) -> Result<(), AppError> {
    let mut prov = toml::Table::new();
    prov.insert("autotune_version".into(), env!("CARGO_PKG_VERSION").into());
    prov.insert("method".into(), method.into());
    prov.insert("measurements".into(), record.display().to_string().into());
    prov.insert(score.0.into(), score.1.into());
    let mut outputs = Outputs::new();
    outputs.file(out, estimated_config_toml(p, theta, prov));
    outputs.commit()?;
    Ok(())
}

pub(super) fn linear<'a>(
    p: &'a Problem,
    path: &std::path::Path,
    what: &str,
) -> Result<&'a LinearExperiment, AppError> {
    p.linear().ok_or_else(|| {
        // Name what the problem is, so the user knows which section is the obstacle.
        let (field, kind) = if p.catalog().is_some() {
            ("model", "a catalog model ([model])")
        } else {
            ("external", "an external worker ([external])")
        };
        FileError::new(
            path,
            field,
            format!("{what} works on a linear problem ([truth] and [filter] matrices); this one is {kind}"),
        )
        .into()
    })
}

/// Refuse a record no estimate can come from: no measured value at all, or a single step
/// (one innovation says nothing about how Q and R split), which would otherwise leave the
/// start values standing as if they were estimates.
fn estimable(file: &std::path::Path, data: &Measurements) -> Result<(), AppError> {
    if data.values() == 0 {
        return Err(FileError::new(
            file,
            "z",
            "no measured values (every component is empty): nothing to estimate from",
        )
        .into());
    }
    let steps: usize = data.sequences.iter().map(|s| s.steps).sum();
    if steps < 2 {
        return Err(FileError::new(
            file,
            "z",
            "a single step: Q and R need at least two steps of measurements",
        )
        .into());
    }
    Ok(())
}

/// The filter of problem `p` (file `path`) over the measurement record `file`, as an
/// experiment `check` and `tune` can judge by its innovations.
pub fn measured_experiment(
    p: &Problem,
    path: &std::path::Path,
    file: &std::path::Path,
) -> Result<MeasuredExperiment, AppError> {
    let lin = linear(p, path, "--measurements")?;
    let data = read_measurements(file)?;
    let m = lin.filter.H.nrows();
    if data.dim != m {
        return Err(FileError::new(
            file,
            "z",
            format!(
                "{} components per step, but {} measures {m}",
                data.dim,
                p.name()
            ),
        )
        .into());
    }
    MeasuredExperiment::new(lin, data)
        .map_err(|e| FileError::new(file, "", format!("{}: {}", e.setting, e.message)).into())
}

/// The start `tune --init METHOD` searches from: the estimate of `method` ("ml" or "als")
/// on `record`, or on a record simulated from `p`'s truth (its Monte Carlo runs × steps,
/// with another seed than the search's so that the start does not fit the search's noise).
/// Says on stderr where the start came from.
pub fn initial(
    p: &Problem,
    path: &std::path::Path,
    record: Option<&std::path::Path>,
    method: &str,
) -> Result<Vec<f64>, AppError> {
    let lin = linear(p, path, "--init")?;
    let m = lin.filter.H.nrows();
    let (data, origin) = match record {
        Some(f) => {
            let d = read_measurements(f)?;
            if d.dim != m {
                return Err(FileError::new(
                    f,
                    "z",
                    format!(
                        "{} components per step, but {} measures {m}",
                        d.dim,
                        p.name()
                    ),
                )
                .into());
            }
            estimable(f, &d)?;
            (d, f.display().to_string())
        }
        None => {
            let mc = p.mc();
            let seed = mc.seed().wrapping_add(INIT_SEED_OFFSET);
            let sim = simulate(&lin.truth, lin.truth.n_z(), mc.runs(), mc.steps(), seed);
            (
                sim.measurements,
                format!(
                    "{} × {} steps simulated from the truth (seed {seed})",
                    mc.runs(),
                    mc.steps()
                ),
            )
        }
    };
    let params = p.params();
    let start = params.values();
    let fixed: Vec<bool> = params.params.iter().map(|d| d.fixed).collect();
    let t0 = Instant::now();
    let theta = if method == "als" {
        let model = AlsModel::of(lin);
        als::estimate_passes(&model, &data, &start, &fixed, 15, 2)
            .map_err(|m| AppError::Refused(format!("--init als on {origin}: {m}")))?
            .theta
    } else {
        let build = |theta: &[f64]| lin.filter_at(theta);
        ml::estimate(&build, &data, &start, &fixed, 200)
            .map_err(|m| AppError::Refused(format!("--init ml on {origin}: {m}")))?
            .theta
    };
    let shown: Vec<String> = params
        .params
        .iter()
        .zip(&theta)
        .map(|(d, v)| format!("{} = {}", d.name, fmt_g(*v)))
        .collect();
    eprintln!(
        "start: {method} estimate from {origin} in {:.3} s: {}",
        t0.elapsed().as_secs_f64(),
        shown.join(", ")
    );
    Ok(theta)
}

/// Added to the problem's seed for the record `tune --init` simulates.
const INIT_SEED_OFFSET: u64 = 0x5eed_1417;

/// Run `estimate`.
pub fn run_estimate(a: EstimateArgs) -> Result<ExitCode, AppError> {
    let p = Problem::load(&a.problem)?;
    let lin = linear(&p, &a.problem, "estimate")?;
    let data = read_measurements(&a.measurements)?;
    let m = lin.filter.H.nrows();
    if data.dim != m {
        return Err(FileError::new(
            &a.measurements,
            "z",
            format!(
                "{} components per step, but {} measures {m}",
                data.dim,
                p.name()
            ),
        )
        .into());
    }
    estimable(&a.measurements, &data)?;
    if let Some(out) = &a.out {
        check_output_file(out)?;
    }
    let params = p.params();
    let mut start = params.values();
    for kv in &a.set {
        let (i, v) = name_value(params, "--set", kv)?;
        start[i] = v;
    }
    let fixed: Vec<bool> = params.params.iter().map(|d| d.fixed).collect();
    let build = |theta: &[f64]| lin.filter_at(theta);
    if a.method == "als" {
        if !(1..=200).contains(&a.lags) {
            return Err(AppError::flag(
                "--lags",
                format!("{} is not in 1..=200", a.lags),
            ));
        }
        let model = AlsModel::of(lin);
        if !(1..=20).contains(&a.passes) {
            return Err(AppError::flag(
                "--passes",
                format!("{} is not in 1..=20", a.passes),
            ));
        }
        if let Some(full) = &a.full {
            if a.out.is_some() {
                return Err(AppError::flag(
                    "--out",
                    "a full Q or R is not one of the problem's parameters, so there is no config to write; --json gives the matrices",
                ));
            }
            let full = FullMatrix::parse(full).expect("clap allows q, r and qr only");
            return super::estimate_full::run(
                &p,
                &a.measurements,
                &data,
                &model,
                &start,
                &fixed,
                full,
                a.lags,
                a.passes,
                a.json,
            );
        }
        let t0 = Instant::now();
        let est = als::estimate_passes(&model, &data, &start, &fixed, a.lags, a.passes)
            .map_err(|m| AppError::Refused(format!("{}: {m}", a.measurements.display())))?;
        let took = t0.elapsed().as_secs_f64();
        if let Some(out) = &a.out {
            write_config(
                &p,
                out,
                &est.theta,
                "als",
                &a.measurements,
                ("residual", est.residual),
            )?;
        }
        print_stdout(|o| {
            if a.json {
                let json = serde_json::json!({
                    "problem": p.name(),
                    "method": "als",
                    "params": params.names(),
                    "estimate": est,
                    "seconds": took,
                });
                return writeln!(
                    o,
                    "{}",
                    serde_json::to_string_pretty(&json).expect("serializes")
                );
            }
            writeln!(
                o,
                "autotune estimate: {} from {} ({} sequence(s), {} innovations), autocovariance least squares, lags 0..{}",
                p.name(),
                a.measurements.display(),
                data.sequences.len(),
                est.samples,
                est.lags - 1
            )?;
            writeln!(
                o,
                "{:<14} {:>12} {:>14} {:>12}  unit",
                "parameter", "estimate", "unconstrained", "start"
            )?;
            for (i, d) in params.params.iter().enumerate() {
                let unc = if d.fixed {
                    "fixed".to_string()
                } else {
                    fmt_g(est.unconstrained[i])
                };
                writeln!(
                    o,
                    "{:<14} {:>12} {:>14} {:>12}  {}",
                    d.name,
                    fmt_g(est.theta[i]),
                    unc,
                    fmt_g(start[i]),
                    d.unit
                )?;
            }
            writeln!(
                o,
                "rms residual of the autocovariances {}; filter at the start: spectral radius of F(I − KH) {:.4}; {:.3} s",
                fmt_g(est.residual),
                est.spectral_radius,
                took
            )?;
            if !est.at_zero.is_empty() {
                let names: Vec<&str> = est
                    .at_zero
                    .iter()
                    .map(|&i| params.params[i].name.as_str())
                    .collect();
                writeln!(
                    o,
                    "held at zero by the constraint (unconstrained least squares would make them negative): {}",
                    names.join(", ")
                )?;
            }
            Ok(())
        })?;
        return Ok(ExitCode::SUCCESS);
    }
    if a.full.is_some() {
        return Err(AppError::flag(
            "--full",
            "a full Q or R is estimated by --method als only",
        ));
    }
    let t0 = Instant::now();
    let est = ml::estimate(&build, &data, &start, &fixed, a.max_iterations)
        .map_err(|m| AppError::Refused(format!("{}: {m}", a.measurements.display())))?;
    let took = t0.elapsed().as_secs_f64();
    if let Some(out) = &a.out {
        write_config(
            &p,
            out,
            &est.theta,
            "ml",
            &a.measurements,
            ("neg_log_likelihood", est.neg_log_likelihood),
        )?;
    }
    print_stdout(|o| {
        if a.json {
            let json = serde_json::json!({
                "problem": p.name(),
                "method": "ml",
                "params": params.names(),
                "estimate": est,
                "seconds": took,
            });
            writeln!(
                o,
                "{}",
                serde_json::to_string_pretty(&json).expect("serializes")
            )?;
            return Ok(());
        }
        writeln!(
            o,
            "autotune estimate: {} from {} ({} sequence(s), {} values), maximum likelihood",
            p.name(),
            a.measurements.display(),
            data.sequences.len(),
            data.values()
        )?;
        writeln!(
            o,
            "{:<14} {:>12} {:>12} {:>12}  unit",
            "parameter", "estimate", "std error", "start"
        )?;
        for (i, d) in params.params.iter().enumerate() {
            let se = match (d.fixed, est.std_errors[i]) {
                (true, _) => "fixed".to_string(),
                (false, Some(s)) => fmt_g(s),
                (false, None) if est.at_bound.contains(&i) => "at bound (0)".to_string(),
                (false, None) => "not identified".to_string(),
            };
            writeln!(
                o,
                "{:<14} {:>12} {:>12} {:>12}  {}",
                d.name,
                fmt_g(est.theta[i]),
                se,
                fmt_g(start[i]),
                d.unit
            )?;
        }
        writeln!(
            o,
            "−log L: {} at the start, {} at the estimate; {} L-BFGS iterations ({} restart(s)), {} Newton step(s), {} likelihood evaluations, {:.3} s",
            fmt_g(est.start_neg_log_likelihood),
            fmt_g(est.neg_log_likelihood),
            est.iterations,
            est.restarts,
            est.newton_steps,
            est.evaluations,
            took,
        )?;
        let gradient: Vec<String> = est.gradient.iter().map(|g| fmt_g(*g)).collect();
        if est.converged {
            writeln!(
                o,
                "converged: the quadratic model at the estimate predicts {} nats still to gain (below {}); gradient in log θ [{}]",
                fmt_g(est.predicted_improvement),
                fmt_g(ml::PREDICTED_TOL),
                gradient.join(", ")
            )?;
        } else {
            let names = |ix: &[usize]| -> String {
                ix.iter()
                    .map(|&i| params.params[i].name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let why = if !est.stuck.is_empty() {
                format!(
                    "{} stayed near zero although the likelihood pulls them up",
                    names(&est.stuck)
                )
            } else if est.predicted_improvement.is_finite() {
                format!(
                    "the quadratic model at the estimate predicts {} nats still to gain",
                    fmt_g(est.predicted_improvement)
                )
            } else {
                "the information at the estimate is not positive definite (not a maximum)"
                    .to_string()
            };
            writeln!(
                o,
                "not converged: {why}; gradient in log θ [{}]{}",
                gradient.join(", "),
                if est.iterations >= a.max_iterations {
                    " (iteration limit reached: raise --max-iterations)"
                } else {
                    ""
                }
            )?;
        }
        if !est.at_bound.is_empty() {
            let names: Vec<&str> = est
                .at_bound
                .iter()
                .map(|&i| params.params[i].name.as_str())
                .collect();
            writeln!(
                o,
                "at the bound (0): {} (setting it to zero changes −log L by less than 0.001 nats); the other standard errors leave it out",
                names.join(", ")
            )?;
        }
        if !est.not_identified.is_empty() {
            let names: Vec<&str> = est
                .not_identified
                .iter()
                .map(|&i| params.params[i].name.as_str())
                .collect();
            writeln!(
                o,
                "not identified by these data (relative standard error above 1, or no curvature): {}",
                names.join(", ")
            )?;
        }
        Ok(())
    })?;
    Ok(ExitCode::SUCCESS)
}
