//! Q and R from recorded measurements alone: the exact likelihood of a linear filter and its
//! maximum ([`ml`]), autocovariance least squares ([`als`]; with a full Q or R,
//! `als_full`, under the `sdp` feature), and the data such estimates are tried on
//! ([`simulate`]).

pub mod als;
#[cfg(feature = "sdp")]
pub mod als_full;
mod error;
mod files;
mod filter_replay;
mod likelihood;
pub mod ml;
mod ranges;
mod replay;

pub use files::{read_measurements, read_states, record_bytes};

pub use error::{EstimateError, NotDefinite};
pub use filter_replay::{FilterReplay, ReplayRefusal, ReplayStop};
pub use ranges::{GateRanges, LikelihoodRanges, Range, RangeEnd, gate_ranges, likelihood_ranges};
pub use replay::ReplayExperiment;

use nalgebra::DVector;

use crate::model::TruthModel;
use crate::montecarlo::run_rng;

/// One recorded sequence of a single sensor's measurements (a drive, a flight, a run).
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    /// Steps T.
    pub steps: usize,
    /// The measurements, T × m row-major; NaN where a component was not measured.
    pub z: Vec<f64>,
    /// Each step's time, s since the filter's initial state (the record's `time` column),
    /// increasing; empty when the record has none (the steps are then the filter's own).
    pub time: Vec<f64>,
}

/// Recorded measurements: several sequences of one sensor of dimension m.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasurementRecord {
    /// Measurement dimension m.
    pub dim: usize,
    /// The sequences.
    pub sequences: Vec<Sequence>,
}

impl MeasurementRecord {
    /// Whether every component was measured at every step.
    pub fn complete(&self) -> bool {
        self.sequences
            .iter()
            .all(|s| s.z.iter().all(|v| v.is_finite()))
    }

    /// Measured scalar values in all.
    pub fn values(&self) -> usize {
        self.sequences
            .iter()
            .map(|s| s.z.iter().filter(|v| v.is_finite()).count())
            .sum()
    }
}

/// What [`simulate`] draws: the measurements, and the truth states beside them (T × n per
/// sequence, row-major).
#[derive(Debug, Clone)]
pub struct Simulated {
    /// The measurements.
    pub measurements: MeasurementRecord,
    /// The true states, one `Vec` per sequence.
    pub states: Vec<Vec<f64>>,
    /// State dimension n.
    pub n: usize,
}

/// Draw `runs` sequences of `steps` steps from `truth` with the Monte Carlo engines' per-run
/// streams (run i uses `run_rng(seed, i)`), measuring the sensor of dimension `m` (index 0).
pub fn simulate(
    truth: &dyn TruthModel,
    m: usize,
    runs: usize,
    steps: usize,
    seed: u64,
) -> Simulated {
    simulate_sensors(truth, &[m], runs, steps, seed)
}

/// [`simulate`] with every sensor of dimension `dims[s]` (sensor s) side by side in the
/// record, in sensor order: a step's columns of a sensor that did not report stay NaN.
pub fn simulate_sensors(
    truth: &dyn TruthModel,
    dims: &[usize],
    runs: usize,
    steps: usize,
    seed: u64,
) -> Simulated {
    let n = truth.n_x();
    let m: usize = dims.iter().sum();
    let offsets = crate::measurement::sensor_offsets(dims);
    let mut sequences = Vec::with_capacity(runs);
    let mut states = Vec::with_capacity(runs);
    let mut meas = Vec::new();
    for i in 0..runs {
        let mut rng = run_rng(seed, i);
        let mut x: DVector<f64> = truth.initial_state(&mut rng);
        let mut z = vec![f64::NAN; steps * m];
        let mut xs = Vec::with_capacity(steps * n);
        for k in 1..=steps {
            x = truth.propagate(k, &x, &mut rng);
            meas.clear();
            truth.measure(k, &x, &mut rng, &mut meas);
            for me in meas.iter().filter(|me| me.sensor < dims.len()) {
                let o = (k - 1) * m + offsets[me.sensor];
                z[o..o + dims[me.sensor]].copy_from_slice(me.z.as_slice());
            }
            xs.extend_from_slice(x.as_slice());
        }
        sequences.push(Sequence {
            steps,
            z,
            time: Vec::new(),
        });
        states.push(xs);
    }
    Simulated {
        measurements: MeasurementRecord { dim: m, sequences },
        states,
        n,
    }
}
