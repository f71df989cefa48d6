//! Exact expected Monte Carlo sums for a linear filter on a linear-Gaussian truth.
//!
//! Where the filter's model matches the truth's (same F and H; Q, R, P0 and x0 may differ):
//! With matched models the estimation error obeys its own recursion, driven by the truth's
//! noise and the filter's gain (DESIGN.md, "Theory in one page"):
//! `e⁻_k = F e_{k−1} + w_k`, `ν_k = H e⁻_k + v_k`, `e_k = (I − K_k H) e⁻_k − K_k v_k`, so its
//! mean and covariance propagate in closed form, `E[NEES_k] = tr(P_k⁻¹ E[e_k e_k'])`,
//! `E[NIS_k] = tr(S_k⁻¹ E[ν_k ν_k'])`, and innovation cross-moments follow from
//! `E[ν_k ν_j'] = H F Φ_{k−1,j} E[e_j ν_j']`. These are the sums N Monte Carlo runs would
//! produce on average, with no sampling noise: the tuner's objective becomes a deterministic,
//! smooth function of the parameters, and a Monte Carlo run still confirms the result.
//!
//! Where it does not (another F or H, other states than the truth's through a map M, as a
//! misfit explanation's hypotheses give): the truth's state and the filter's estimate
//! propagate together, `s = [x; x̂]`, a linear system driven by the truth's noise and the
//! filter's (data-independent) gains: `s⁻ = Φ s + [w; 0]` with `Φ = diag(F_t, F_f)`,
//! `ν = C s⁻ + v` with `C = [H_t, −H_f]`, `s = B s⁻ + [0; K] v` with
//! `B = [[I, 0], [K H_t, I − K H_f]]`, and the error is `e = D s` with `D = [M, −I]`. The
//! same expected values follow from the joint mean and covariance ([`JointMoments`]).

#![allow(non_snake_case)]

use nalgebra::DMatrix;

mod filter_step;
mod joint;
mod matched;
mod values;

use filter_step::FilterStep;
use joint::JointMoments;
use matched::ErrorMoments;
use values::StepValues;

use super::McConfig;
use super::generic::Fault;
use super::linear::{self, same_covariance};
use super::truth_moments::{Truth, TruthMoment, TruthTrack};
use crate::filter::{Filter, FilterError, KalmanFilter};
use crate::linalg::products::Sparse;
use crate::model::LinearGaussianModel;
use crate::stats::Accumulator;
use crate::stats::{ComponentNullVariance, GateMode, NeesNullVariance};

/// Whether [`expected_accumulator`] applies: the filter uses the truth's F and H.
pub fn models_match(truth: &LinearGaussianModel, filter: &KalmanFilter) -> bool {
    truth.F == filter.F && truth.H == filter.H
}

/// Quiet steps in a row after which the recursion is treated as being in steady state.
const STEADY_STEPS: usize = 3;

/// The expected value of the sums [`super::run_linear`] accumulates over `mc.runs()`
/// runs, computed exactly, for a filter whose model matches the truth's ([`models_match`]):
/// [`expected_accumulator_mapped`] without a map. Per-run component spreads are not defined
/// here (they are set as if every run equalled the mean).
pub fn expected_accumulator(
    truth: &LinearGaussianModel,
    f: &KalmanFilter,
    mc: &McConfig,
) -> Result<Accumulator, FilterError> {
    expected_accumulator_mapped(truth, f, None, mc)
}

/// The error moments of either kind.
enum Moments<'a> {
    Matched(Box<ErrorMoments>),
    Joint(Box<JointMoments<'a>>),
}

/// The expected value of the sums [`super::run_linear`] accumulates over `mc.runs()` runs
/// of `f` on `truth`, the NEES taken on `map · x − x̂` (`None`: the identity), computed
/// exactly for any linear filter: through the error's own recursion where the models match
/// and there is no map, through the joint moments of truth and estimate otherwise.
pub fn expected_accumulator_mapped(
    truth: &LinearGaussianModel,
    f: &KalmanFilter,
    map: Option<&DMatrix<f64>>,
    mc: &McConfig,
) -> Result<Accumulator, FilterError> {
    expected_accumulator_tracked(truth, f, map, mc, None)
}

