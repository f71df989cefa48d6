//! Records into sums: [`RecordSink`] checks each run's steps arrive in order with the
//! layout's shapes, normalizes raw errors and innovations exactly as the built-in engines
//! do, and streams them into an [`Accumulator`].

use std::collections::HashSet;

use nalgebra::{DMatrix, DVector};

use super::error::{Breakdown, MAX_DOF, RecordError, SensorShapeError, ShapeError};
use super::{Layout, SensorRecord, StateRecord, StepRecord};
use crate::linalg::{cholesky_owned, mahalanobis_sq};
use crate::stats::{Accumulator, RunRecorder, StopCause};

/// `log 2π`, the constant of each measured component's Gaussian density.
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// One sensor's measurement normalized: its NIS, degrees of freedom and, where the record
/// gives them, the per-component normalized innovations `ν_j/√S_jj`.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalizedSensor {
    /// `ν' S⁻¹ ν`.
    pub nis: f64,
    /// Its degrees of freedom.
    pub dof: f64,
    /// `ν_j/√S_jj` per component (`components` set, or `u` given).
    pub u: Option<Vec<f64>>,
    /// `log det S`, where the record gives S (a normalized record does not).
    pub log_det: Option<f64>,
}

/// Normalize one sensor record of dimension `dim`. `Err` is a shape error (the record does
/// not fit the layout: a malformed file); `Ok(Err(why))` numbers that show the filter broke
/// down (NaN, infinite, S not positive definite, a negative NIS). With `components`, a raw
/// record's per-component values are kept and a normalized one must carry `u`.
pub fn normalize_sensor(
    rec: &SensorRecord,
    dim: usize,
    components: bool,
) -> Result<Result<NormalizedSensor, Breakdown>, SensorShapeError> {
    let m = dim;
    match rec {
        SensorRecord::Raw { nu, s: sm } => {
            if nu.len() != m || sm.len() != m * m {
                return Err(SensorShapeError::Sizes {
                    nu: nu.len(),
                    s: sm.len(),
                    m,
                });
            }
            if nu.iter().chain(sm).any(|v| !v.is_finite()) {
                return Ok(Err(Breakdown::NotFinite("nu or S")));
            }
            let Some(chol) = cholesky_owned(DMatrix::from_row_slice(m, m, sm)) else {
                return Ok(Err(Breakdown::NotPositiveDefinite("S")));
            };
            let nis = mahalanobis_sq(&chol, &DVector::from_column_slice(nu));
            if !nis.is_finite() {
                return Ok(Err(Breakdown::Overflowed("NIS")));
            }
            let u = components.then(|| (0..m).map(|j| nu[j] / sm[j * m + j].sqrt()).collect());
            let log_det = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            Ok(Ok(NormalizedSensor {
                nis,
                dof: m as f64,
                u,
                log_det: Some(log_det),
            }))
        }
        SensorRecord::Normalized { nis, dof, u } => {
            // Degrees of freedom count components: a fraction is a mistake in the file, as
            // `autotune nis` says of the same column.
            if !(*dof >= 1.0 && *dof <= MAX_DOF && dof.fract() == 0.0) {
                return Err(SensorShapeError::Dof(*dof));
            }
            if components != u.is_some() {
                return Err(SensorShapeError::SometimesU);
            }
            if let Some(u) = u {
                if u.len() != m {
                    return Err(SensorShapeError::ULength { len: u.len(), m });
                }
                if u.iter().any(|x| !x.is_finite()) {
                    return Ok(Err(Breakdown::NotFinite("u")));
                }
            }
            if !nis.is_finite() || *nis < 0.0 {
                return Ok(Err(Breakdown::NegativeOrNotFinite("NIS")));
            }
            Ok(Ok(NormalizedSensor {
                nis: *nis,
                dof: *dof,
                u: u.clone(),
                log_det: None,
            }))
        }
    }
}

/// A step's normalized state: its NEES and degrees of freedom, `e_j²/P_jj` where given,
/// and `e_j/√P_jj` for raw records with `components`.
type NormalizedState = ((f64, f64), Option<Vec<f64>>, Option<Vec<f64>>);

