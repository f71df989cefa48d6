//! Any filter held as code (a catalog model's EKF, UKF or ESKF, a Rust model's filter) run
//! over recorded measurements, as an [`Experiment`] judged by its innovations, and the
//! likelihood of those innovations (issue 39).
//!
//! A record's columns are the filter's sensors' components, concatenated in sensor order
//! (the problem's measurement names); a sensor reports at a step when its components are
//! given and is absent where they are empty, so sensors at different rates (a lidar and a
//! radar taking turns) share one record. The filter predicts to every step and updates with
//! each sensor that reported, in sensor order, as the Monte Carlo engine runs it; each
//! component's normalized innovation pairs with the same component's previous reading for
//! the whiteness tests, however many steps back.

use nalgebra::DVector;

use super::MeasurementRecord;
use crate::experiment::{Covariances, Definition, Experiment, ExperimentError, RunOptions};
use crate::filter::{Estimate, Filter, FilterError, Innovation};
use crate::linalg::cholesky;
use crate::measurement::{Measurement, sensor_offsets};
use crate::montecarlo::{Engine, McConfig};
use crate::params::Target;
use crate::stats::{Accumulator, RunRecorder, StopCause};

/// ln 2π.
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Why a record cannot be replayed through a problem's filter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplayRefusal {
    /// The problem's filter is not held by autotune (a worker's) or has no sensors.
    #[error("autotune does not hold {0}'s filter as code, so it cannot replay it over a record")]
    NoFilter(String),
    /// The filter predicts from inputs (IMU samples) that a record of measurements does
    /// not carry.
    #[error(
        "{problem}'s filter cannot run over a record of measurements alone: it does not support {what} (it predicts from inputs the truth supplies, which the record does not carry)"
    )]
    Inputs {
        /// The problem's name.
        problem: String,
        /// What the filter asked for.
        what: &'static str,
    },
    /// The record's components per step differ from the filter's.
    #[error("{record} components per step, but the filter's sensors measure {filter} ({names})")]
    Components {
        /// Components per step in the record.
        record: usize,
        /// Components of all the filter's sensors.
        filter: usize,
        /// The filter's component names, comma-separated.
        names: String,
    },
    /// A sensor's reading has some components given and others empty.
    #[error(
        "run {run}, step {step}: sensor {sensor} ({names}) has some components given and others empty: give all of a reading's components, or none where the sensor did not report"
    )]
    Partial {
        /// Run (0-based, as the record numbers them).
        run: usize,
        /// Step (1-based).
        step: usize,
        /// Sensor index.
        sensor: usize,
        /// The sensor's component names.
        names: String,
    },
    /// The settings the record implies (one run per sequence, its longest sequence's
    /// steps) are out of range.
    #[error("{0}")]
    Settings(String),
    /// The reference states do not line up with the record or the filter's state.
    #[error("{0}")]
    Reference(String),
    /// The record has times the filter cannot step by.
    #[error(
        "the record has a time column, but {0}'s filter steps only by its own step length: leave the column out to replay it at the filter's own steps"
    )]
    Times(String),
}

/// Where a replay stopped: the sequence, the step and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("sequence {sequence}, step {step}: {error}")]
pub struct ReplayStop {
    /// The sequence (0-based).
    pub sequence: usize,
    /// The step (1-based).
    pub step: usize,
    /// What the filter reported.
    pub error: FilterError,
}

/// A problem's filter held as code and a measurement record: one run per recorded
/// sequence, judged by its innovations (NIS, per-component `ν_j²/S_jj` and whiteness), and
/// by its errors against reference states where the record has them (NEES, `e_j²/P_jj`).
pub struct FilterReplay<'a> {
    definition: Definition,
    source: &'a dyn Experiment,
    data: MeasurementRecord,
    /// Reference states (RTK, motion capture, a simulator's log) beside the measurements,
    /// one T × n row-major block per sequence, in the filter's state order.
    reference: Option<MeasurementRecord>,
    /// Each sensor's dimension and first component.
    dims: Vec<usize>,
    offsets: Vec<usize>,
}

