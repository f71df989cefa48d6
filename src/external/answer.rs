//! The worker's side of a sums answer: a worker program that links this library (directly,
//! through its C ABI or through its Python package) hands it a request line and its runs'
//! records, and gets back the answer line that carries their sums instead of the records.
//! The records go through the same [`RecordSink`] (and, for arrays, the same NumPy reader)
//! as a records file would, so the sums are the records path's bit for bit, computed where
//! the numbers already are.

use std::path::Path;

use serde::Deserialize;

use crate::input::FileError;
use crate::records::{ChunkShape, ChunkSums, encode_sums, fingerprint};
use crate::records::{
    Layout, MAX_COMPONENTS, MAX_STEPS, RecordError, RecordSink, SensorLayout, SensorRecord,
    StateLayout, StateRecord, StepRecord, StepSink, read_numpy_records, valid_sensor,
};

/// Most runs one request may ask for: autotune asks for chunks of 64.
const MAX_RUNS: usize = 1 << 20;

/// Why a worker's chunk cannot be answered with sums.
#[derive(Debug, thiserror::Error)]
pub enum ChunkError {
    /// The request line is not one this library can answer (an older autotune sends no
    /// layout).
    #[error("request: {0}")]
    Request(String),
    /// A record was refused (its run, step and what is wrong).
    #[error("{0}")]
    Record(#[from] RecordError),
    /// The arrays were refused (which array, and why).
    #[error("{0}")]
    Arrays(#[from] FileError),
    /// A quantity given that the request's layout does not have, or given twice.
    #[error("{0}")]
    Given(String),
    /// Records given both step by step and as arrays.
    #[error("records given both step by step and as arrays: use one or the other per request")]
    Mixed,
}

/// The request fields a sums answer needs.
#[derive(Deserialize)]
struct RequestLine {
    id: u64,
    runs: [usize; 2],
    steps: usize,
    lags: Option<usize>,
    layout: Option<WireLayout>,
}

/// The records' layout as a request states it.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WireLayout {
    /// n, 0 without ground truth.
    state: usize,
    sensors: Vec<WireSensor>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WireSensor {
    name: String,
    dim: usize,
}

/// `"lags":L,"layout":{…}`: what a request adds so that a worker can sum its own records.
pub(super) fn request_fields(layout: &Layout, lags: usize) -> String {
    let state = layout.state.map_or(0, |s| s.dim);
    let sensors: Vec<String> = layout
        .sensors
        .iter()
        .map(|s| {
            format!(
                "{{\"name\":{},\"dim\":{}}}",
                serde_json::to_string(&s.name).expect("a string serializes"),
                s.dim
            )
        })
        .collect();
    format!(
        "\"lags\":{lags},\"layout\":{{\"state\":{state},\"sensors\":[{}]}}",
        sensors.join(",")
    )
}

/// The records of one request's runs, summed in the worker's process.
pub struct WorkerChunk {
    id: u64,
    layout: Layout,
    shape: ChunkShape,
    sink: Fingerprinted,
    arrays: Vec<(String, Vec<usize>, Vec<f64>)>,
    stepped: bool,
    /// The step being given quantity by quantity ([`WorkerChunk::state`] and
    /// [`WorkerChunk::sensor`]): its record, pushed when another step begins.
    pending: Option<StepRecord>,
}

/// The sums of the records so far, and each run's fingerprint.
struct Fingerprinted {
    sink: RecordSink,
    first: usize,
    prints: Vec<Option<u64>>,
}

impl StepSink for Fingerprinted {
    type Error = RecordError;

    fn push(&mut self, r: StepRecord) -> Result<(), RecordError> {
        // The sink refuses a run outside the request; the fingerprint waits for it.
        if let Some(slot) = r
            .run
            .checked_sub(self.first)
            .and_then(|i| self.prints.get_mut(i))
        {
            *slot = Some(fingerprint(*slot, &r));
        }
        self.sink.push(r)
    }
}

impl std::fmt::Debug for WorkerChunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerChunk")
            .field("id", &self.id)
            .field("shape", &self.shape)
            .finish_non_exhaustive()
    }
}

