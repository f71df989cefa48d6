//! `estimate`: Q and R estimated from recorded measurements alone, and the pieces `tune`
//! uses to run on a record (`--measurements`) or to start from an estimate (`--init`).

use crate::experiment::Structure;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::CommandError;
use super::options::name_value;
use crate::estimate::EstimateError;
use crate::estimate::als::{self, AlsModel, FullMatrix};
use crate::estimate::{
    GateRanges, LikelihoodRanges, MeasurementRecord, ReplayExperiment, ml, read_measurements,
};
use crate::experiment::Experiment;
use crate::input::FileError;
use crate::output::{Outputs, check_output_file};
use crate::problem::Problem;
use crate::report::estimate::{
    EstimateSummary, als_text, estimate_json, ml_text, ranges_json, ranges_text, rests_on,
};
use crate::report::tuned::estimated_config_toml;

mod record;
mod start;

pub use record::measured_experiment;
use record::{
    estimable, read_record, replayable_method, replayed, replayed_ml, supported, worker_ml,
    worker_replay,
};
pub use start::{Start, initial};

/// The options of `estimate`.
#[derive(Debug, Clone, clap::Args)]
pub struct EstimateOptions {
    /// Problem file (TOML) whose filter has the parameters to estimate: a linear problem, or
    /// a catalog model (its sensors' components side by side in the record).
    pub problem: PathBuf,
    /// The recorded measurements: .csv, .jsonl, .npy or .npz (docs/src/measurements.md).
    #[arg(long, value_name = "FILE")]
    pub measurements: PathBuf,
    /// Estimation method: ml (maximum likelihood over the filter's innovations) or als
    /// (autocovariance least squares from the innovations of the filter at the start values).
    #[arg(long, default_value = "ml", value_parser = ["ml", "als"])]
    pub method: String,
    /// ALS: autocovariance lags L (0 … L − 1).
    #[arg(long, default_value_t = 15)]
    pub lags: usize,
    /// ALS: passes, each with the gain of the filter at the previous estimate (1: the start
    /// values' gain only).
    #[arg(long, default_value_t = 2)]
    pub passes: usize,
    /// ALS: estimate Q (the covariance of the problem's process noise inputs), R, or both
    /// (qr) as full matrices constrained positive semidefinite, instead of the problem's
    /// parameters (a build with the `sdp` feature).
    #[arg(long, value_name = "q|r|qr", value_parser = ["q", "r", "qr"])]
    pub full: Option<String>,
    /// Start a parameter at NAME=VALUE instead of the problem's value (repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
    /// L-BFGS iteration limit.
    #[arg(long, default_value_t = 200)]
    pub max_iterations: u64,
    /// Also write the estimate as a config `autotune check PROBLEM --config FILE` reads.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Print the estimate as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Replace an --out file autotune did not write (by default only its own files, which
    /// carry its mark, are replaced; an input is never replaced).
    #[arg(long)]
    pub force: bool,
}

/// What an estimate printed: a table, or JSON with `--json`.
#[derive(Debug, Clone)]
pub struct EstimateRun {
    /// The estimate as `estimate` prints it (the table or the JSON).
    pub output: String,
}

/// Write `theta` as a config to `out`, with where it came from.
fn write_config(
    p: &Problem,
    out: &Path,
    theta: &[f64],
    method: &str,
    record: &Path,
    score: (&str, f64),
    force: bool,
) -> Result<(), CommandError> {
    let mut prov = toml::Table::new();
    prov.insert("autotune_version".into(), env!("CARGO_PKG_VERSION").into());
    prov.insert("method".into(), method.into());
    prov.insert("measurements".into(), record.display().to_string().into());
    prov.insert(score.0.into(), score.1.into());
    let mut outputs = Outputs::replacing(force);
    outputs.file(out, estimated_config_toml(p, theta, prov));
    outputs.commit().map_err(|e| e.of_flag("--out"))?;
    Ok(())
}

/// The checked options of an estimate, before it runs.
fn validate(a: &EstimateOptions) -> Result<(), CommandError> {
    if a.method == "als" {
        if !(1..=200).contains(&a.lags) {
            return Err(CommandError::option(
                "--lags",
                format!("{} is not in 1..=200", a.lags),
            ));
        }
        if !(1..=20).contains(&a.passes) {
            return Err(CommandError::option(
                "--passes",
                format!("{} is not in 1..=20", a.passes),
            ));
        }
        if a.full.is_some() && a.out.is_some() {
            return Err(CommandError::option(
                "--out",
                "a full Q or R is not one of the problem's parameters, so there is no config to write; --json gives the matrices",
            ));
        }
    } else if a.full.is_some() {
        return Err(CommandError::option(
            "--full",
            "a full Q or R is estimated by --method als only",
        ));
    }
    Ok(())
}

