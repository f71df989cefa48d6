//! A measurement record read for a problem, and the experiments that run on it: the
//! problem's own filter replayed over it (`tune --measurements`), a worker's replay, and the
//! range of values the record supports around an estimate.

use crate::experiment::Structure;
use std::path::Path;

use crate::check::{Truth, check};
use crate::commands::CommandError;
use crate::estimate::EstimateError;
use crate::estimate::{
    FilterReplay, GateRanges, LikelihoodRanges, MeasurementRecord, ReplayExperiment, ReplayRefusal,
    gate_ranges, likelihood_ranges, ml, read_measurements, read_states,
};
use crate::experiment::{Experiment, LinearExperiment};
use crate::external::{ExternalExperiment, WorkerReplay};
use crate::input::FileError;
use crate::problem::Problem;

/// The record `file` read, with as many components per step as problem `p` measures.
pub(super) fn read_record(
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
pub(super) fn at_own_step(
    p: &Problem,
    file: &Path,
    data: &MeasurementRecord,
) -> Result<(), CommandError> {
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
pub(super) fn estimable(file: &Path, data: &MeasurementRecord) -> Result<(), CommandError> {
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
pub(super) fn worker_replay<'a>(
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
pub(super) fn worker_ml(
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
pub(super) fn replayed<'a>(
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
pub(super) fn replayed_ml(
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
pub(super) fn replayable_method(method: &str, flag: &str) -> Result<(), CommandError> {
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

/// The range of each free parameter the record supports around the estimate `est`: its
/// 95% profile-likelihood interval (`−log L = nll(θ)`), and where the record passes the
/// gate of `judged` (the filter over the record) with the other parameters at the
/// estimate.
pub(super) fn supported(
    nll: &dyn Fn(&[f64]) -> Option<f64>,
    judged: &dyn Experiment,
    est: &ml::MlEstimate,
    fixed: &[bool],
) -> (LikelihoodRanges, GateRanges) {
    let likelihood = likelihood_ranges(nll, est, fixed, 0.95);
    let passes = |t: &[f64]| {
        check(judged, t, judged.mc(), Truth::Unknown)
            .ok()
            .map(|r| r.verdict.passes())
    };
    (likelihood, gate_ranges(&passes, &est.theta, fixed))
}