/// [`expected_accumulator_mapped`] with the truth's own moments taken from `track` where
/// it was built for this truth, map and at least `mc.steps()` steps (a search scoring many
/// filters against one truth: [`TruthTrack`]); computed here otherwise.
pub fn expected_accumulator_tracked(
    truth: &LinearGaussianModel,
    f: &KalmanFilter,
    map: Option<&DMatrix<f64>>,
    mc: &McConfig,
    track: Option<&TruthTrack>,
) -> Result<Accumulator, FilterError> {
    // The judged states: the map's rows (a filter with states the truth lacks is judged on
    // its first ones), or all of them.
    let n_f = f.n_x();
    let n = map.map_or(n_f, |m| m.nrows());
    let m = f.H.nrows();
    let lags = mc.lags();
    let runs = mc.runs() as f64;
    let mut acc = Accumulator::new(mc.steps(), n, m, lags);

    let built;
    let (mut moments, mut truth_m2) = if map.is_none() && models_match(truth, f) {
        (
            Moments::Matched(Box::new(ErrorMoments::new(truth, f, lags))),
            Truth::Propagated(Box::new(TruthMoment::new(truth, map))),
        )
    } else {
        let judged = TruthTrack::judged_map(truth, f, map);
        let track = match track {
            Some(t) if t.serves(truth, &judged, mc.steps()) => t,
            _ => {
                built = TruthTrack::new(truth, f, map, mc.steps());
                &built
            }
        };
        (
            Moments::Joint(Box::new(JointMoments::new(truth, f, track, lags))),
            Truth::Tracked(track),
        )
    };
    let mut null_var = NeesNullVariance::judged(n_f, n);
    // The component variances (second and first moment) cost n times the NEES one; only
    // the full gate reads them, as on the Monte Carlo paths.
    let mut comp_var = (mc.gate() == GateMode::Full).then(|| ComponentNullVariance::new(n_f));
    // Σ_k E[e_j]/√P_jj: every run's expected first-moment sum.
    let mut mean_x = vec![0.0; n];
    // Σ_k E[ν_j]/√S_jj: every run's expected first-moment sum of the innovations.
    let mut mean_z = vec![0.0; m];
    let mut comp_x = vec![0.0; n];
    let mut comp_z = vec![0.0; m];
    let mut steady: Option<StepValues> = None;
    let mut previous: Option<StepValues> = None;
    // This step's values, written over the buffers of the step before last.
    let mut values = StepValues::default();
    let mut quiet_steps = 0usize;
    // The filter's latest step, and how many steps in a row its P has not changed: once it
    // is steady (as the Monte Carlo engine judges it), its step serves every later one.
    let mut filt: Option<FilterStep> = None;
    let mut spare: Option<FilterStep> = None;
    let mut filter_quiet = 0usize;
    let (f_op, h_op) = (Sparse::new(&f.F), Sparse::new(&f.H));

    for k in 1..=mc.steps() {
        let i = k - 1;
        if let Some(fault) = truth_m2.overflows(k) {
            return Ok(stop_all(acc, mc, k, fault));
        }
        if let (Some(v), Some(fs)) = (&steady, &filt) {
            if let Some(fault) = truth_m2.step(k, &fs.up.cu.P, &v.comp_x) {
                return Ok(stop_all(acc, mc, k, fault));
            }
            v.add(&mut acc, i, runs, n, m, &mut comp_x, &mut comp_z, lags, k);
            for (s, y) in mean_x.iter_mut().zip(&v.mean_x) {
                *s += y;
            }
            for (s, y) in mean_z.iter_mut().zip(&v.mean_z) {
                *s += y;
            }
            null_var.step_judged(&fs.a, &fs.up.cu.P, &fs.p_inv);
            if let Some(cv) = &mut comp_var {
                cv.step(&fs.a, &fs.up.cu.P);
            }
            continue;
        }
        let frozen = filter_quiet >= FILTER_STEADY_STEPS;
        if !frozen {
            // The step before the last gives its storage to this one.
            let from = filt.as_ref().map_or(&f.P0, |s| &s.up.cu.P);
            let next = match spare.take() {
                Some(mut s) => {
                    s.advance(f, (&f_op, &h_op), from, n, k)?;
                    s
                }
                None => FilterStep::after(f, (&f_op, &h_op), from, n, k)?,
            };
            filter_quiet = match &filt {
                Some(prev) if same_covariance(&next.up.cu.P, &prev.up.cu.P) => filter_quiet + 1,
                _ => 0,
            };
            spare = filt.replace(next);
        }
        let fs = filt.as_ref().expect("a filter step");
        null_var.step_judged(&fs.a, &fs.up.cu.P, &fs.p_inv);
        if let Some(cv) = &mut comp_var {
            cv.step(&fs.a, &fs.up.cu.P);
        }
        match &mut moments {
            Moments::Matched(e) => e.advance(truth, f, fs, &mut values),
            Moments::Joint(j) => j.step(i, truth, f, fs, frozen, &mut values),
        }
        if let Some(fault) = truth_m2.step(k, &fs.up.cu.P, &values.comp_x) {
            return Ok(stop_all(acc, mc, k, fault));
        }
        values.add(&mut acc, i, runs, n, m, &mut comp_x, &mut comp_z, lags, k);
        for (s, y) in mean_x.iter_mut().zip(&values.mean_x) {
            *s += y;
        }
        for (s, y) in mean_z.iter_mut().zip(&values.mean_z) {
            *s += y;
        }
        // Steady state is judged on the per-step expected values themselves, each relative
        // to its own size, so that a state with a tiny variance converging slowly is not
        // hidden behind one with a large variance (a whole-matrix norm would be unit-bound).
        // Several quiet steps in a row are required.
        quiet_steps = match &previous {
            Some(prev) if values.same_as(prev) => quiet_steps + 1,
            _ => 0,
        };
        let converged = k > lags + 1 && quiet_steps >= STEADY_STEPS;
        if converged {
            steady = Some(std::mem::take(&mut values));
        } else {
            match &mut previous {
                Some(p) => std::mem::swap(p, &mut values),
                None => previous = Some(std::mem::take(&mut values)),
            }
        }
    }
    let runs_sums = RunSums {
        comp_x: &comp_x,
        comp_z: &comp_z,
        mean_x: &mean_x,
        mean_z: &mean_z,
    };
    runs_sums.add(&mut acc, mc, &null_var, comp_var.as_ref());
    Ok(acc)
}