/// Run `estimate`: the problem's free parameters from the record by maximum likelihood or
/// autocovariance least squares (or a full Q or R, with the `sdp` feature), written as a
/// config where `--out` asks.
pub fn estimate(a: &EstimateOptions) -> Result<EstimateRun, CommandError> {
    let p = Problem::load(&a.problem)?;
    let Some(lin) = p.linear() else {
        return estimate_replayed(&p, a);
    };
    let data = read_record(&p, lin, &a.measurements)?;
    estimable(&a.measurements, &data)?;
    if let Some(out) = &a.out {
        check_output_file(out, a.force).map_err(|e| e.of_flag("--out"))?;
    }
    let (start, fixed) = start_values(&p, a)?;
    validate(a)?;
    let failed = |e: EstimateError| CommandError::Estimate {
        subject: a.measurements.display().to_string(),
        source: e,
    };
    let mut summary = summary_of(&p, a, &data, &start);
    let t0 = Instant::now();
    if a.method == "als" {
        let model = AlsModel::of(lin);
        if let Some(full) = &a.full {
            let full = FullMatrix::parse(full).expect("clap allows q, r and qr only");
            return full_estimate(&p, &mut summary, &data, &model, &fixed, full, a);
        }
        let est = als::estimate_passes(&model, &data, &start, &fixed, a.lags, a.passes)
            .map_err(failed)?;
        summary.seconds = t0.elapsed().as_secs_f64();
        if let Some(out) = &a.out {
            let score = ("residual", est.residual);
            write_config(&p, out, &est.theta, "als", &a.measurements, score, a.force)?;
        }
        let output = if a.json {
            estimate_json(&summary, "als", &est, serde_json::Map::new())
        } else {
            als_text(&summary, &est)
        };
        return Ok(EstimateRun { output });
    }
    let build = |theta: &[f64]| lin.filter_at(theta);
    let est = ml::estimate(&build, &data, &start, &fixed, a.max_iterations).map_err(failed)?;
    summary.seconds = t0.elapsed().as_secs_f64();
    let nll = |t: &[f64]| lin.filter_at(t).neg_log_likelihood(&data).ok();
    let judged = ReplayExperiment::new(lin, data.clone()).map_err(|e| {
        FileError::new(&a.measurements, "", format!("{}: {}", e.setting, e.message))
    })?;
    let ranges = supported(&nll, &judged, &est, &fixed);
    ml_run(&p, a, &summary, &est, &ranges)
}

/// What an estimate's table and JSON say of its inputs, before its search has run.
fn summary_of<'a>(
    p: &'a Problem,
    a: &'a EstimateOptions,
    data: &MeasurementRecord,
    start: &'a [f64],
) -> EstimateSummary<'a> {
    EstimateSummary {
        problem: p.name(),
        record: &a.measurements,
        sequences: data.sequences.len(),
        steps: data.sequences.iter().map(|s| s.steps).sum(),
        values: data.values(),
        params: p.params(),
        start,
        seconds: 0.0,
        max_iterations: a.max_iterations,
    }
}

/// The start values (the problem's, with `--set`'s) and which parameters are fixed.
fn start_values(p: &Problem, a: &EstimateOptions) -> Result<(Vec<f64>, Vec<bool>), CommandError> {
    let params = p.params();
    let mut start = params.values();
    for kv in &a.set {
        let (i, v) = name_value(params, "--set", kv)?;
        start[i] = v;
    }
    Ok((start, params.params.iter().map(|d| d.fixed).collect()))
}

/// A maximum-likelihood estimate's config (where `--out` asks) and its table or JSON.
fn ml_run(
    p: &Problem,
    a: &EstimateOptions,
    summary: &EstimateSummary<'_>,
    est: &ml::MlEstimate,
    (likelihood, gate): &(LikelihoodRanges, GateRanges),
) -> Result<EstimateRun, CommandError> {
    if let Some(out) = &a.out {
        let score = ("neg_log_likelihood", est.neg_log_likelihood);
        write_config(p, out, &est.theta, "ml", &a.measurements, score, a.force)?;
    }
    let output = if a.json {
        let mut extra = serde_json::Map::new();
        extra.insert("supported".into(), ranges_json(likelihood, gate));
        extra.insert("judged_on".into(), rests_on(summary).into());
        estimate_json(summary, "ml", est, extra)
    } else {
        let mut o = ml_text(summary, est);
        ranges_text(&mut o, summary, likelihood, gate);
        o
    };
    Ok(EstimateRun { output })
}

