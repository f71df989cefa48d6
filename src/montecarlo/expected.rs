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

use nalgebra::{DMatrix, DVector};

use super::McConfig;
use super::generic::Fault;
use super::linear::{self, same_covariance};
use super::truth_moments::{STEADY_RTOL, Truth, TruthMoment, TruthTrack};
use crate::filter::{CovarianceUpdate, Filter, FilterError, KalmanFilter};
use crate::linalg::products::Sparse;
use crate::linalg::{cholesky, spd_inverse};
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
            Some(t) if t.serves(&judged, mc.steps()) => t,
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
    let mut quiet_steps = 0usize;
    // The filter's latest step, and how many steps in a row its P has not changed: once it
    // is steady (as the Monte Carlo engine judges it), its step serves every later one.
    let mut filt: Option<FilterStep> = None;
    let mut filter_quiet = 0usize;
    let (f_op, h_op) = (Sparse::new(&f.F), Sparse::new(&f.H));

    for k in 1..=mc.steps() {
        let i = k - 1;
        if let Some(fault) = truth_m2.overflows(k) {
            return Ok(stop_all(acc, mc, k, fault));
        }
        if let (Some(v), Some(fs)) = (&steady, &filt) {
            if let Some(fault) = truth_m2.step(k, &fs.cu.P, &v.comp_x) {
                return Ok(stop_all(acc, mc, k, fault));
            }
            v.add(&mut acc, i, runs, n, m, &mut comp_x, &mut comp_z, lags, k);
            for (s, y) in mean_x.iter_mut().zip(&v.mean_x) {
                *s += y;
            }
            for (s, y) in mean_z.iter_mut().zip(&v.mean_z) {
                *s += y;
            }
            null_var.step_judged(&fs.a, &fs.cu.P, &fs.p_inv);
            if let Some(cv) = &mut comp_var {
                cv.step(&fs.a, &fs.cu.P);
            }
            continue;
        }
        let frozen = filter_quiet >= FILTER_STEADY_STEPS;
        if !frozen {
            let next = FilterStep::after(
                f,
                (&f_op, &h_op),
                filt.as_ref().map_or(&f.P0, |s| &s.cu.P),
                n,
                k,
            )?;
            filter_quiet = match &filt {
                Some(prev) if same_covariance(&next.cu.P, &prev.cu.P) => filter_quiet + 1,
                _ => 0,
            };
            filt = Some(next);
        }
        let fs = filt.as_ref().expect("a filter step");
        null_var.step_judged(&fs.a, &fs.cu.P, &fs.p_inv);
        if let Some(cv) = &mut comp_var {
            cv.step(&fs.a, &fs.cu.P);
        }
        let values = match &mut moments {
            Moments::Matched(e) => e.advance(truth, f, fs),
            Moments::Joint(j) => j.step(i, truth, f, fs, frozen),
        };
        if let Some(fault) = truth_m2.step(k, &fs.cu.P, &values.comp_x) {
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
            steady = Some(values);
        } else {
            previous = Some(values);
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

/// One step of the filter's covariance recursion, and what the moments read of it.
struct FilterStep {
    cu: CovarianceUpdate,
    /// K and `I − K H` as product operands.
    k_op: Sparse,
    ikh_op: Sparse,
    /// The error map `A = (I − K H) F`, n × n.
    a: DMatrix<f64>,
    /// The inverse of P's judged block (its first `judged` states), and of S: the weights
    /// of the NEES and NIS.
    p_inv: DMatrix<f64>,
    s_inv: DMatrix<f64>,
}

impl FilterStep {
    /// Step `k` of `f` (its F and H as product operands, `f_op` and `h_op`) from the
    /// posterior `P` of the step before.
    ///
    /// The update is [`KalmanFilter::update_covariance_sparse`]: its products run over the
    /// models' nonzeros, and its K and I − K H serve the moment recursions as operands.
    fn after(
        f: &KalmanFilter,
        (f_op, h_op): (&Sparse, &Sparse),
        P: &DMatrix<f64>,
        judged: usize,
        k: usize,
    ) -> Result<Self, FilterError> {
        // `predict_covariance`'s F P F' + Q, with F's zeros skipped.
        let mut Pp = f_op.sandwich(P, f_op) + &f.Q;
        crate::linalg::symmetrize(&mut Pp);
        let (cu, (k_op, ikh_op)) = f.update_covariance_sparse(&Pp, h_op, k)?;
        let judged_p = cu.P.view((0, 0), (judged, judged)).clone_owned();
        let chol_p = cholesky(&judged_p).ok_or(FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        })?;
        let a = f_op.right(&cu.IKH);
        let p_inv = spd_inverse(chol_p.l_dirty());
        let s_inv = spd_inverse(cu.chol.l_dirty());
        Ok(FilterStep {
            cu,
            k_op,
            ikh_op,
            a,
            p_inv,
            s_inv,
        })
    }
}

/// The gain operands kept from the last step where the filter's step is `frozen` (the same
/// as the last one), built by `make` otherwise; the caller puts them back after the step.
fn kept_or<G>(kept: &mut Option<G>, frozen: bool, make: impl FnOnce() -> G) -> G {
    match kept.take() {
        Some(g) if frozen => g,
        _ => make(),
    }
}

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

/// The estimation error's mean and covariance, and the innovation cross-moments the
/// whiteness sums need, propagated step by step (F and H as [`Sparse`] operands).
struct ErrorMoments {
    mu: DVector<f64>,
    sigma: DMatrix<f64>,
    f: Sparse,
    h: Sparse,
    lags: usize,
    /// `E[e_{k−1} ν_{k−l}']` for l = 1, 2, … side by side (n × m each, most recent first).
    window: DMatrix<f64>,
    /// History of diag(S) for the lagged normalizations, most recent first.
    s_diag_hist: Vec<DVector<f64>>,
    /// History of expected u_j² per step, most recent first.
    comp_z_hist: Vec<Vec<f64>>,
}

impl ErrorMoments {
    fn new(truth: &LinearGaussianModel, f: &KalmanFilter, lags: usize) -> Self {
        ErrorMoments {
            mu: &truth.x0 - &f.x0,
            sigma: truth.P0.clone(),
            f: Sparse::new(&f.F),
            h: Sparse::new(&f.H),
            lags,
            window: DMatrix::zeros(f.F.nrows(), 0),
            s_diag_hist: Vec::with_capacity(lags),
            comp_z_hist: Vec::with_capacity(lags),
        }
    }

    /// Through one step of the filter: the step's expected values.
    fn advance(
        &mut self,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        step: &FilterStep,
    ) -> StepValues {
        let cu = &step.cu;
        let (k, l) = (&step.k_op, &step.ikh_op);
        let (fs, hs) = (&self.f, &self.h);
        let (n, m) = (f.F.nrows(), f.H.nrows());
        // Error moments before and after the update.
        let mu_p = &f.F * &self.mu;
        let mut sig_p = fs.sandwich(&self.sigma, fs) + &truth.Q;
        crate::linalg::symmetrize(&mut sig_p);
        let m2_p = &sig_p + &mu_p * mu_p.transpose();
        let nu_mean = &f.H * &mu_p;
        let m2_ht = hs.right_tr(&m2_p);
        let nu_m2 = hs.left(&m2_ht) + &truth.R;
        let mut sig = l.sandwich(&sig_p, l) + k.sandwich(&truth.R, k);
        crate::linalg::symmetrize(&mut sig);
        let mu_new = &cu.IKH * &mu_p;
        let e_m2 = &sig + &mu_new * mu_new.transpose();

        let (nees, nees_sq) = gaussian_quadratic_moments(&step.p_inv, &sig, &mu_new);
        let nu_cov = &nu_m2 - &nu_mean * nu_mean.transpose();
        let (nis, nis_sq) = gaussian_quadratic_moments(&step.s_inv, &nu_cov, &nu_mean);

        let s_diag = cu.S.diagonal();
        // E[ν_k ν_{k−l}'] = H F E[e_{k−1} ν_{k−l}']: only the diagonal of each block is read.
        let z = fs.left(&self.window);
        // Only the diagonal of each lag's block is read: row j of H against column j.
        let cross = |lag: usize, j: usize| hs.row_dot(j, z.column(lag * m + j).as_slice());
        let comp_z_now: Vec<f64> = (0..m).map(|j| nu_m2[(j, j)] / s_diag[j]).collect();
        let values = StepValues {
            nees,
            nees_sq,
            nis,
            nis_sq,
            comp_x: (0..n).map(|j| e_m2[(j, j)] / cu.P[(j, j)]).collect(),
            comp_z: comp_z_now.clone(),
            mean_x: (0..n).map(|j| mu_new[j] / cu.P[(j, j)].sqrt()).collect(),
            mean_z: (0..m).map(|j| nu_mean[j] / s_diag[j].sqrt()).collect(),
            white: self
                .s_diag_hist
                .iter()
                .enumerate()
                .map(|(lag, sd)| {
                    (0..m)
                        .map(|j| cross(lag, j) / (s_diag[j] * sd[j]).sqrt())
                        .collect()
                })
                .collect(),
            lagged_b2: self.comp_z_hist.clone(),
        };

        // Advance the cross-moment window: E[e_k ν_k'] = (I − K H) E[e⁻ ν'] − K R, and the
        // older ones through A_k = (I − K H) F (F applied above).
        if self.lags > 0 {
            let kept = (self.lags - 1).min(self.s_diag_hist.len()) * m;
            let d = l.left(&m2_ht) - k.left(&truth.R);
            let mut next = DMatrix::zeros(n, m + kept);
            next.columns_mut(0, m).copy_from(&d);
            next.columns_mut(m, kept)
                .copy_from(&l.left(&z.columns(0, kept).clone_owned()));
            self.window = next;
        }
        self.s_diag_hist.insert(0, s_diag.clone_owned());
        self.s_diag_hist.truncate(self.lags);
        self.comp_z_hist.insert(0, comp_z_now);
        self.comp_z_hist.truncate(self.lags);
        self.sigma = sig;
        self.mu = mu_new;
        values
    }
}

/// The joint mean and second moments of the truth's state and the filter's estimate,
/// `s = [x; x̂]`, and the innovation cross-moments the whiteness sums need, propagated step
/// by step (the module's second case).
///
/// Held by blocks: `Φ` is block-diagonal and `B` the identity over the truth's rows, so the
/// truth's block is only propagated, never updated, and is read from its [`TruthTrack`].
/// The models' matrices are products' sparse operands ([`Sparse`]): a misfit trial spends
/// most of its scoring time here.
struct JointMoments<'a> {
    /// The truth's moments, step by step.
    track: &'a TruthTrack,
    /// `E[x̂]`, n_f.
    mu_f: DVector<f64>,
    /// `Cov(x, x̂)`, n_t × n_f.
    s_tf: DMatrix<f64>,
    /// `Cov(x̂)`, n_f × n_f.
    s_ff: DMatrix<f64>,
    /// The truth's F and H, the filter's, and `M` (ne × n_t; the judged error is
    /// `M x − x̂[..ne]`).
    f_t: Sparse,
    h_t: Sparse,
    f_f: Sparse,
    h_f: Sparse,
    map: Sparse,
    /// The error's rows.
    ne: usize,
    lags: usize,
    /// `E[x_{k−1} ν_{k−l}']` for l = 1, 2, … side by side (n_t × m each, most recent
    /// first), and `E[x̂_{k−1} ν_{k−l}']` (n_f × m each).
    window_t: DMatrix<f64>,
    window_f: DMatrix<f64>,
    s_diag_hist: Vec<DVector<f64>>,
    comp_z_hist: Vec<Vec<f64>>,
    /// The step's operands kept while the filter is steady.
    gains: Option<JointGains>,
}