/// Normalize one state record of dimension `n`, as [`normalize_sensor`] a sensor's.
fn normalize_state(
    state: &StateRecord,
    n: usize,
    components: bool,
) -> Result<Result<NormalizedState, Breakdown>, ShapeError> {
    match state {
        StateRecord::Raw { e, p } => {
            if e.len() != n || p.len() != n * n {
                return Err(ShapeError::StateSizes {
                    e: e.len(),
                    p: p.len(),
                    n,
                });
            }
            if e.iter().chain(p).any(|v| !v.is_finite()) {
                return Ok(Err(Breakdown::NotFinite("e or P")));
            }
            let Some(chol) = cholesky_owned(DMatrix::from_row_slice(n, n, p)) else {
                return Ok(Err(Breakdown::NotPositiveDefinite("P")));
            };
            let nees = mahalanobis_sq(&chol, &DVector::from_column_slice(e));
            if !nees.is_finite() {
                return Ok(Err(Breakdown::Overflowed("NEES")));
            }
            let ep = components.then(|| (0..n).map(|j| e[j] / p[j * n + j].sqrt()).collect());
            Ok(Ok(((nees, n as f64), None, ep)))
        }
        StateRecord::Normalized { nees, dof, e2p } => {
            if !(*dof >= 1.0 && *dof <= MAX_DOF && dof.fract() == 0.0) {
                return Err(ShapeError::NeesDof(*dof));
            }
            if components != e2p.is_some() {
                return Err(ShapeError::SometimesE2p);
            }
            if let Some(c) = e2p
                && c.len() != n
            {
                return Err(ShapeError::E2pLength { len: c.len(), n });
            }
            let bad = !nees.is_finite()
                || *nees < 0.0
                || e2p
                    .as_ref()
                    .is_some_and(|c| c.iter().any(|v| !v.is_finite() || *v < 0.0));
            if bad {
                return Ok(Err(Breakdown::NegativeOrNotFinite("NEES or e2p")));
            }
            Ok(Ok(((*nees, *dof), e2p.clone(), None)))
        }
    }
}

/// Why a run stops at a step: a breakdown of its state's numbers, or of a sensor's.
struct Stopped {
    /// The sensor (empty: the unnamed one), `None` for the state or the step's total NIS.
    sensor: Option<String>,
    why: Breakdown,
}

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.sensor.as_deref() {
            None => write!(f, "{}", self.why),
            Some("") => write!(f, "the sensor: {}", self.why),
            Some(name) => write!(f, "sensor {name}: {}", self.why),
        }
    }
}

/// Where a reader's [`StepRecord`]s go: the Monte Carlo sums ([`RecordSink`]), or another
/// consumer (the field-log reader takes records without truth as a log).
pub trait StepSink {
    /// Why a record is refused.
    type Error: std::error::Error;
    /// Add the next record; `Err` names what is wrong with it (run, step, quantity).
    fn push(&mut self, r: StepRecord) -> Result<(), Self::Error>;
}

impl StepSink for RecordSink {
    type Error = RecordError;

    fn push(&mut self, r: StepRecord) -> Result<(), RecordError> {
        RecordSink::push(self, r)
    }
}

/// The run being read.
struct Current {
    run: usize,
    last_step: usize,
    stopped: bool,
    nees_total: f64,
}

/// A step's numbers, normalized, before they join the sums.
struct Normalized {
    nees: Option<(f64, f64)>,
    e2p: Option<Vec<f64>>,
    /// `e_j/√P_jj`, when the records give e and P (`e2p` is then unused).
    ep: Option<Vec<f64>>,
    nis: Option<(f64, f64)>,
    /// `(component, ν_j/√S_jj)`.
    u: Vec<(usize, f64)>,
    /// The step's `−log L` terms, `½ (log det S + ν'S⁻¹ν + m log 2π)` summed over its
    /// sensors; `None` when a sensor's record is normalized (no S to take log det of).
    nll: Option<f64>,
}

