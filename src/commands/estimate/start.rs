//! Where `tune --init` starts: Q and R estimated from a record (given, or simulated from the
//! problem's truth), the estimate and a line saying where it came from.

use crate::experiment::{HeldAsCode, Structure};
use std::path::Path;
use std::time::Instant;

use super::record::{
    estimable, read_record, replayable_method, replayed, replayed_ml, worker_ml, worker_replay,
};
use crate::commands::CommandError;
use crate::estimate::EstimateError;
use crate::estimate::als::{self, AlsModel};
use crate::estimate::{ml, read_measurements, simulate, simulate_sensors};
use crate::experiment::Experiment;
use crate::input::FileError;
use crate::problem::Problem;
use crate::report::estimate::start_note;

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
pub(super) fn initial_replayed(
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
