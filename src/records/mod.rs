//! Recorded Monte Carlo experiments: what a program in any language writes about its own
//! filter's runs (estimation errors and covariances, innovations and their covariances, or
//! their normalized forms), read from CSV, NumPy (`.npy`/`.npz`) and JSON Lines and summed
//! into the same [`Accumulator`] the built-in engines fill.
//!
//! The format is documented in `docs/external.md`. Every reader turns its rows or arrays
//! into [`StepRecord`]s, one per run and step, in order; a [`RecordSink`] checks their order
//! and shapes against a [`Layout`] and streams them into the sums, so memory does not grow
//! with the number of runs.

mod csv;
mod error;
mod files;
mod fingerprint;
mod json;
mod names;
mod npy;
mod rows;
mod sink;
mod wire;

pub use error::shown_number;
pub use error::{Breakdown, LayoutError, RecordError, SensorShapeError, ShapeError};
pub use files::{Recorded, feed_file, feed_files, read_files, scan_files};
pub(crate) use fingerprint::chain as fingerprint;
pub(crate) use json::object as json_object;
pub use json::parse_record_line;
pub use names::{Quantity, experiment_name, valid_sensor};
pub(crate) use npy::{read_numpy_records, read_raw as read_numpy_arrays};
pub use rows::shown_up_to;
pub use sink::{NormalizedSensor, RecordSink, StepSink, normalize_sensor};
pub use wire::{
    ChunkShape, ChunkSums, WireError, decode as decode_sums, decode_bytes as decode_sums_bytes,
    decode_packed_bytes as decode_packed_sums_bytes,
    decode_packed_bytes_into as decode_packed_sums_bytes_into, encode as encode_sums,
    encode_bytes as encode_sums_bytes, encode_into as encode_sums_into,
    encode_packed_into as encode_packed_sums_into, min_len as min_sums_len,
};

/// Largest number of steps per run records may have. The sums take memory proportional to
/// T, allocated before the first record is read, so T is checked first; this is the
/// engines' `montecarlo::MAX_STEPS`, repeated here because `records` sits below
/// `montecarlo` (tests/workers/records.rs checks the two agree).
pub const MAX_STEPS: usize = 1_000_000;

/// Most components a state or a sensor of records may have (e, P's side, nu, u, …): the
/// sums and the report grow with them (docs/external.md, Limits).
pub const MAX_COMPONENTS: usize = 4096;

/// The state quantities of a record: the ground-truth side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StateLayout {
    /// n, the dimension of the error state (the NEES's degrees of freedom).
    pub dim: usize,
    /// Whether the records give per-component data (`e`/`P`, or `e2p`).
    pub components: bool,
}

/// One sensor of a record.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SensorLayout {
    /// The sensor's name (empty for a single unnamed sensor).
    pub name: String,
    /// m_s, its measurement dimension.
    pub dim: usize,
    /// Whether the records give per-component data (`nu`/`S`, or `u`).
    pub components: bool,
}

/// What the records of one experiment hold: the state quantities (absent without ground
/// truth) and the sensors, in order.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Layout {
    /// The state quantities, `None` when the records carry no ground truth.
    pub state: Option<StateLayout>,
    /// The sensors, in the order their components are numbered.
    pub sensors: Vec<SensorLayout>,
}

impl Layout {
    /// State components the sums keep (n when the records give them, else 0).
    pub fn n_x(&self) -> usize {
        self.state.filter(|s| s.components).map_or(0, |s| s.dim)
    }

    /// Measurement components the sums keep: the sensors with per-component data.
    pub fn n_z(&self) -> usize {
        self.sensors
            .iter()
            .filter(|s| s.components)
            .map(|s| s.dim)
            .sum()
    }

    /// The index of sensor `name`.
    pub fn sensor(&self, name: &str) -> Option<usize> {
        self.sensors.iter().position(|s| s.name == name)
    }

    /// Where each sensor's components start among the measurement components (sensors
    /// without components take none).
    pub fn offsets(&self) -> Vec<usize> {
        let mut at = 0;
        self.sensors
            .iter()
            .map(|s| {
                let o = at;
                if s.components {
                    at += s.dim;
                }
                o
            })
            .collect()
    }

    /// State component names for reports: `x1 … xn`.
    pub fn default_state_names(&self) -> Vec<String> {
        (1..=self.n_x()).map(|j| format!("x{j}")).collect()
    }

    /// Measurement component names for reports: `<sensor>_<j>` (`z<j>` for an unnamed
    /// sensor), 1-based as in the files.
    pub fn default_measurement_names(&self) -> Vec<String> {
        self.sensors
            .iter()
            .filter(|s| s.components)
            .flat_map(|s| {
                (1..=s.dim).map(move |j| {
                    if s.name.is_empty() {
                        format!("z{j}")
                    } else {
                        format!("{}_{j}", s.name)
                    }
                })
            })
            .collect()
    }
}

/// The state side of one step: raw, or already normalized.
#[derive(Debug, Clone, PartialEq)]
pub enum StateRecord {
    /// Estimation error e (n) and covariance P (n × n, row-major).
    Raw {
        /// `x − x̂`.
        e: Vec<f64>,
        /// P, row-major.
        p: Vec<f64>,
    },
    /// A precomputed NEES.
    Normalized {
        /// `e' P⁻¹ e`.
        nees: f64,
        /// Its degrees of freedom.
        dof: f64,
        /// `e_j² / P_jj` per component, where given.
        e2p: Option<Vec<f64>>,
    },
}

/// One sensor's measurement at one step: raw, or already normalized.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorRecord {
    /// Innovation ν (m) and its covariance S (m × m, row-major).
    Raw {
        /// ν.
        nu: Vec<f64>,
        /// S, row-major.
        s: Vec<f64>,
    },
    /// A precomputed NIS.
    Normalized {
        /// `ν' S⁻¹ ν`.
        nis: f64,
        /// Its degrees of freedom.
        dof: f64,
        /// `ν_j / √S_jj` per component, where given.
        u: Option<Vec<f64>>,
    },
}

/// What one run recorded at one step.
#[derive(Debug, Clone, PartialEq)]
pub struct StepRecord {
    /// Run index (0-based).
    pub run: usize,
    /// Step (1-based).
    pub step: usize,
    /// The state side (absent without ground truth).
    pub state: Option<StateRecord>,
    /// The sensors that measured, by index into [`Layout::sensors`].
    pub sensors: Vec<(usize, SensorRecord)>,
    /// Set when the run's filter broke down at this step: the reason.
    pub diverged: Option<String>,
}

impl StepRecord {
    /// An empty record of run `run` at step `step`.
    pub fn new(run: usize, step: usize) -> Self {
        StepRecord {
            run,
            step,
            state: None,
            sensors: Vec::new(),
            diverged: None,
        }
    }
}
