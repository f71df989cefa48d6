//! `estimate`: Q and R estimated from recorded measurements alone, and the pieces `tune`
//! uses to run on a record (`--measurements`) or to start from an estimate (`--init`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::CommandError;
use super::options::name_value;
use crate::check::check;
use crate::estimate::EstimateError;
use crate::estimate::als::{self, AlsModel, FullMatrix};
use crate::estimate::{
    FilterReplay, GateRanges, LikelihoodRanges, MeasurementRecord, ReplayExperiment, ReplayRefusal,
    gate_ranges, likelihood_ranges, ml, read_measurements, read_states, simulate, simulate_sensors,
};
use crate::experiment::{Experiment, LinearExperiment};
use crate::external::{ExternalExperiment, WorkerReplay};
use crate::input::FileError;
use crate::output::{Outputs, check_output_file};
use crate::problem::Problem;
use crate::report::estimate::{
    EstimateSummary, als_text, estimate_json, ml_text, ranges_json, ranges_text, rests_on,
    start_note,
};
use crate::report::tuned::estimated_config_toml;

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

/// The record `file` read, with as many components per step as problem `p` measures.
fn read_record(
    p: &Problem,
    lin: &LinearExperiment,
    file: &Path,
) -> Result<MeasurementRecord, CommandError> {
    let data = read_measurements(file)?;
    at_own_step(p, file, &data)?;
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
    Ok(data)
}

/// Refuse a record whose times step a linear problem's filter by another length than its
/// dt (its F and Q are built for that step).
fn at_own_step(p: &Problem, file: &Path, data: &MeasurementRecord) -> Result<(), CommandError> {
    for (i, seq) in data.sequences.iter().enumerate() {
        let mut last = 0.0;
        for (k, &t) in seq.time.iter().enumerate() {
            if ((t - last) - p.dt).abs() > 1e-9 * p.dt {
                return Err(FileError::new(
                    file,
                    "time",
                    format!(
                        "run {i}, step {}: {} s after the last, but {}'s filter steps by dt = {} s (a linear problem's filter replays a record at its own step only)",
                        k + 1,
                        t - last,
                        p.name(),
                        p.dt
                    ),
                )
                .into());
            }
            last = t;
        }
    }
    Ok(())
}

/// Refuse a record no estimate can come from: no measured value at all, or a single step
/// (one innovation says nothing about how Q and R split), which would otherwise leave the
/// start values standing as if they were estimates.
fn estimable(file: &Path, data: &MeasurementRecord) -> Result<(), CommandError> {
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
/// experiment `check` and `tune` can judge by its innovations: a linear problem's Kalman
/// filter (every component may come and go on its own), or any other filter autotune holds
/// as code (a catalog model's: the record gives its sensors' components side by side, a
/// sensor's reading whole or not at all).
pub fn measured_experiment<'a>(
    p: &'a Problem,
    path: &Path,
    file: &Path,
    truth: Option<&Path>,
) -> Result<Box<dyn Experiment + 'a>, CommandError> {
    if let Some(states) = truth {
        if p.worker().is_some() {
            return Err(CommandError::option(
                "--truth",
                "a worker that replays gives its own errors (e and P in its records) where it has a reference; --truth is for a filter autotune holds",
            ));
        }
        // The generic replay, which a linear problem's filter runs through as well (at its
        // own step: a record with times keeps its dt, and they are then not needed).
        let mut data = read_measurements(file)?;
        if p.linear().is_some() {
            at_own_step(p, file, &data)?;
            for seq in &mut data.sequences {
                seq.time.clear();
            }
        }
        let reference = read_states(states)?;
        let replay = replayed(p, path, data, file, "--measurements")?;
        let judged = replay
            .with_reference(reference)
            .map_err(|e| FileError::new(states, "x", e.to_string()))?;
        return Ok(Box::new(judged));
    }
    if let Some(lin) = p.experiment().linear() {
        let data = read_record(p, lin, file)?;
        let replay = ReplayExperiment::new(lin, data)
            .map_err(|e| FileError::new(file, "", format!("{}: {}", e.setting, e.message)))?;
        return Ok(Box::new(replay));
    }
    if let Some(w) = p.worker() {
        return Ok(Box::new(worker_replay(p, w, file)?.0));
    }
    let data = read_measurements(file)?;
    Ok(Box::new(replayed(p, path, data, file, "--measurements")?))
}

