//! One run of the generic engine: its steps, the NEES's factor of P, and the run's
//! predicted NEES variance.

use nalgebra::{DMatrix, DVector};

use super::fault::Fault;
use crate::filter::conditioning::check_conditioned_factor;
use crate::filter::{Estimate, Filter, FilterError, Innovation, check_measurement};
use crate::linalg::cholesky_in_place;
use crate::measurement::Measurement;
use crate::montecarlo::McConfig;
use crate::montecarlo::tape::TruthSource;
use crate::stats::{Accumulator, ComponentNullVariance, GateMode, NeesNullVariance, RunRecorder};

/// Why [`one_run`] stopped.
pub(super) enum Stop {
    Filter(FilterError),
    Fault(Fault, usize),
}

impl From<FilterError> for Stop {
    fn from(e: FilterError) -> Self {
        Stop::Filter(e)
    }
}

/// The generic engine computes the NEES-sum variance its filter predicts (an O(n³) matrix
/// recursion per step, as costly as a 15-state filter itself) on every this-many-th run
/// only. The predicted variance depends on the data only through the linearization
/// points, so it varies little between runs; the sampled mean stands for all of them (for
/// a linear filter it is the same in every run, and the estimate is exact).
pub const NULL_VAR_STRIDE: usize = 8;

/// The filter's sensors: each one's dimension and first component's offset.
#[derive(Clone, Copy)]
pub(super) struct Shape<'a> {
    pub(super) offsets: &'a [usize],
    pub(super) dims: &'a [usize],
}

pub(super) fn one_run<S, F>(
    mut truth: S,
    filter: &F,
    mc: &McConfig,
    run: usize,
    shape: Shape<'_>,
    acc: &mut Accumulator,
    work: &mut Work,
) -> Result<(), Stop>
where
    S: TruthSource,
    F: Filter + ?Sized,
{
    let Work {
        recorder: scratch,
        bufs,
        error,
        innovation,
        ..
    } = work;
    let n_x = filter.n_x();
    let mut est = filter.initial();
    let mut null_var = RunNullVariance::new(n_x, mc, run);
    let mut run_nees = 0.0;
    for k in 1..=mc.steps() {
        let i = k - 1;
        if !truth.advance(k) {
            return Err(Stop::Fault(Fault::TruthOverflow, k));
        }
        match truth.input() {
            Some(u) => filter.predict_with_input(k, &mut est, u)?,
            None => filter.predict(k, &mut est)?,
        }
        let step = Step {
            filter,
            k,
            shape,
            scratch: &mut *scratch,
            out: &mut *innovation,
        };
        let (nis, dof) = update_all(step, &mut est, truth.measurements())?;

        filter.state_error_into(truth.state(), &est.x, error);
        let e = &*error;
        let StepBuffers { factors, whitened } = &mut *bufs;
        let Some(l) = factors.factor(k, &est.P) else {
            return Err(Stop::Filter(FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            }));
        };
        check_conditioned_factor("P", &est.P, l, k)?;
        // The estimate's magnitude is comparable with P only when it is laid out as the
        // error state (an error-state filter's nominal state is not).
        if est.x.len() == n_x
            && let Some(f) = Fault::resolution(n_x, |j| {
                est.x[j] * est.x[j] / est.P[(j, j)].max(e[j] * e[j])
            })
        {
            return Err(Stop::Fault(f, k));
        }
        let nees = mahalanobis_sq(l, whitened, e);
        if !nees.is_finite() || !nis.is_finite() {
            return Err(Stop::Fault(Fault::Overflow, k));
        }
        if dof > 0 {
            acc.add_nis(i, nis, dof as f64);
        }
        scratch.end_step(acc);
        acc.add_nees(i, nees, n_x as f64);
        run_nees += nees;
        scratch.state_step(acc, (0..n_x).map(|j| e[j] / est.P[(j, j)].sqrt()));
        null_var.step(&est, l);
    }
    acc.add_run_nees_total(run_nees);
    null_var.add_to(acc);
    Ok(())
}

/// A thread's storage, reused from run to run: the run's recorder, the step's buffers, the
/// state error (n_x), the last update's innovation and a live truth's measurements.
pub(super) struct Work {
    pub(super) recorder: RunRecorder,
    pub(super) bufs: StepBuffers,
    pub(super) error: DVector<f64>,
    pub(super) innovation: Innovation,
    /// A live truth's measurements of the step.
    pub(super) meas: Vec<Measurement>,
}