/// [`estimate`] of a problem whose filter autotune holds as code (a catalog model's): the
/// maximum of its innovations' likelihood over the record.
fn estimate_replayed(p: &Problem, a: &EstimateOptions) -> Result<EstimateRun, CommandError> {
    validate(a)?;
    replayable_method(&a.method, "--method")?;
    if let Some(w) = p.worker() {
        let (replay, data) = worker_replay(p, w, &a.measurements)?;
        estimable(&a.measurements, &data)?;
        if let Some(out) = &a.out {
            check_output_file(out, a.force).map_err(|e| e.of_flag("--out"))?;
        }
        let (start, fixed) = start_values(p, a)?;
        let mut summary = summary_of(p, a, &data, &start);
        let t0 = Instant::now();
        let values = data.values();
        let (est, ranges) = worker_ml(
            &replay,
            values,
            &start,
            &fixed,
            a.max_iterations,
            &a.measurements,
            true,
        )?;
        summary.seconds = t0.elapsed().as_secs_f64();
        let ranges = ranges.expect("asked for");
        return ml_run(p, a, &summary, &est, &ranges);
    }
    let data = read_measurements(&a.measurements)?;
    estimable(&a.measurements, &data)?;
    let replay = replayed(p, &a.problem, data, &a.measurements, "estimate")?;
    if let Some(out) = &a.out {
        check_output_file(out, a.force).map_err(|e| e.of_flag("--out"))?;
    }
    let (start, fixed) = start_values(p, a)?;
    let data = replay.data();
    let mut summary = summary_of(p, a, data, &start);
    let t0 = Instant::now();
    let est =
        replayed_ml(&replay, &start, &fixed, a.max_iterations, &a.measurements)?.map_err(|e| {
            CommandError::Estimate {
                subject: a.measurements.display().to_string(),
                source: e,
            }
        })?;
    summary.seconds = t0.elapsed().as_secs_f64();
    let nll = |t: &[f64]| replay.neg_log_likelihood(t).ok();
    let ranges = supported(&nll, &replay, &est, &fixed);
    ml_run(p, a, &summary, &est, &ranges)
}

/// A full Q or R by autocovariance least squares under a semidefinite constraint: needs
/// the `sdp` build feature (clarabel's semidefinite cone on the system's OpenBLAS).
#[cfg(not(feature = "sdp"))]
fn full_estimate(
    _p: &Problem,
    _summary: &mut EstimateSummary<'_>,
    _data: &MeasurementRecord,
    _model: &AlsModel<'_>,
    _fixed: &[bool],
    _full: FullMatrix,
    _a: &EstimateOptions,
) -> Result<EstimateRun, CommandError> {
    Err(CommandError::option(
        "--full",
        "this autotune was built without the `sdp` feature (clarabel's semidefinite cone needs a system OpenBLAS: apt-get install libopenblas-dev, then cargo build --release --features sdp)",
    ))
}

/// A full Q or R by autocovariance least squares under a semidefinite constraint.
#[cfg(feature = "sdp")]
fn full_estimate(
    p: &Problem,
    summary: &mut EstimateSummary<'_>,
    data: &MeasurementRecord,
    model: &AlsModel<'_>,
    fixed: &[bool],
    full: FullMatrix,
    a: &EstimateOptions,
) -> Result<EstimateRun, CommandError> {
    use crate::estimate::als_full::estimate_full;
    use crate::report::estimate::{full_json, full_text};
    let t0 = Instant::now();
    let est =
        estimate_full(model, data, summary.start, fixed, full, a.lags, a.passes).map_err(|e| {
            CommandError::Estimate {
                subject: a.measurements.display().to_string(),
                source: e,
            }
        })?;
    summary.seconds = t0.elapsed().as_secs_f64();
    let exp = p.experiment();
    let output = if a.json {
        full_json(summary, &est, model, exp.measurement_names())
    } else {
        full_text(
            summary,
            &est,
            model,
            exp.state_names(),
            exp.measurement_names(),
        )
    };
    Ok(EstimateRun { output })
}