/// Steps in a row with an unchanged P after which the filter's step is reused.
const FILTER_STEADY_STEPS: usize = linear::STEADY_STEPS;

/// Every run's expected sums over its steps, for the per-run spreads.
struct RunSums<'a> {
    /// Σ_k E[e_j²]/P_jj.
    comp_x: &'a [f64],
    /// Σ_k E[u_j²].
    comp_z: &'a [f64],
    /// Σ_k E[e_j]/√P_jj.
    mean_x: &'a [f64],
    /// Σ_k E[ν_j]/√S_jj.
    mean_z: &'a [f64],
}

impl RunSums<'_> {
    /// Set the per-run sums and the null variances of `mc.runs()` runs that all equal the
    /// mean.
    fn add(
        &self,
        acc: &mut Accumulator,
        mc: &McConfig,
        null_var: &NeesNullVariance,
        comp_var: Option<&ComponentNullVariance>,
    ) {
        let runs = mc.runs() as f64;
        let t = mc.steps() as f64;
        for (j, c) in self.comp_x.iter().enumerate() {
            acc.state_comp_run_sum[j] = runs * c / t;
            acc.state_comp_run_sq[j] = runs * (c / t).powi(2);
        }
        for (j, c) in self.comp_z.iter().enumerate() {
            acc.meas_comp_run_sum[j] = runs * c / t;
            acc.meas_comp_run_sq[j] = runs * (c / t).powi(2);
            acc.meas_comp_runs[j] = mc.runs();
        }
        // The runs all equal the mean here, but the zero-mean tests read the run-to-run
        // spread: each run's first-moment sum gets the variance a consistent filter
        // predicts (the filter's own for the states, one per step for white innovations),
        // so that a spread of 0 does not make every mean significant.
        let mean_var = comp_var.map(|cv| cv.mean_variances().to_vec());
        for (j, c) in self.mean_x.iter().enumerate() {
            let v = mean_var.as_ref().map_or(0.0, |v| v[j]);
            // Σ r² = N c² + (N − 1) v gives the sample variance v about the mean c.
            acc.state_mean_run_sq[j] = runs * c * c + (runs - 1.0) * v;
        }
        for (j, c) in self.mean_z.iter().enumerate() {
            acc.meas_mean_run_sq[j] = runs * c * c + (runs - 1.0) * t;
        }
        acc.runs = mc.runs();
        acc.nees_null_var = runs * null_var.variance();
        acc.null_var_runs = mc.runs();
        if let Some(cv) = comp_var {
            for (s, v) in acc.state_comp_null_var.iter_mut().zip(cv.variances()) {
                *s = runs * v;
            }
            for (s, v) in acc.state_mean_null_var.iter_mut().zip(cv.mean_variances()) {
                *s = runs * v;
            }
            acc.comp_null_var_runs = mc.runs();
        }
    }
}

/// `acc` with every run stopped at step `k` by `fault`: the steps before it keep their
/// sums, as in the Monte Carlo runs that stop there; no run finishes.
fn stop_all(mut acc: Accumulator, mc: &McConfig, k: usize, fault: Fault) -> Accumulator {
    acc.runs = mc.runs();
    for run in 0..mc.runs() {
        acc.record_stop(run, k, fault.cause(), fault.reason(k));
    }
    acc
}