/// Storage a step's NEES reuses from step to step, so that factoring P and whitening the
/// error allocate nothing; the arithmetic is [`crate::linalg::cholesky`]'s and
/// [`crate::linalg::mahalanobis_sq`]'s, bit for bit ([`cholesky_in_place`]).
#[derive(Default)]
pub(super) struct StepBuffers {
    /// P's lower Cholesky factors.
    factors: Factors,
    /// `L⁻¹ e`, n_x.
    whitened: DVector<f64>,
}

/// Bytes of P's and their factors a thread's [`Factors`] holds at most, and steps (the
/// slots take memory before any matrix).
const FACTOR_BYTES: usize = 4 << 20;
const FACTOR_STEPS: usize = 1 << 14;

/// P's lower Cholesky factor at each step, with the P it was computed from (n_x × n_x
/// each; the factor's strict upper triangle is P's). A linear filter's P at a step is the
/// same in every run, so the runs after the first find the factor of their P, the same
/// bits, instead of computing it again (it was a tenth of a run's time on a filter held as
/// code); a filter whose P depends on the readings (an EKF) finds none and computes it, as
/// before. Steps past the byte budget share one slot and are always computed.
#[derive(Default)]
struct Factors {
    slots: Vec<(DMatrix<f64>, DMatrix<f64>)>,
}

impl Factors {
    /// P's factor at step `k` (from 1); `None` when P has a non-finite entry or is not
    /// positive definite.
    #[inline]
    fn factor(&mut self, k: usize, p: &DMatrix<f64>) -> Option<&DMatrix<f64>> {
        let held =
            (FACTOR_BYTES / (2 * std::mem::size_of::<f64>() * p.len()).max(1)).min(FACTOR_STEPS);
        let slot = k.saturating_sub(1).min(held);
        if self.slots.len() <= slot {
            self.slots
                .resize_with(slot + 1, || (DMatrix::zeros(0, 0), DMatrix::zeros(0, 0)));
        }
        let (from, l) = &mut self.slots[slot];
        // Only a factor that succeeded is kept with its P, and its P was finite.
        if slot < held && crate::linalg::same_bits(from, p) {
            return Some(l);
        }
        if p.iter().any(|v| !v.is_finite()) {
            return None;
        }
        if l.shape() != p.shape() {
            *l = DMatrix::zeros(p.nrows(), p.ncols());
        }
        l.copy_from(p);
        if !cholesky_in_place(l) {
            *from = DMatrix::zeros(0, 0);
            return None;
        }
        if slot < held {
            if from.shape() != p.shape() {
                *from = DMatrix::zeros(p.nrows(), p.ncols());
            }
            from.copy_from(p);
        }
        Some(l)
    }
}

/// `e' P⁻¹ e = |L⁻¹ e|²` from P's lower factor `l`, whitening into `whitened`.
#[inline]
fn mahalanobis_sq(l: &DMatrix<f64>, whitened: &mut DVector<f64>, e: &DVector<f64>) -> f64 {
    if whitened.len() != e.len() {
        *whitened = DVector::zeros(e.len());
    }
    whitened.copy_from(e);
    // A Cholesky factor's diagonal is positive, so the solve always succeeds.
    l.solve_lower_triangular_mut(whitened);
    whitened.norm_squared()
}

/// What updating a step needs besides the estimate and the measurements: the filter, the
/// step `k`, the sensors' layout, the run's recorder and the innovation's storage.
struct Step<'a, F: ?Sized> {
    filter: &'a F,
    k: usize,
    shape: Shape<'a>,
    scratch: &'a mut RunRecorder,
    out: &'a mut Innovation,
}

/// Update the filter with every measurement of step `k`: the step's NIS and its degrees
/// of freedom, and each component's normalized innovation into the recorder.
#[inline]
fn update_all<F: Filter + ?Sized>(
    step: Step<'_, F>,
    est: &mut Estimate,
    meas: &[Measurement],
) -> Result<(f64, usize), Stop> {
    let Step {
        filter,
        k,
        shape: Shape { offsets, dims },
        scratch,
        out,
    } = step;
    let (mut nis, mut dof) = (0.0, 0usize);
    for m in meas {
        check_measurement(dims.get(m.sensor).copied(), m)?;
        filter.update_into(k, est, m, out)?;
        nis += out.nis;
        dof += m.z.len();
        for j in 0..m.z.len() {
            scratch.innovation(offsets[m.sensor] + j, out.nu[j] / out.S[(j, j)].sqrt());
        }
    }
    Ok((nis, dof))
}