/// The operand of a joint step that depends on the filter's gain and the truth's H:
/// `G = K H_t`, dense and as an operand.
struct JointGains {
    g_dense: DMatrix<f64>,
    g: Sparse,
}

impl JointGains {
    fn new(h_t: &Sparse, cu: &CovarianceUpdate) -> Self {
        let g_dense = h_t.right(&cu.K);
        JointGains {
            g: Sparse::new(&g_dense),
            g_dense,
        }
    }
}

impl<'a> JointMoments<'a> {
    fn new(
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        track: &'a TruthTrack,
        lags: usize,
    ) -> Self {
        let (n_t, n_f) = (truth.F.nrows(), f.F.nrows());
        JointMoments {
            track,
            mu_f: f.x0.clone(),
            s_tf: DMatrix::zeros(n_t, n_f),
            s_ff: DMatrix::zeros(n_f, n_f),
            f_t: Sparse::new(&truth.F),
            h_t: Sparse::new(&truth.H),
            f_f: Sparse::new(&f.F),
            h_f: Sparse::new(&f.H),
            ne: track.map.nrows(),
            map: Sparse::new(&track.map),
            lags,
            window_t: DMatrix::zeros(n_t, 0),
            window_f: DMatrix::zeros(n_f, 0),
            s_diag_hist: Vec::with_capacity(lags),
            comp_z_hist: Vec::with_capacity(lags),
            gains: None,
        }
    }