/// The worker of problem `p` replayed over the record `file` (its measured values counted
/// beside it): refused when the record's components are not the worker's sensors', or its
/// sequences differ in length (a worker's records run every sequence to the same T).
fn worker_replay<'a>(
    p: &'a Problem,
    w: &'a ExternalExperiment,
    file: &Path,
) -> Result<(WorkerReplay<'a>, MeasurementRecord), CommandError> {
    let data = read_measurements(file)?;
    let names = p.measurement_names();
    if data.dim != names.len() {
        return Err(FileError::new(
            file,
            "z",
            format!(
                "{} components per step, but {}'s worker measures {} ({})",
                data.dim,
                p.name(),
                names.len(),
                names.join(", ")
            ),
        )
        .into());
    }
    let steps = data.sequences.first().map_or(0, |s| s.steps);
    if let Some((i, s)) = data
        .sequences
        .iter()
        .enumerate()
        .find(|(_, s)| s.steps != steps)
    {
        return Err(FileError::new(
            file,
            "step",
            format!(
                "run {i} has {} steps and run 0 {steps}: a worker replays sequences of one length",
                s.steps
            ),
        )
        .into());
    }
    let replay = WorkerReplay::new(w, file, data.sequences.len(), steps)
        .map_err(|e| FileError::new(file, "", format!("{}: {}", e.setting, e.message)))?;
    Ok((replay, data))
}

/// The maximum-likelihood estimate of a worker's filter replayed over `file` by `replay`,
/// from `start`: `−log L` from the innovations and covariances it answers. A worker failure
/// ends it with that error; records without S (normalized innovations) give no likelihood,
/// and are refused naming the file.
fn worker_ml(
    replay: &WorkerReplay<'_>,
    values: usize,
    start: &[f64],
    fixed: &[bool],
    max_iterations: u64,
    file: &Path,
    with_ranges: bool,
) -> Result<(ml::MlEstimate, Option<(LikelihoodRanges, GateRanges)>), CommandError> {
    match replay.neg_log_likelihood(start)? {
        Some(_) => {}
        None => {
            return Err(FileError::new(
                file,
                "z",
                "the worker's answer to this replay gives no likelihood at the start values: it answered sums, or records of normalized innovations (nis_<sensor>), rather than records of nu_<sensor> and S_<sensor>; or a sequence stopped",
            )
            .into());
        }
    }
    // The first worker failure stops the search and is the command's error.
    let failure: std::cell::RefCell<Option<crate::experiment::ExperimentError>> =
        std::cell::RefCell::new(None);
    let nll = |t: &[f64]| {
        if failure.borrow().is_some() {
            return None;
        }
        replay
            .neg_log_likelihood(t)
            .map_err(|e| *failure.borrow_mut() = Some(e))
            .ok()
            .flatten()
    };
    let est = ml::estimate_by(&nll, values, start, fixed, max_iterations);
    let ranges = est
        .as_ref()
        .ok()
        .filter(|_| with_ranges)
        .map(|est| supported(&nll, replay, est, fixed));
    // A failure inside the gate's trace reads as "fails" there: the worker's own record
    // of it stops the command as well.
    if let Some(e) = failure.into_inner().or_else(|| replay.failure()) {
        return Err(e.into());
    }
    let est = est.map_err(|e| CommandError::Estimate {
        subject: file.display().to_string(),
        source: e,
    })?;
    Ok((est, ranges))
}