impl<'a> FilterReplay<'a> {
    /// The filter of `source` over `data`. Refused when `source` has no filter held as code
    /// ([`HeldAsCode::replay_filter`]), when the record's components differ from its
    /// sensors', or when a sensor's reading is given in part.
    pub fn new(source: &'a dyn Experiment, data: MeasurementRecord) -> Result<Self, ReplayRefusal> {
        let theta = source.params().values();
        let name = || source.info().name.clone();
        let filter = source
            .replay_filter(&theta)
            .ok_or_else(|| ReplayRefusal::NoFilter(name()))?;
        let dims = filter.sensor_dims();
        if dims.is_empty() {
            return Err(ReplayRefusal::NoFilter(name()));
        }
        // A filter driven by inputs (an INS by its IMU samples) cannot predict from a record
        // of measurements alone.
        if let Err(FilterError::Unsupported { what }) = filter.predict(1, &mut filter.initial()) {
            return Err(ReplayRefusal::Inputs {
                problem: name(),
                what,
            });
        }
        // A record with times steps the filter by them: it must say its own step length and
        // be able to depart from it.
        if data.sequences.iter().any(|s| !s.time.is_empty()) {
            let steps_by_time = filter.step_length().is_some_and(|h| {
                let mut est = filter.initial();
                filter.predict_over(1, &mut est, 0.5 * h).is_ok()
            });
            if !steps_by_time {
                return Err(ReplayRefusal::Times(name()));
            }
        }
        let offsets = sensor_offsets(&dims);
        let names = source.measurement_names();
        let total: usize = dims.iter().sum();
        if data.dim != total {
            return Err(ReplayRefusal::Components {
                record: data.dim,
                filter: total,
                names: names.join(", "),
            });
        }
        for (run, seq) in data.sequences.iter().enumerate() {
            for (k, z) in seq.z.chunks(data.dim).enumerate() {
                for (sensor, (&o, &d)) in offsets.iter().zip(&dims).enumerate() {
                    let given = z[o..o + d].iter().filter(|v| v.is_finite()).count();
                    if given != 0 && given != d {
                        return Err(ReplayRefusal::Partial {
                            run,
                            step: k + 1,
                            sensor,
                            names: names
                                .get(o..o + d)
                                .map_or_else(String::new, |n| n.join(", ")),
                        });
                    }
                }
            }
        }
        let mut definition = source.definition().clone();
        let steps = data.sequences.iter().map(|s| s.steps).max().unwrap_or(0);
        definition.mc = definition
            .mc
            .with_runs(data.sequences.len())
            .and_then(|mc| mc.with_steps(steps))
            .map_err(|e| ReplayRefusal::Settings(format!("{}: {}", e.setting, e.message)))?;
        Ok(FilterReplay {
            definition,
            source,
            data,
            reference: None,
            dims,
            offsets,
        })
    }

    /// The same replay judged against reference states as well (`states`: as many
    /// sequences as the record, each as long, n values a step in the filter's state order,
    /// every one given): NEES and each state's `e_j²/P_jj` join the innovations' tests.
    pub fn with_reference(mut self, states: MeasurementRecord) -> Result<Self, ReplayRefusal> {
        let n = self.definition.state_names.len();
        let refuse = |why: String| Err(ReplayRefusal::Reference(why));
        if states.dim != n {
            return refuse(format!(
                "{} values a step, but the filter's state has {n} ({})",
                states.dim,
                self.definition.state_names.join(", ")
            ));
        }
        if states.sequences.len() != self.data.sequences.len() {
            return refuse(format!(
                "{} sequences, but the measurements have {}",
                states.sequences.len(),
                self.data.sequences.len()
            ));
        }
        for (i, (x, z)) in states
            .sequences
            .iter()
            .zip(&self.data.sequences)
            .enumerate()
        {
            if x.steps != z.steps {
                return refuse(format!(
                    "run {i} has {} steps, its measurements {}",
                    x.steps, z.steps
                ));
            }
            if let Some(k) = x.z.iter().position(|v| !v.is_finite()) {
                return refuse(format!(
                    "run {i}, step {}: a state value is missing (every step needs the whole state)",
                    k / n + 1
                ));
            }
        }
        self.reference = Some(states);
        Ok(self)
    }