    /// Through step `i` (from 0) of the filter, `fs` (`frozen`: the same step as the last
    /// one): the step's expected values.
    fn step(
        &mut self,
        i: usize,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        fs: &FilterStep,
        frozen: bool,
    ) -> StepValues {
        let cu = &fs.cu;
        let gains = kept_or(&mut self.gains, frozen, || JointGains::new(&self.h_t, cu));
        let values = self.advance(i, truth, f, fs, &gains);
        self.gains = Some(gains);
        values
    }

    fn advance(
        &mut self,
        i: usize,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        step: &FilterStep,
        gains: &JointGains,
    ) -> StepValues {
        let cu = &step.cu;
        let (f_t, h_t, f_f, h_f) = (&self.f_t, &self.h_t, &self.f_f, &self.h_f);
        let m = f.H.nrows();
        let ne = self.ne;
        let ts = &self.track.steps[i];

        // The prediction: Φ is block-diagonal, the truth's noise enters its own block (the
        // truth's moments are the track's).
        let (mp_t, p_tt) = (&ts.mean, &ts.cov);
        let mp_f = &f.F * &self.mu_f;
        let p_tf = f_t.sandwich(&self.s_tf, f_f);
        let mut p_ff = f_f.sandwich(&self.s_ff, f_f);
        crate::linalg::symmetrize(&mut p_ff);
        let m_ft = p_tf.transpose() + &mp_f * mp_t.transpose();
        let m_tf = m_ft.transpose();
        let m_ff = &p_ff + &mp_f * mp_f.transpose();

        // ν = H_t x − H_f x̂ + v: its mean, its second moment and E[s⁻ ν'] by blocks.
        let w_t = &ts.m2_ht - h_f.right_tr(&m_tf);
        let w_f = h_t.right_tr(&m_ft) - h_f.right_tr(&m_ff);
        let nu_mean = &ts.h_mean - &f.H * &mp_f;
        let nu_m2 = h_t.left(&w_t) - h_f.left(&w_f) + &truth.R;

        // The update leaves the truth alone and sets x̂ = K H_t x + (I − K H_f) x̂⁻ + K v.
        // With G = K H_t: Cov(x, x̂) = P_tt G' + P_tf L', Cov(x̂) = Cov(x̂, x) G' +
        // (G P_tf + L P_ff) L' + K R K'.
        let JointGains { g_dense, g } = gains;
        let (k, l) = (&step.k_op, &step.ikh_op);
        let s_tf = g.right_tr(p_tt) + l.right_tr(&p_tf);
        let v = g.right_tr(&p_tf.transpose()) + l.right_tr(&p_ff);
        let mut s_ff =
            g.right_tr(&s_tf.transpose()) + l.right_tr(&v.transpose()) + k.sandwich(&truth.R, k);
        crate::linalg::symmetrize(&mut s_ff);
        let mu_f = g_dense * mp_t + &cu.IKH * &mp_f;

        // The judged error M x − x̂[..ne].
        let e_mean = &ts.map_mean - mu_f.rows(0, ne);
        let x = self.map.left(&s_tf.columns(0, ne).clone_owned());
        let mut e_cov = &ts.map_cov - &x - x.transpose() + s_ff.view((0, 0), (ne, ne));
        crate::linalg::symmetrize(&mut e_cov);
        let e_m2 = &e_cov + &e_mean * e_mean.transpose();

        let (nees, nees_sq) = gaussian_quadratic_moments(&step.p_inv, &e_cov, &e_mean);
        let nu_cov = &nu_m2 - &nu_mean * nu_mean.transpose();
        let (nis, nis_sq) = gaussian_quadratic_moments(&step.s_inv, &nu_cov, &nu_mean);
        let s_diag = cu.S.diagonal();
        // E[ν_k ν_{k−l}'] = C Φ E[s_{k−1} ν_{k−l}'], whose Φ part also advances the window.
        let z_t = f_t.left(&self.window_t);
        let z_f = f_f.left(&self.window_f);
        // Only the diagonal of each lag's block is read: row j of C against column j.
        let cross = |l: usize, j: usize| {
            let c = l * m + j;
            h_t.row_dot(j, z_t.column(c).as_slice()) - h_f.row_dot(j, z_f.column(c).as_slice())
        };
        let comp_z_now: Vec<f64> = (0..m).map(|j| nu_m2[(j, j)] / s_diag[j]).collect();
        let values = StepValues {
            nees,
            nees_sq,
            nis,
            nis_sq,
            comp_x: (0..ne).map(|j| e_m2[(j, j)] / cu.P[(j, j)]).collect(),
            comp_z: comp_z_now.clone(),
            mean_x: (0..ne).map(|j| e_mean[j] / cu.P[(j, j)].sqrt()).collect(),
            mean_z: (0..m).map(|j| nu_mean[j] / s_diag[j].sqrt()).collect(),
            white: self
                .s_diag_hist
                .iter()
                .enumerate()
                .map(|(l, sd)| {
                    (0..m)
                        .map(|j| cross(l, j) / (s_diag[j] * sd[j]).sqrt())
                        .collect()
                })
                .collect(),
            lagged_b2: self.comp_z_hist.clone(),
        };
        // E[s_k ν_k'] and the older cross-moments through B (Φ applied above).
        if self.lags > 0 {
            let kept = (self.lags - 1).min(self.s_diag_hist.len()) * m;
            let now_f = g.left(&w_t) + l.left(&w_f) + k.left(&truth.R);
            let (z_t, z_f) = (z_t.columns(0, kept).clone_owned(), z_f.columns(0, kept));
            let older_f = g.left(&z_t) + l.left(&z_f.clone_owned());
            let mut next_t = DMatrix::zeros(w_t.nrows(), m + kept);
            next_t.columns_mut(0, m).copy_from(&w_t);
            next_t.columns_mut(m, kept).copy_from(&z_t);
            let mut next_f = DMatrix::zeros(now_f.nrows(), m + kept);
            next_f.columns_mut(0, m).copy_from(&now_f);
            next_f.columns_mut(m, kept).copy_from(&older_f);
            self.window_t = next_t;
            self.window_f = next_f;
        }
        self.s_diag_hist.insert(0, s_diag.clone_owned());
        self.s_diag_hist.truncate(self.lags);
        self.comp_z_hist.insert(0, comp_z_now);
        self.comp_z_hist.truncate(self.lags);
        self.mu_f = mu_f;
        self.s_tf = s_tf;
        self.s_ff = s_ff;
        values
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

/// `E[x' M⁻¹ x]` and `E[(x' M⁻¹ x)²]` for x ~ N(μ, Σ), given `M⁻¹` (symmetric):
/// `tr B + μ'M⁻¹μ` and `(tr B)² + 2 tr(B²) + 4 μ' M⁻¹ Σ M⁻¹ μ + 2 tr(B) μ'M⁻¹μ + (μ'M⁻¹μ)²`,
/// `B = M⁻¹ Σ`, in plain loops (a few states: no packing, no allocation beyond B).
fn gaussian_quadratic_moments(
    minv: &DMatrix<f64>,
    sigma: &DMatrix<f64>,
    mu: &DVector<f64>,
) -> (f64, f64) {
    let n = mu.len();
    let (w, s) = (minv.as_slice(), sigma.as_slice());
    let mut b = vec![0.0; n * n];
    for j in 0..n {
        let col = &mut b[j * n..(j + 1) * n];
        for k in 0..n {
            let skj = s[k + j * n];
            for (bi, wi) in col.iter_mut().zip(&w[k * n..(k + 1) * n]) {
                *bi += wi * skj;
            }
        }
    }
    let tr: f64 = (0..n).map(|i| b[i + i * n]).sum();
    let mut tr2 = 0.0;
    for j in 0..n {
        for i in 0..n {
            tr2 += b[i + j * n] * b[j + i * n];
        }
    }
    let minv_mu = minv * mu;
    let q = mu.dot(&minv_mu);
    let cross = minv_mu.dot(&(sigma * &minv_mu));
    (
        tr + q,
        tr * tr + 2.0 * tr2 + 4.0 * cross + 2.0 * tr * q + q * q,
    )
}

/// The expected per-run values of one step.
struct StepValues {
    nees: f64,
    nees_sq: f64,
    nis: f64,
    nis_sq: f64,
    comp_x: Vec<f64>,
    comp_z: Vec<f64>,
    /// `E[e_j]/√P_jj`.
    mean_x: Vec<f64>,
    /// `E[ν_j]/√S_jj`.
    mean_z: Vec<f64>,
    /// `white[l − 1][j]` = E[u_k,j u_{k−l},j].
    white: Vec<Vec<f64>>,
    /// `lagged_b2[l − 1][j]` = E[u_{k−l},j²].
    lagged_b2: Vec<Vec<f64>>,
}

impl StepValues {
    /// Whether every value equals `o`'s to [`STEADY_RTOL`] relative.
    fn same_as(&self, o: &StepValues) -> bool {
        let close = |a: f64, b: f64| {
            (a - b).abs() <= STEADY_RTOL * a.abs().max(b.abs()).max(f64::MIN_POSITIVE)
        };
        let all = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y))
        };
        // A mean in standard deviations decays geometrically towards 0 and never settles
        // relative to itself; 1e-12 σ is settled enough.
        let near = |a: &[f64], b: &[f64]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| (x - y).abs() <= STEADY_RTOL * x.abs().max(y.abs()).max(1.0))
        };
        close(self.nees, o.nees)
            && close(self.nees_sq, o.nees_sq)
            && close(self.nis, o.nis)
            && close(self.nis_sq, o.nis_sq)
            && all(&self.comp_x, &o.comp_x)
            && all(&self.comp_z, &o.comp_z)
            && near(&self.mean_x, &o.mean_x)
            && near(&self.mean_z, &o.mean_z)
            && self.white.len() == o.white.len()
            && self.white.iter().zip(&o.white).all(|(a, b)| all(a, b))
            && self.lagged_b2.len() == o.lagged_b2.len()
            && self
                .lagged_b2
                .iter()
                .zip(&o.lagged_b2)
                .all(|(a, b)| all(a, b))
    }

    #[allow(clippy::too_many_arguments)]
    fn add(
        &self,
        acc: &mut Accumulator,
        i: usize,
        runs: f64,
        n: usize,
        m: usize,
        comp_x: &mut [f64],
        comp_z: &mut [f64],
        lags: usize,
        k: usize,
    ) {
        acc.nees_sum[i] = runs * self.nees;
        acc.nees_sq[i] = runs * self.nees_sq;
        acc.nees_dof[i] = runs * n as f64;
        acc.nees_count[i] = runs;
        acc.nis_sum[i] = runs * self.nis;
        acc.nis_sq[i] = runs * self.nis_sq;
        acc.nis_dof[i] = runs * m as f64;
        acc.nis_count[i] = runs;
        for (j, (c, v)) in comp_x.iter_mut().zip(&self.comp_x).enumerate() {
            *c += v;
            acc.state_comp_total[j] += runs * v;
            acc.state_comp_samples[j] += runs;
            acc.state_mean_total[j] += runs * self.mean_x[j];
            acc.state_mean_samples[j] += runs;
        }
        for (j, (c, v)) in comp_z.iter_mut().zip(&self.comp_z).enumerate() {
            *c += v;
            acc.meas_comp_total[j] += runs * v;
            acc.meas_comp_samples[j] += runs;
            acc.meas_mean_total[j] += runs * self.mean_z[j];
        }
        for lag in 1..=lags.min(k - 1).min(self.white.len()) {
            for j in 0..m {
                let o = (lag - 1) * m + j;
                acc.white_ab[o] += runs * self.white[lag - 1][j];
                acc.white_a2[o] += runs * self.comp_z[j];
                acc.white_b2[o] += runs * self.lagged_b2[lag - 1][j];
                acc.white_pairs[o] += runs;
            }
        }
    }
}