/// The filter of problem `p` (file `path`), held as code, over `data` (read from `file`,
/// or simulated): refused naming the problem's section when autotune does not hold its
/// filter (`asked_by`: the flag or command that asked), and the record's field when it
/// does not fit the filter's sensors.
fn replayed<'a>(
    p: &'a Problem,
    path: &Path,
    data: MeasurementRecord,
    file: &Path,
    asked_by: &str,
) -> Result<FilterReplay<'a>, CommandError> {
    FilterReplay::new(p, data).map_err(|e| match e {
        ReplayRefusal::NoFilter(_) => FileError::new(
            path,
            p.kind().field(),
            format!(
                "{asked_by}: this problem is {}, whose filter autotune does not hold, so it cannot replay it over a record",
                p.kind().describe()
            ),
        )
        .into(),
        ReplayRefusal::Inputs { .. } => {
            FileError::new(path, p.kind().field(), format!("{asked_by}: {e}")).into()
        }
        e @ ReplayRefusal::Times(_) => FileError::new(file, "time", e.to_string()).into(),
        e => FileError::new(file, "z", e.to_string()).into(),
    })
}

/// The maximum-likelihood estimate of the filter `replay` replays, from `start`: its own
/// innovations' likelihood (exact for a Kalman filter, the usual approximation for an EKF,
/// UKF or ESKF), searched as for a linear problem.
fn replayed_ml(
    replay: &FilterReplay<'_>,
    start: &[f64],
    fixed: &[bool],
    max_iterations: u64,
    file: &Path,
) -> Result<Result<ml::MlEstimate, EstimateError>, CommandError> {
    // Where the filter cannot run over the record at the start, say where and why.
    if let Err(stop) = replay.neg_log_likelihood(start) {
        return Err(FileError::new(
            file,
            "z",
            format!("the filter cannot run over the record at the start values: {stop}"),
        )
        .into());
    }
    let nll = |theta: &[f64]| replay.neg_log_likelihood(theta).ok();
    Ok(ml::estimate_by(
        &nll,
        replay.data().values(),
        start,
        fixed,
        max_iterations,
    ))
}

/// A linear problem's record method, or `ml` (the one a filter held otherwise has).
fn replayable_method(method: &str, flag: &str) -> Result<(), CommandError> {
    if method == "ml" {
        Ok(())
    } else {
        Err(CommandError::option(
            flag,
            format!(
                "{method} works on a linear problem's matrices; a filter held as code (a catalog model's) is estimated by ml, its innovations' likelihood"
            ),
        ))
    }
}

/// Added to the problem's seed for the record `tune --init` simulates.
const INIT_SEED_OFFSET: u64 = 0x5eed_1417;

/// Where a tune's search starts: the estimate, and the line saying where it came from.
#[derive(Debug, Clone)]
pub struct Start {
    /// One value per parameter.
    pub theta: Vec<f64>,
    /// `start: ml estimate from FILE in 0.12 s: q = …`, for stderr.
    pub note: String,
}