    /// The record.
    pub fn data(&self) -> &MeasurementRecord {
        &self.data
    }

    /// `−log L` of the record under the filter at `theta`: `½ Σ [log det S + ν'S⁻¹ν +
    /// m log 2π]` over every reading of every sequence (the prediction-error decomposition
    /// on the filter's own innovations; exact for a Kalman filter on its own model, the
    /// usual approximation for an EKF, UKF or ESKF).
    pub fn neg_log_likelihood(&self, theta: &[f64]) -> Result<f64, ReplayStop> {
        let filter = self.filter(theta);
        let mut nll = 0.0;
        for (i, seq) in self.data.sequences.iter().enumerate() {
            self.replay(&*filter, i, seq.steps, &mut |event| {
                if let Event::Update {
                    step, innovation, ..
                } = event
                {
                    let chol = cholesky(&innovation.S).ok_or(ReplayStop {
                        sequence: i,
                        step,
                        error: FilterError::NotPositiveDefinite { which: "S", step },
                    })?;
                    let log_det = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
                    nll += 0.5 * (log_det + innovation.nis + innovation.nu.len() as f64 * LN_2PI);
                }
                Ok(())
            })?;
        }
        Ok(nll)
    }

    fn filter(&self, theta: &[f64]) -> Box<dyn Filter + 'a> {
        // `new` found a filter at the start values; a source gives one at every θ.
        self.source
            .replay_filter(theta)
            .expect("a source that replays at one θ replays at every θ")
    }

    /// Run `filter` over sequence `i` (its first `steps` steps): `each` sees every update's
    /// innovation, in order, and the close of every step.
    fn replay(
        &self,
        filter: &dyn Filter,
        i: usize,
        steps: usize,
        each: &mut dyn FnMut(Event<'_>) -> Result<(), ReplayStop>,
    ) -> Result<(), ReplayStop> {
        let m = self.data.dim;
        let stop = |step, error| ReplayStop {
            sequence: i,
            step,
            error,
        };
        let mut est = filter.initial();
        let times = &self.data.sequences[i].time;
        let own = filter.step_length();
        for (k, z) in self.data.sequences[i].z.chunks(m).take(steps).enumerate() {
            let step = k + 1;
            // With times, the step from the last reading (the first from the initial state
            // at 0); the filter's own predict where that is its own step length.
            let over = match (times.get(k), own) {
                (Some(&t), Some(h)) => {
                    let dt = t - if k == 0 { 0.0 } else { times[k - 1] };
                    ((dt - h).abs() > 1e-9 * h).then_some(dt)
                }
                _ => None,
            };
            match over {
                Some(dt) => filter.predict_over(step, &mut est, dt),
                None => filter.predict(step, &mut est),
            }
            .map_err(|e| stop(step, e))?;
            for (sensor, (&o, &d)) in self.offsets.iter().zip(&self.dims).enumerate() {
                // `new` checked that a reading is given whole or not at all.
                if !z[o].is_finite() {
                    continue;
                }
                let meas = Measurement {
                    sensor,
                    z: DVector::from_column_slice(&z[o..o + d]),
                };
                let innovation = filter
                    .update(step, &mut est, &meas)
                    .map_err(|e| stop(step, e))?;
                if !innovation.nis.is_finite() {
                    return Err(stop(
                        step,
                        FilterError::NotPositiveDefinite { which: "S", step },
                    ));
                }
                each(Event::Update {
                    step,
                    offset: o,
                    innovation: &innovation,
                })?;
            }
            each(Event::Close { step, est: &est })?;
        }
        Ok(())
    }
}

