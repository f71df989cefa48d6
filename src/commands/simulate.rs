//! `simulate`: measurements (and the true states) drawn from a problem's truth, to try
//! `estimate`, and `check` or `tune` with `--measurements`, on data whose answer is known.

use crate::experiment::{HeldAsCode, Structure};
use std::path::PathBuf;

use super::CommandError;
use crate::estimate::{record_bytes, simulate_sensors as draw};
use crate::experiment::Experiment;
use crate::input::FileError;
use crate::output::{Outputs, check_output_file, same_place};
use crate::problem::Problem;
use crate::report::estimate::simulate_text;

/// The options of `simulate`.
#[derive(Debug, Clone, clap::Args)]
pub struct SimulateOptions {
    /// Problem file (TOML) whose truth autotune holds: a linear problem or a catalog model.
    pub problem: PathBuf,
    /// Where to write the measurements: .csv, .jsonl or .npy (docs/src/measurements.md).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Also write the true states here (same formats, columns x_1 … x_n).
    #[arg(long, value_name = "FILE")]
    pub truth: Option<PathBuf>,
    /// Number of sequences (runs).
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Steps per sequence (default: the problem's montecarlo.steps).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Seed (default: the problem's montecarlo.seed); run i draws from the same stream as
    /// run i of a Monte Carlo check.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Write each step's time beside it (k · dt, s since the initial state): a `time` column
    /// (CSV) or key (JSON Lines), as a recording with timestamps has.
    #[arg(long)]
    pub time: bool,
    /// Replace existing --out and --truth files (a record has no room for autotune's mark,
    /// so an existing one is replaced only with --force; an input is never replaced).
    #[arg(long)]
    pub force: bool,
}

/// Run `simulate`: draw the measurements (and the true states where asked) from the
/// problem's truth and write them, every sensor's components side by side (empty where a
/// sensor did not report); returns the line saying what was written.
pub fn simulate(a: &SimulateOptions) -> Result<String, CommandError> {
    let p = Problem::load(&a.problem)?;
    // Each sensor's dimension: a linear problem's one sensor, or the filter's sensors.
    let dims = match p.linear() {
        Some(lin) => Some(vec![lin.truth.n_z()]),
        None => p
            .replay_filter(&p.params().values())
            .map(|f| f.sensor_dims()),
    };
    let (Some(truth), Some(dims)) = (p.simulation_truth(), dims) else {
        return Err(FileError::new(
            &a.problem,
            p.kind().field(),
            format!(
                "simulate works on a problem whose truth autotune holds (a linear problem, a catalog model); this one is {}",
                p.kind().describe()
            ),
        )
        .into());
    };
    if !(1..=100_000).contains(&a.runs) {
        return Err(CommandError::option(
            "--runs",
            format!("{} is not in 1..=100000", a.runs),
        ));
    }
    let steps = a.steps.unwrap_or(p.mc().steps());
    if !(1..=10_000_000).contains(&steps) || a.runs.saturating_mul(steps) > 10_000_000 {
        return Err(CommandError::option(
            "--steps",
            format!(
                "{steps} steps × {} runs: at most 10 000 000 steps in all",
                a.runs
            ),
        ));
    }
    let npy = |f: &PathBuf| f.extension().is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    if a.time && (npy(&a.out) || a.truth.as_ref().is_some_and(npy)) {
        return Err(CommandError::option(
            "--time",
            "a .npy array has no room for times: write .csv or .jsonl",
        ));
    }
    let seed = a.seed.unwrap_or(p.mc().seed());
    check_output_file(&a.out, a.force).map_err(|e| e.of_flag("--out"))?;
    if let Some(t) = &a.truth {
        check_output_file(t, a.force).map_err(|e| e.of_flag("--truth"))?;
        if same_place(&a.out, t) {
            return Err(CommandError::option(
                "--truth",
                format!(
                    "{} is the file --out names: the states would overwrite the measurements",
                    t.display()
                ),
            ));
        }
    }
    let m: usize = dims.iter().sum();
    let sim = draw(truth, &dims, a.runs, steps, seed);
    let z: Vec<&[f64]> = sim
        .measurements
        .sequences
        .iter()
        .map(|s| s.z.as_slice())
        .collect();
    let mut outputs = Outputs::replacing(a.force);
    let dt = a.time.then_some(p.dt);
    outputs.file(&a.out, record_bytes(&a.out, "z", m, &z, dt)?);
    if let Some(t) = &a.truth {
        let x: Vec<&[f64]> = sim.states.iter().map(Vec::as_slice).collect();
        outputs.file(t, record_bytes(t, "x", sim.n, &x, dt)?);
    }
    outputs.commit()?;
    Ok(simulate_text(a.runs, steps, m, &a.out, seed))
}