/// Streams [`StepRecord`]s of one experiment (T steps, `lags` whiteness lags) into an
/// [`Accumulator`]. A record out of order or of the wrong shape is an error (a message
/// naming the run, the step and the quantity); numbers that show the filter broke down
/// (NaN, infinite, a covariance that is not positive definite) stop the run as diverged.
pub struct RecordSink {
    layout: Layout,
    steps: usize,
    offsets: Vec<usize>,
    acc: Accumulator,
    recorder: RunRecorder,
    current: Option<Current>,
    seen: HashSet<usize>,
    /// The runs expected, where known (a worker's answer to a request).
    expected: Option<std::ops::Range<usize>>,
    /// `−log L` of the innovations so far; `None` once a record gave no S or a run
    /// stopped (the filter has no likelihood there).
    nll: Option<f64>,
}

impl RecordSink {
    /// A sink for records of `layout`, T = `steps`, with `lags` whiteness lags.
    pub fn new(layout: &Layout, steps: usize, lags: usize) -> Self {
        let (n_x, n_z) = (layout.n_x(), layout.n_z());
        RecordSink {
            layout: layout.clone(),
            steps,
            offsets: layout.offsets(),
            acc: Accumulator::new(steps, n_x, n_z, lags),
            recorder: RunRecorder::new(n_x, n_z, lags),
            current: None,
            seen: HashSet::new(),
            expected: None,
            nll: Some(0.0),
        }
    }

    /// Expect exactly the runs in `runs`: another run is an error, and so is a missing one
    /// at [`RecordSink::finish`].
    pub fn expecting(mut self, runs: std::ops::Range<usize>) -> Self {
        self.expected = Some(runs);
        self
    }

    /// Runs read so far (finished or stopped).
    pub fn runs(&self) -> usize {
        self.seen.len()
    }

    /// Add the next record.
    pub fn push(&mut self, r: StepRecord) -> Result<(), RecordError> {
        let (run, k) = (r.run, r.step);
        if self.current.as_ref().is_none_or(|c| c.run != run) {
            if let Some(range) = &self.expected
                && !range.contains(&run)
            {
                return Err(RecordError::NotAskedFor {
                    run,
                    asked: range.clone(),
                });
            }
            self.close()?;
            if !self.seen.insert(run) {
                return Err(RecordError::RunTwice(run));
            }
            self.recorder.reset();
            self.current = Some(Current {
                run,
                last_step: 0,
                stopped: false,
                nees_total: 0.0,
            });
        }
        let cur = self.current.as_mut().expect("set above");
        if k != cur.last_step + 1 {
            return Err(RecordError::StepGap {
                run,
                step: k,
                last: cur.last_step,
                steps: self.steps,
            });
        }
        if k > self.steps {
            return Err(RecordError::StepBeyond {
                run,
                step: k,
                steps: self.steps,
            });
        }
        cur.last_step = k;
        // A filter that broke down usually goes on printing NaN: what follows the step it
        // stopped at is read for its order only.
        if cur.stopped {
            return Ok(());
        }
        if let Some(reason) = r.diverged {
            self.stop(run, k, reason);
            return Ok(());
        }
        match self.normalize(&r).map_err(|problem| RecordError::Shape {
            run,
            step: k,
            problem,
        })? {
            Ok(n) => {
                self.add(k, n);
                Ok(())
            }
            Err(stopped) => {
                self.stop(run, k, format!("{stopped} at step {k}"));
                Ok(())
            }
        }
    }

    /// The sums, once every run is complete, and `−log L` of every innovation the records
    /// hold (`½ Σ (log det S + ν'S⁻¹ν + m log 2π)`: a filter replayed over a record), or
    /// `None` where a record is normalized or a run stopped.
    pub fn finish_with_likelihood(self) -> Result<(Accumulator, Option<f64>), RecordError> {
        let nll = self.nll;
        self.finish().map(|acc| (acc, nll))
    }

    /// The sums, once every run is complete.
    pub fn finish(mut self) -> Result<Accumulator, RecordError> {
        self.close()?;
        if let Some(range) = &self.expected
            && self.seen.len() != range.len()
        {
            let missing = range
                .clone()
                .find(|r| !self.seen.contains(r))
                .unwrap_or(range.start);
            return Err(RecordError::RunsMissing {
                came: self.seen.len(),
                asked: range.clone(),
                missing,
            });
        }
        if self.acc.runs == 0 {
            return Err(RecordError::NoRuns);
        }
        Ok(self.acc)
    }