impl WorkerChunk {
    /// The chunk a request line asks for (the line autotune wrote to the worker's stdin).
    pub fn from_request(line: &str) -> Result<Self, ChunkError> {
        let bad = |m: String| ChunkError::Request(m);
        let req: RequestLine = serde_json::from_str(line.trim())
            .map_err(|e| bad(format!("not a request line: {e}")))?;
        let (Some(lags), Some(wl)) = (req.lags, req.layout) else {
            return Err(bad(
                "no \"layout\" and \"lags\": this autotune is older than its worker library; answer with records"
                    .into(),
            ));
        };
        let [a, b] = req.runs;
        if a >= b || b - a > MAX_RUNS {
            return Err(bad(format!(
                "runs [{a}, {b}): expected 1 to {MAX_RUNS} runs"
            )));
        }
        if !(1..=MAX_STEPS).contains(&req.steps) || lags > req.steps {
            return Err(bad(format!(
                "{} steps with {lags} lags: expected 1 to {MAX_STEPS} steps and no more lags",
                req.steps
            )));
        }
        if wl.state > MAX_COMPONENTS {
            return Err(bad(format!("state of {} components", wl.state)));
        }
        let mut sensors = Vec::new();
        for s in wl.sensors {
            if !valid_sensor(&s.name)
                || !(1..=MAX_COMPONENTS).contains(&s.dim)
                || sensors.iter().any(|o: &SensorLayout| o.name == s.name)
            {
                return Err(bad(format!("sensor {:?} of {} components", s.name, s.dim)));
            }
            sensors.push(SensorLayout {
                name: s.name,
                dim: s.dim,
                components: true,
            });
        }
        let layout = Layout {
            state: (wl.state > 0).then_some(StateLayout {
                dim: wl.state,
                components: true,
            }),
            sensors,
        };
        let shape = ChunkShape {
            runs: a..b,
            steps: req.steps,
            lags,
            n_x: layout.n_x(),
            n_z: layout.n_z(),
        };
        Ok(WorkerChunk {
            id: req.id,
            sink: Fingerprinted {
                sink: RecordSink::new(&layout, req.steps, lags).expecting(a..b),
                first: a,
                prints: vec![None; b - a],
            },
            layout,
            shape,
            arrays: Vec::new(),
            stepped: false,
            pending: None,
        })
    }

    /// The request's id.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// The runs asked for, [a, b).
    pub fn runs(&self) -> std::ops::Range<usize> {
        self.shape.runs.clone()
    }

    /// T, the steps per run.
    pub fn steps(&self) -> usize {
        self.shape.steps
    }

    /// The records' layout (state dimension, 0 without ground truth; sensors in order).
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Add the next record: runs in any order, each run's steps 1..=T in order (a run may
    /// end early at a record marked diverged).
    pub fn push(&mut self, r: StepRecord) -> Result<(), ChunkError> {
        self.flush()?;
        self.push_now(r)
    }

    fn push_now(&mut self, r: StepRecord) -> Result<(), ChunkError> {
        if !self.arrays.is_empty() {
            return Err(ChunkError::Mixed);
        }
        self.stepped = true;
        Ok(self.sink.push(r)?)
    }

    /// Push the step given quantity by quantity, if any.
    fn flush(&mut self) -> Result<(), ChunkError> {
        match self.pending.take() {
            Some(mut r) => {
                // In layout order, as a records file's columns give them: the sums then add
                // a step's sensors in the records path's order, bit for bit.
                r.sensors.sort_by_key(|(k, _)| *k);
                self.push_now(r)
            }
            None => Ok(()),
        }
    }

    /// The record of (run, step), begun (and the one before pushed) when new.
    fn pending(&mut self, run: usize, step: usize) -> Result<&mut StepRecord, ChunkError> {
        // Refused at the call that gives them, naming the argument, rather than at the
        // answer (where a step 0 would read as a run given twice).
        let runs = self.runs();
        if !runs.contains(&run) {
            return Err(ChunkError::Given(format!(
                "run {run} is not one the request asks for ({}..{})",
                runs.start, runs.end
            )));
        }
        if !(1..=self.steps()).contains(&step) {
            return Err(ChunkError::Given(format!(
                "run {run}: step {step} is outside the request's steps 1..={}",
                self.steps()
            )));
        }
        if self
            .pending
            .as_ref()
            .is_some_and(|p| (p.run, p.step) != (run, step))
        {
            self.flush()?;
        }
        Ok(self
            .pending
            .get_or_insert_with(|| StepRecord::new(run, step)))
    }