/// The predicted variance of one run's NEES sums (and, for the full gate, of its
/// per-component sums), from the filter's error map; sampled every [`NULL_VAR_STRIDE`]-th
/// run.
struct RunNullVariance {
    sample: bool,
    nees: NeesNullVariance,
    /// The per-component variances cost n_x times the NEES one; only the full gate reads
    /// them.
    components: Option<ComponentNullVariance>,
    /// The filter did not give its error map at some step.
    map_missing: bool,
}

impl RunNullVariance {
    fn new(n_x: usize, mc: &McConfig, run: usize) -> Self {
        let sample = run.is_multiple_of(NULL_VAR_STRIDE);
        // An unsampled run never steps its recursions: no storage for them (the component
        // one is 3 n³ numbers).
        RunNullVariance {
            sample,
            nees: NeesNullVariance::new(if sample { n_x } else { 0 }),
            components: (sample && mc.gate() == GateMode::Full)
                .then(|| ComponentNullVariance::new(n_x)),
            map_missing: false,
        }
    }

    /// Step with the estimate's error map (`l` is P's lower Cholesky factor).
    #[inline]
    fn step(&mut self, est: &Estimate, l: &DMatrix<f64>) {
        if !self.sample || self.map_missing {
            return;
        }
        let n_x = est.P.nrows();
        match &est.error_map {
            Some(a) if a.shape() == (n_x, n_x) => {
                self.nees.step_factored(a, &est.P, l);
                if let Some(cv) = &mut self.components {
                    cv.step(a, &est.P);
                }
            }
            _ => self.map_missing = true,
        }
    }

    /// Add the run's variances to the sums (or count its missing map).
    fn add_to(self, acc: &mut Accumulator) {
        if self.map_missing {
            acc.error_map_missing += 1;
        } else if self.sample {
            acc.nees_null_var += self.nees.variance();
            acc.null_var_runs += 1;
            if let Some(cv) = &self.components {
                for (s, v) in acc.state_comp_null_var.iter_mut().zip(cv.variances()) {
                    *s += v;
                }
                for (s, v) in acc.state_mean_null_var.iter_mut().zip(cv.mean_variances()) {
                    *s += v;
                }
                acc.comp_null_var_runs += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lower triangle of `l` has the bits of `linalg::cholesky(p)`'s factor.
    fn is_factor_of(l: &DMatrix<f64>, p: &DMatrix<f64>) -> bool {
        let want = crate::linalg::cholesky(p).unwrap().l();
        (0..p.nrows()).all(|i| (0..=i).all(|j| l[(i, j)].to_bits() == want[(i, j)].to_bits()))
    }

    #[test]
    fn a_remembered_factor_is_the_factor_of_the_p_asked_about() {
        let a = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let b = DMatrix::from_row_slice(2, 2, &[2.0, -0.5, -0.5, 1.0]);
        let mut f = Factors::default();
        // Step 1 asked with a, again with a (served), then with b (computed, replacing a),
        // and a again: each answer is the factor of what was asked.
        for p in [&a, &a, &b, &a] {
            assert!(is_factor_of(f.factor(1, p).unwrap(), p));
        }
        assert!(is_factor_of(f.factor(2, &b).unwrap(), &b));
        assert!(is_factor_of(f.factor(1, &a).unwrap(), &a));
        // Not positive definite, or not finite: none, and not remembered.
        let indefinite = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        assert!(f.factor(1, &indefinite).is_none());
        assert!(f.factor(1, &indefinite).is_none());
        let mut nan = a.clone();
        nan[(1, 1)] = f64::NAN;
        assert!(f.factor(1, &nan).is_none());
        assert!(is_factor_of(f.factor(1, &a).unwrap(), &a));
        // Steps past the budget share one slot and are computed each time.
        let far = FACTOR_STEPS + 10;
        assert!(is_factor_of(f.factor(far, &a).unwrap(), &a));
        assert!(is_factor_of(f.factor(far + 1, &b).unwrap(), &b));
        assert!(f.slots.len() <= FACTOR_STEPS + 1);
    }
}