    /// Close the current run: it must have reached step T, or have stopped.
    fn close(&mut self) -> Result<(), RecordError> {
        let Some(cur) = self.current.take() else {
            return Ok(());
        };
        if cur.stopped {
            return Ok(());
        }
        if cur.last_step != self.steps {
            return Err(RecordError::EndsEarly {
                run: cur.run,
                last: cur.last_step,
                steps: self.steps,
            });
        }
        if self.layout.state.is_some() {
            self.acc.add_run_nees_total(cur.nees_total);
        }
        self.recorder.end_run(&mut self.acc);
        Ok(())
    }

    fn stop(&mut self, run: usize, k: usize, reason: String) {
        self.nll = None;
        self.recorder.stop_run(&mut self.acc);
        self.acc.record_stop(run, k, StopCause::Diverged, reason);
        self.acc.runs += 1;
        if let Some(c) = self.current.as_mut() {
            c.stopped = true;
        }
    }

    /// Check the record's shapes (a shape error is `Err`), then normalize it: `Ok(Err(why))`
    /// when its numbers show a filter that broke down.
    fn normalize(&self, r: &StepRecord) -> Result<Result<Normalized, Stopped>, ShapeError> {
        let mut out = Normalized {
            nees: None,
            e2p: None,
            ep: None,
            nis: None,
            u: Vec::new(),
            nll: Some(0.0),
        };
        match (&self.layout.state, &r.state) {
            (None, None) => {}
            (None, Some(_)) => return Err(ShapeError::UnexpectedState),
            (Some(_), None) => return Err(ShapeError::NoState),
            (Some(layout), Some(state)) => {
                match normalize_state(state, layout.dim, layout.components)? {
                    Ok((nees, e2p, ep)) => {
                        out.nees = Some(nees);
                        out.e2p = e2p;
                        out.ep = ep;
                    }
                    Err(why) => return Ok(Err(Stopped { sensor: None, why })),
                }
            }
        }
        let mut nis = 0.0;
        let mut dof = 0.0;
        for (s, rec) in &r.sensors {
            let Some(layout) = self.layout.sensors.get(*s) else {
                return Err(ShapeError::SensorIndex(*s));
            };
            let n = match normalize_sensor(rec, layout.dim, layout.components) {
                Ok(Ok(n)) => n,
                Ok(Err(why)) => {
                    return Ok(Err(Stopped {
                        sensor: Some(layout.name.clone()),
                        why,
                    }));
                }
                Err(problem) => {
                    return Err(ShapeError::Sensor {
                        sensor: layout.name.clone(),
                        problem,
                    });
                }
            };
            nis += n.nis;
            dof += n.dof;
            out.nll = match (out.nll, n.log_det) {
                (Some(sum), Some(log_det)) => Some(sum + 0.5 * (log_det + n.nis + n.dof * LN_2PI)),
                _ => None,
            };
            if let Some(u) = n.u {
                let o = self.offsets[*s];
                out.u
                    .extend(u.into_iter().enumerate().map(|(j, x)| (o + j, x)));
            }
        }
        if !nis.is_finite() {
            return Ok(Err(Stopped {
                sensor: None,
                why: Breakdown::Overflowed("NIS"),
            }));
        }
        if dof > 0.0 {
            out.nis = Some((nis, dof));
        }
        Ok(Ok(out))
    }

    /// Add a normalized step to the sums, in the generic engine's order.
    fn add(&mut self, k: usize, n: Normalized) {
        let i = k - 1;
        self.nll = self.nll.zip(n.nll).map(|(a, b)| a + b);
        if let Some((nis, dof)) = n.nis {
            self.acc.add_nis(i, nis, dof);
        }
        for (j, u) in n.u {
            self.recorder.innovation(j, u);
        }
        self.recorder.end_step(&mut self.acc);
        if let Some((nees, dof)) = n.nees {
            self.acc.add_nees(i, nees, dof);
            if let Some(c) = self.current.as_mut() {
                c.nees_total += nees;
            }
        }
        if let Some(ep) = n.ep {
            self.recorder.state_step(&mut self.acc, ep.into_iter());
        } else if let Some(e2p) = n.e2p {
            self.recorder
                .state_step_squares(&mut self.acc, e2p.into_iter());
        }
    }
}