    /// Run `run`'s estimation error `e` = x − x̂ (n) and covariance `p` (n × n, row-major)
    /// after step `step` (1-based).
    pub fn state(
        &mut self,
        run: usize,
        step: usize,
        e: Vec<f64>,
        p: Vec<f64>,
    ) -> Result<(), ChunkError> {
        if self.layout.state.is_none() {
            return Err(ChunkError::Given(
                "the problem has no state_names: its records carry no ground truth".into(),
            ));
        }
        self.pending(run, step)?.state = Some(StateRecord::Raw { e, p });
        Ok(())
    }

    /// Run `run`'s innovation `nu` (m) and its covariance `s` (m × m, row-major) from sensor
    /// `sensor` at step `step`; a sensor that did not measure is not given.
    pub fn sensor(
        &mut self,
        run: usize,
        step: usize,
        sensor: &str,
        nu: Vec<f64>,
        s: Vec<f64>,
    ) -> Result<(), ChunkError> {
        let k = self.layout.sensor(sensor).ok_or_else(|| {
            ChunkError::Given(format!("no sensor {sensor:?} in the request's layout"))
        })?;
        let r = self.pending(run, step)?;
        if r.sensors.iter().any(|(j, _)| *j == k) {
            return Err(ChunkError::Given(format!(
                "run {run}, step {step}: sensor {sensor:?} given twice"
            )));
        }
        r.sensors.push((k, SensorRecord::Raw { nu, s }));
        Ok(())
    }

    /// Run `run`'s filter broke down at step `step`, for `reason`: the run ends there.
    pub fn diverged(&mut self, run: usize, step: usize, reason: &str) -> Result<(), ChunkError> {
        let r = self.pending(run, step)?;
        r.state = None;
        r.sensors.clear();
        r.diverged = Some(reason.to_string());
        Ok(())
    }

    /// The dimension of sensor `name`, if the request's layout has it.
    pub fn sensor_dim(&self, name: &str) -> Option<usize> {
        self.layout.sensor(name).map(|k| self.layout.sensors[k].dim)
    }

    /// n, the state dimension (0 without ground truth).
    pub fn state_dim(&self) -> usize {
        self.layout.state.map_or(0, |s| s.dim)
    }

    /// Add one array of the NumPy layout (`e` (runs, T, n), `P` (runs, T, n, n) or (T, n, n),
    /// `nu_<sensor>`, `S_<sensor>`, `diverged` (runs,), … as in docs/src/records.md), its
    /// first axis the runs asked for; `data` is in C order. The arrays are summed at
    /// [`WorkerChunk::answer`].
    pub fn add_array(
        &mut self,
        name: &str,
        shape: Vec<usize>,
        data: Vec<f64>,
    ) -> Result<(), ChunkError> {
        if self.stepped || self.pending.is_some() {
            return Err(ChunkError::Mixed);
        }
        let elements = shape
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d))
            .filter(|&n| n == data.len());
        let refuse = |why: String| FileError::new(Path::new(ARRAYS), format!("array {name}"), why);
        if elements.is_none() {
            return Err(refuse(format!(
                "shape {shape:?} does not hold its {} numbers",
                data.len()
            ))
            .into());
        }
        if self.arrays.iter().any(|(n, _, _)| n == name) {
            return Err(refuse("given twice".into()).into());
        }
        self.arrays.push((name.to_string(), shape, data));
        Ok(())
    }

    /// The answer line (`{"id":…,"sums":"…"}`, no newline): the sums of every run asked
    /// for. A missing run, a step out of order or an array of the wrong shape is an error
    /// naming it, as it would be in a records file.
    pub fn answer(mut self) -> Result<String, ChunkError> {
        self.flush()?;
        let WorkerChunk {
            id,
            layout,
            shape,
            mut sink,
            arrays,
            ..
        } = self;
        if !arrays.is_empty() {
            read_numpy_records(
                Path::new(ARRAYS),
                arrays,
                &layout,
                shape.steps,
                shape.runs.start,
                &mut sink,
            )?;
        }
        let sums = sink.sink.finish()?;
        let prints = sink
            .prints
            .into_iter()
            .map(Option::unwrap_or_default)
            .collect();
        let text = encode_sums(&ChunkSums { sums, prints }, &shape);
        Ok(format!("{{\"id\":{id},\"sums\":\"{text}\"}}"))
    }
}

/// What errors call the arrays of an answer, in place of a file name.
const ARRAYS: &str = "the answer's arrays";