/// The start `tune --init METHOD` searches from: the estimate of `method` ("ml" or "als")
/// on `record`, or on a record simulated from `p`'s truth (its Monte Carlo runs × steps,
/// with another seed than the search's so that the start does not fit the search's noise).
/// `asked_by` is the flag that asked for it (`--init`, or `--measurements` for the
/// default start on a record), which an error names.
pub fn initial(
    p: &Problem,
    path: &Path,
    record: Option<&Path>,
    method: &str,
    asked_by: &str,
) -> Result<Start, CommandError> {
    let Some(lin) = p.linear() else {
        return initial_replayed(p, path, record, method, asked_by);
    };
    let (data, origin) = match record {
        Some(f) => {
            let d = read_record(p, lin, f)?;
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
    let failed = |e: EstimateError| CommandError::Estimate {
        subject: format!("the start ({method} on {origin}, asked by {asked_by})"),
        source: e,
    };
    let theta = if method == "als" {
        let model = AlsModel::of(lin);
        als::estimate_passes(&model, &data, &start, &fixed, 15, 2)
            .map_err(failed)?
            .theta
    } else {
        let build = |theta: &[f64]| lin.filter_at(theta);
        ml::estimate(&build, &data, &start, &fixed, 200)
            .map_err(failed)?
            .theta
    };
    let note = start_note(method, &origin, t0.elapsed().as_secs_f64(), params, &theta);
    Ok(Start { theta, note })
}

/// [`initial`] of a problem whose filter autotune holds as code (a catalog model's): the
/// likelihood's maximum over its innovations on the record, or on one simulated from the
/// problem's truth (its Monte Carlo runs × steps, another seed).
fn initial_replayed(
    p: &Problem,
    path: &Path,
    record: Option<&Path>,
    method: &str,
    asked_by: &str,
) -> Result<Start, CommandError> {
    replayable_method(method, asked_by)?;
    if let (Some(w), Some(f)) = (p.worker(), record) {
        let (replay, data) = worker_replay(p, w, f)?;
        estimable(f, &data)?;
        let params = p.params();
        let fixed: Vec<bool> = params.params.iter().map(|d| d.fixed).collect();
        let t0 = Instant::now();
        let (est, _) = worker_ml(
            &replay,
            data.values(),
            &params.values(),
            &fixed,
            200,
            f,
            false,
        )?;
        let origin = f.display().to_string();
        let note = start_note(
            method,
            &origin,
            t0.elapsed().as_secs_f64(),
            params,
            &est.theta,
        );
        return Ok(Start {
            theta: est.theta,
            note,
        });
    }
    let (data, origin, file) = match record {
        Some(f) => {
            let d = read_measurements(f)?;
            estimable(f, &d)?;
            (d, f.display().to_string(), f.to_path_buf())
        }
        None => {
            let mc = p.mc();
            let seed = mc.seed().wrapping_add(INIT_SEED_OFFSET);
            let truth = p.simulation_truth().ok_or_else(|| {
                FileError::new(
                    path,
                    p.kind().field(),
                    format!("{asked_by}: autotune does not hold this problem's truth to simulate a record from"),
                )
            })?;
            let dims = p
                .replay_filter(&p.params().values())
                .map(|f| f.sensor_dims())
                .unwrap_or_default();
            let sim = simulate_sensors(truth, &dims, mc.runs(), mc.steps(), seed);
            let origin = format!(
                "{} × {} steps simulated from the truth (seed {seed})",
                mc.runs(),
                mc.steps()
            );
            (sim.measurements, origin, path.to_path_buf())
        }
    };
    let replay = replayed(p, path, data, &file, asked_by)?;
    let params = p.params();
    let fixed: Vec<bool> = params.params.iter().map(|d| d.fixed).collect();
    let t0 = Instant::now();
    let theta = replayed_ml(&replay, &params.values(), &fixed, 200, &file)?
        .map_err(|e| CommandError::Estimate {
            subject: format!("the start ({method} on {origin}, asked by {asked_by})"),
            source: e,
        })?
        .theta;
    let note = start_note(method, &origin, t0.elapsed().as_secs_f64(), params, &theta);
    Ok(Start { theta, note })
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

/// The range of each free parameter the record supports around the estimate `est`: its
/// 95% profile-likelihood interval (`−log L = nll(θ)`), and where the record passes the
/// gate of `judged` (the filter over the record) with the other parameters at the
/// estimate.
fn supported(
    nll: &dyn Fn(&[f64]) -> Option<f64>,
    judged: &dyn Experiment,
    est: &ml::MlEstimate,
    fixed: &[bool],
) -> (LikelihoodRanges, GateRanges) {
    let likelihood = likelihood_ranges(nll, est, fixed, 0.95);
    let passes = |t: &[f64]| {
        check(judged, t, judged.mc(), false)
            .ok()
            .map(|r| r.verdict.passes())
    };
    (likelihood, gate_ranges(&passes, &est.theta, fixed))
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