/// What a replay reports as it goes.
enum Event<'i> {
    /// An update at `step` by the sensor whose first component is `offset`.
    Update {
        step: usize,
        offset: usize,
        innovation: &'i Innovation,
    },
    /// Every update of `step` is done; the estimate after them.
    Close { step: usize, est: &'i Estimate },
}

impl Experiment for FilterReplay<'_> {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    /// The filter at `theta` over every recorded sequence (the seed and the number of runs
    /// of `mc` do not apply: the data are what they are); steps beyond `mc`'s are not read.
    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        _options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let filter = self.filter(theta);
        let m = self.data.dim;
        let steps = mc.steps();
        // No truth: the state components stay empty, keeping their slots so that the
        // report lines up with the problem's state names.
        let n = self.definition.state_names.len();
        let mut acc = Accumulator::new(steps, n, m, mc.lags());
        let judged_n = if self.reference.is_some() { n } else { 0 };
        let mut rec = RunRecorder::new(judged_n, m, mc.lags());
        for i in 0..self.data.sequences.len() {
            rec.reset();
            let (mut nis, mut dof) = (0.0, 0usize);
            let mut run_nees = 0.0;
            let states = self.reference.as_ref().map(|r| &r.sequences[i].z);
            let run = self.replay(&*filter, i, steps, &mut |event| {
                match event {
                    Event::Update {
                        offset, innovation, ..
                    } => {
                        nis += innovation.nis;
                        dof += innovation.nu.len();
                        for j in 0..innovation.nu.len() {
                            let u = innovation.nu[j] / innovation.S[(j, j)].sqrt();
                            rec.innovation(offset + j, u);
                        }
                    }
                    Event::Close { step, est } => {
                        if dof > 0 {
                            acc.add_nis(step - 1, nis, dof as f64);
                        }
                        rec.end_step(&mut acc);
                        (nis, dof) = (0.0, 0);
                        if let Some(states) = states {
                            let truth =
                                DVector::from_column_slice(&states[(step - 1) * n..step * n]);
                            let e = filter.state_error(&truth, &est.x);
                            let stop = |which| ReplayStop {
                                sequence: i,
                                step,
                                error: FilterError::NotPositiveDefinite { which, step },
                            };
                            let chol = cholesky(&est.P).ok_or(stop("P"))?;
                            let nees = chol.solve(&e).dot(&e);
                            if !nees.is_finite() {
                                return Err(stop("P"));
                            }
                            acc.add_nees(step - 1, nees, n as f64);
                            run_nees += nees;
                            rec.state_step(&mut acc, (0..n).map(|j| e[j] / est.P[(j, j)].sqrt()));
                        }
                    }
                }
                Ok(())
            });
            match run {
                Ok(()) => {
                    if states.is_some() {
                        acc.add_run_nees_total(run_nees);
                    }
                    rec.end_run(&mut acc)
                }
                Err(s) => {
                    rec.stop_run(&mut acc);
                    let cause = match s.error {
                        FilterError::IllConditioned { .. } => StopCause::IllConditioned,
                        _ => StopCause::Diverged,
                    };
                    acc.record_stop(i, s.step, cause, s.error.to_string());
                    acc.runs += 1;
                }
            }
        }
        Ok(acc)
    }
}

impl crate::experiment::Structure for FilterReplay<'_> {
    fn supports(&self, engine: Engine) -> bool {
        engine != Engine::Linear
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.source.target(i)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.source.covariances(theta)
    }
}

impl crate::experiment::HeldAsCode for FilterReplay<'_> {}

impl crate::experiment::Sampling for FilterReplay<'_> {
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> crate::experiment::TruthReuse {
        crate::experiment::TruthReuse::Recorded
    }

    fn seed_free(&self) -> bool {
        true
    }
}
