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
use super::truth_moments::{STEADY_RTOL, Truth, TruthMoment, TruthStep, TruthTrack};
use crate::filter::{CovarianceUpdate, Filter, FilterError, KalmanFilter};
use crate::linalg::products::{Sparse, shaped};
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
        match &mut moments {
            Moments::Matched(e) => e.advance(truth, f, fs, &mut values),
            Moments::Joint(j) => j.step(i, truth, f, fs, frozen, &mut values),
        }
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
        out: &mut StepValues,
    ) {
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

        let quad = &mut QuadScratch::default();
        let (nees, nees_sq) = gaussian_quadratic_moments(&step.p_inv, &sig, &mu_new, quad);
        let nu_cov = &nu_m2 - &nu_mean * nu_mean.transpose();
        let (nis, nis_sq) = gaussian_quadratic_moments(&step.s_inv, &nu_cov, &nu_mean, quad);

        let s_diag = cu.S.diagonal();
        // E[ν_k ν_{k−l}'] = H F E[e_{k−1} ν_{k−l}']: only the diagonal of each block is read.
        let z = fs.left(&self.window);
        // Only the diagonal of each lag's block is read: row j of H against column j.
        let cross = |lag: usize, j: usize| hs.row_dot(j, z.column(lag * m + j).as_slice());
        let comp_z_now: Vec<f64> = (0..m).map(|j| nu_m2[(j, j)] / s_diag[j]).collect();
        *out = StepValues {
            nees,
            nees_sq,
            nis,
            nis_sq,
            comp_x: (0..n).map(|j| e_m2[(j, j)] / cu.P[(j, j)]).collect(),
            comp_z: comp_z_now.clone(),
            mean_x: (0..n).map(|j| mu_new[j] / cu.P[(j, j)].sqrt()).collect(),
            mean_z: (0..m).map(|j| nu_mean[j] / s_diag[j].sqrt()).collect(),
            lags: self.s_diag_hist.len(),
            white: self
                .s_diag_hist
                .iter()
                .enumerate()
                .flat_map(|(lag, sd)| {
                    (0..m)
                        .map(|j| cross(lag, j) / (s_diag[j] * sd[j]).sqrt())
                        .collect::<Vec<f64>>()
                })
                .collect(),
            lagged_b2: self.comp_z_hist.concat(),
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
    }
}

/// The joint mean and second moments of the truth's state and the filter's estimate,
/// `s = [x; x̂]`, and the innovation cross-moments the whiteness sums need, propagated step
/// by step (the module's second case).
///
/// Held by blocks: `Φ` is block-diagonal and `B` the identity over the truth's rows, so the
/// truth's block is only propagated, never updated, and is read from its [`TruthTrack`].
/// The models' matrices are products' sparse operands ([`Sparse`]): a misfit trial spends
/// most of its scoring time here, so every product writes into a buffer of [`JointWork`]
/// kept from step to step (tens of allocations a step were a fifth of the time).
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
    /// diag(S) and the expected u_j² of the last `held` steps, most recent first (m each).
    s_diag_hist: Vec<f64>,
    comp_z_hist: Vec<f64>,
    held: usize,
    /// The step's operands kept while the filter is steady.
    gains: Option<JointGains>,
    work: JointWork,
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

    /// The operands of another gain, in this one's storage.
    fn refresh(&mut self, h_t: &Sparse, cu: &CovarianceUpdate) {
        h_t.right_into(&cu.K, &mut self.g_dense);
        self.g.reset(&self.g_dense);
    }
}

/// The intermediate products of one joint step, kept for the next (named as in
/// [`JointMoments::advance`]; `t1`, `t2` and the others hold a product before it is added,
/// one buffer per shape so that none is reshaped from step to step).
#[derive(Default)]
struct JointWork {
    mp_f: DVector<f64>,
    p_tf: DMatrix<f64>,
    p_ff: DMatrix<f64>,
    m_ft: DMatrix<f64>,
    m_tf: DMatrix<f64>,
    m_ff: DMatrix<f64>,
    w_t: DMatrix<f64>,
    w_f: DMatrix<f64>,
    h_mp: DVector<f64>,
    nu_mean: DVector<f64>,
    nu_m2: DMatrix<f64>,
    nu_cov: DMatrix<f64>,
    s_tf: DMatrix<f64>,
    v: DMatrix<f64>,
    tr: DMatrix<f64>,
    s_ff: DMatrix<f64>,
    mu_f: DVector<f64>,
    g_mp: DVector<f64>,
    e_mean: DVector<f64>,
    x: DMatrix<f64>,
    e_cov: DMatrix<f64>,
    z_t: DMatrix<f64>,
    z_f: DMatrix<f64>,
    next_t: DMatrix<f64>,
    next_f: DMatrix<f64>,
    t1: DMatrix<f64>,
    t2: DMatrix<f64>,
    u1: DMatrix<f64>,
    u2: DMatrix<f64>,
    tr_ff: DMatrix<f64>,
    scratch_ff: DMatrix<f64>,
    tm: DMatrix<f64>,
    fm1: DMatrix<f64>,
    fm2: DMatrix<f64>,
    mm1: DMatrix<f64>,
    mm2: DMatrix<f64>,
    fk1: DMatrix<f64>,
    fk2: DMatrix<f64>,
    scratch: DMatrix<f64>,
    scratch_k: DMatrix<f64>,
    quad: QuadScratch,
}

impl JointWork {
    /// The prediction and the innovation's moments of a step: `E[x̂⁻]`, the prior
    /// second moments by blocks, `E[ν]`, `E[ν ν']` and `E[s⁻ ν']` (`w_t`, `w_f`), from the
    /// last step's `E[x̂]` (`mu_f`), `[Cov(x, x̂), Cov(x̂)]` (`s`) and the truth's step `ts`;
    /// `ops` are the truth's F and H and the filter's.
    fn predict(
        &mut self,
        f: &KalmanFilter,
        truth: &LinearGaussianModel,
        [f_t, h_t, f_f, h_f]: [&Sparse; 4],
        [s_tf, s_ff]: [&DMatrix<f64>; 2],
        mu_f: &DVector<f64>,
        ts: &TruthStep,
    ) {
        let m = f.H.nrows();
        // The prediction: Φ is block-diagonal, the truth's noise enters its own block (the
        // truth's moments are the track's).
        let mp_t = &ts.mean;
        sized(&mut self.mp_f, f.F.nrows());
        f.F.mul_to(mu_f, &mut self.mp_f);
        f_t.sandwich_into(s_tf, f_f, &mut self.scratch, &mut self.p_tf);
        f_f.sandwich_into(s_ff, f_f, &mut self.scratch_ff, &mut self.p_ff);
        crate::linalg::symmetrize(&mut self.p_ff);
        // M_ft = P_tf' + E[x̂] E[x]', M_tf its transpose, M_ff = P_ff + E[x̂] E[x̂]'.
        let mp_f = &self.mp_f;
        transpose_into(&self.p_tf, &mut self.m_ft);
        add_outer(&mut self.m_ft, mp_f, mp_t);
        transpose_into(&self.m_ft, &mut self.m_tf);
        shaped(&mut self.m_ff, mp_f.len(), mp_f.len());
        self.m_ff.copy_from(&self.p_ff);
        add_outer(&mut self.m_ff, mp_f, mp_f);

        // ν = H_t x − H_f x̂ + v: its mean, its second moment and E[s⁻ ν'] by blocks.
        h_f.right_tr_into(&self.m_tf, &mut self.tm);
        sub_into(&ts.m2_ht, &self.tm, &mut self.w_t);
        h_t.right_tr_into(&self.m_ft, &mut self.fm1);
        h_f.right_tr_into(&self.m_ff, &mut self.fm2);
        sub_into(&self.fm1, &self.fm2, &mut self.w_f);
        sized(&mut self.h_mp, m);
        f.H.mul_to(&self.mp_f, &mut self.h_mp);
        sized(&mut self.nu_mean, m);
        self.nu_mean
            .zip_zip_apply(&ts.h_mean, &self.h_mp, |o, a, b| *o = a - b);
        h_t.left_into(self.w_t.as_slice(), self.w_t.ncols(), &mut self.mm1);
        h_f.left_into(self.w_f.as_slice(), self.w_f.ncols(), &mut self.mm2);
        sub_into(&self.mm1, &self.mm2, &mut self.nu_m2);
        self.nu_m2 += &truth.R;
    }

    /// The update's moments, `Cov(x, x̂)`, `Cov(x̂)` and `E[x̂]`, from the prediction's.
    fn update(
        &mut self,
        truth: &LinearGaussianModel,
        step: &FilterStep,
        gains: &JointGains,
        ts: &TruthStep,
    ) {
        let cu = &step.cu;
        let (mp_t, p_tt) = (&ts.mean, &ts.cov);
        // The update leaves the truth alone and sets x̂ = K H_t x + (I − K H_f) x̂⁻ + K v.
        // With G = K H_t: Cov(x, x̂) = P_tt G' + P_tf L', Cov(x̂) = Cov(x̂, x) G' +
        // (G P_tf + L P_ff) L' + K R K'.
        let JointGains { g_dense, g } = gains;
        let (k, l) = (&step.k_op, &step.ikh_op);
        // The n_t × n_f products in `t1`, `t2`, the n_f × n_f ones in `u1`, `u2`, the
        // transposes in `tr` and `tr_ff`: a buffer that changed shape within a step was
        // reallocated and zeroed twice a step (filters with more states than the truth).
        g.right_tr_into(p_tt, &mut self.t1);
        l.right_tr_into(&self.p_tf, &mut self.t2);
        add_into(&self.t1, &self.t2, &mut self.s_tf);
        transpose_into(&self.p_tf, &mut self.tr);
        g.right_tr_into(&self.tr, &mut self.u1);
        l.right_tr_into(&self.p_ff, &mut self.u2);
        add_into(&self.u1, &self.u2, &mut self.v);
        transpose_into(&self.s_tf, &mut self.tr);
        g.right_tr_into(&self.tr, &mut self.u1);
        transpose_into(&self.v, &mut self.tr_ff);
        l.right_tr_into(&self.tr_ff, &mut self.u2);
        add_into(&self.u1, &self.u2, &mut self.s_ff);
        k.sandwich_into(&truth.R, k, &mut self.scratch_k, &mut self.u1);
        self.s_ff += &self.u1;
        crate::linalg::symmetrize(&mut self.s_ff);
        sized(&mut self.g_mp, g_dense.nrows());
        g_dense.mul_to(mp_t, &mut self.g_mp);
        sized(&mut self.mu_f, cu.IKH.nrows());
        cu.IKH.mul_to(&self.mp_f, &mut self.mu_f);
        self.mu_f += &self.g_mp;
    }
}

/// `out += a b'` (out: a.len() × b.len()), by columns.
fn add_outer(out: &mut DMatrix<f64>, a: &DVector<f64>, b: &DVector<f64>) {
    let r = a.len();
    debug_assert_eq!(out.shape(), (r, b.len()));
    if r == 0 {
        return;
    }
    for (col, &bc) in out.as_mut_slice().chunks_exact_mut(r).zip(b.iter()) {
        for (o, &ar) in col.iter_mut().zip(a.iter()) {
            *o += ar * bc;
        }
    }
}

/// `a − b`, `a + b`: elementwise into `out` (reshaped), the sums of nalgebra's operators.
fn sub_into(a: &DMatrix<f64>, b: &DMatrix<f64>, out: &mut DMatrix<f64>) {
    shaped(out, a.nrows(), a.ncols());
    out.zip_zip_apply(a, b, |o, x, y| *o = x - y);
}

fn add_into(a: &DMatrix<f64>, b: &DMatrix<f64>, out: &mut DMatrix<f64>) {
    shaped(out, a.nrows(), a.ncols());
    out.zip_zip_apply(a, b, |o, x, y| *o = x + y);
}

/// `v` of length `n`, its storage kept where it has that length already (the contents
/// are written over by the caller).
fn sized(v: &mut DVector<f64>, n: usize) {
    if v.len() != n {
        *v = DVector::zeros(n);
    }
}

/// The transpose of `a` into `out` (reshaped).
fn transpose_into(a: &DMatrix<f64>, out: &mut DMatrix<f64>) {
    shaped(out, a.ncols(), a.nrows());
    a.transpose_to(out);
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
            s_diag_hist: Vec::new(),
            comp_z_hist: Vec::new(),
            held: 0,
            gains: None,
            work: JointWork::default(),
        }
    }

    /// Through step `i` (from 0) of the filter, `fs` (`frozen`: the same step as the last
    /// one): the step's expected values, into `out`.
    fn step(
        &mut self,
        i: usize,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        fs: &FilterStep,
        frozen: bool,
        out: &mut StepValues,
    ) {
        let cu = &fs.cu;
        // The gain operands of the last step serve a frozen one; otherwise they are rebuilt
        // in their own storage.
        let gains = match self.gains.take() {
            Some(g) if frozen => g,
            Some(mut g) => {
                g.refresh(&self.h_t, cu);
                g
            }
            None => JointGains::new(&self.h_t, cu),
        };
        self.advance(i, truth, f, fs, &gains, out);
        self.gains = Some(gains);
    }

    fn advance(
        &mut self,
        i: usize,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        step: &FilterStep,
        gains: &JointGains,
        out: &mut StepValues,
    ) {
        let cu = &step.cu;
        let (f_t, h_t, f_f, h_f) = (&self.f_t, &self.h_t, &self.f_f, &self.h_f);
        let m = f.H.nrows();
        let ne = self.ne;
        let ts = &self.track.steps[i];
        let w = &mut self.work;

        w.predict(
            f,
            truth,
            [f_t, h_t, f_f, h_f],
            [&self.s_tf, &self.s_ff],
            &self.mu_f,
            ts,
        );
        w.update(truth, step, gains, ts);
        let n_t = w.s_tf.nrows();
        let (k, l, g) = (&step.k_op, &step.ikh_op, &gains.g);

        // The judged error M x − x̂[..ne].
        sized(&mut w.e_mean, ne);
        w.e_mean
            .zip_zip_apply(&ts.map_mean, &w.mu_f.rows(0, ne), |o, a, b| *o = a - b);
        self.map
            .left_into(&w.s_tf.as_slice()[..n_t * ne], ne, &mut w.x);
        shaped(&mut w.e_cov, ne, ne);
        for c in 0..ne {
            for r in 0..ne {
                w.e_cov[(r, c)] = ts.map_cov[(r, c)] - w.x[(r, c)] - w.x[(c, r)] + w.s_ff[(r, c)];
            }
        }
        crate::linalg::symmetrize(&mut w.e_cov);

        let (nees, nees_sq) =
            gaussian_quadratic_moments(&step.p_inv, &w.e_cov, &w.e_mean, &mut w.quad);
        shaped(&mut w.nu_cov, m, m);
        for c in 0..m {
            for r in 0..m {
                w.nu_cov[(r, c)] = w.nu_m2[(r, c)] - w.nu_mean[r] * w.nu_mean[c];
            }
        }
        let (nis, nis_sq) =
            gaussian_quadratic_moments(&step.s_inv, &w.nu_cov, &w.nu_mean, &mut w.quad);
        // E[ν_k ν_{k−l}'] = C Φ E[s_{k−1} ν_{k−l}'], whose Φ part also advances the window.
        f_t.left_into(self.window_t.as_slice(), self.window_t.ncols(), &mut w.z_t);
        f_f.left_into(self.window_f.as_slice(), self.window_f.ncols(), &mut w.z_f);
        out.nees = nees;
        out.nees_sq = nees_sq;
        out.nis = nis;
        out.nis_sq = nis_sq;
        let s_diag = |j: usize| cu.S[(j, j)];
        let p_diag = |j: usize| cu.P[(j, j)];
        out.comp_x.clear();
        out.comp_x.extend((0..ne).map(|j| {
            let e2 = w.e_cov[(j, j)] + w.e_mean[j] * w.e_mean[j];
            e2 / p_diag(j)
        }));
        out.comp_z.clear();
        out.comp_z
            .extend((0..m).map(|j| w.nu_m2[(j, j)] / s_diag(j)));
        out.mean_x.clear();
        out.mean_x
            .extend((0..ne).map(|j| w.e_mean[j] / p_diag(j).sqrt()));
        out.mean_z.clear();
        out.mean_z
            .extend((0..m).map(|j| w.nu_mean[j] / s_diag(j).sqrt()));
        // Only the diagonal of each lag's block is read: row j of C against column j.
        out.lags = self.held;
        out.white.clear();
        for l in 0..self.held {
            for j in 0..m {
                let c = l * m + j;
                let cross = h_t.row_dot(j, w.z_t.column(c).as_slice())
                    - h_f.row_dot(j, w.z_f.column(c).as_slice());
                out.white
                    .push(cross / (s_diag(j) * self.s_diag_hist[c]).sqrt());
            }
        }
        out.lagged_b2.clear();
        out.lagged_b2
            .extend_from_slice(&self.comp_z_hist[..self.held * m]);
        // E[s_k ν_k'] and the older cross-moments through B (Φ applied above).
        if self.lags > 0 {
            let kept = (self.lags - 1).min(self.held) * m;
            let n_f = w.s_ff.nrows();
            // now_f = G W_t + L W_f + K R, older_f = G Z_t + L Z_f (the kept columns).
            g.left_into(w.w_t.as_slice(), m, &mut w.fm1);
            l.left_into(w.w_f.as_slice(), m, &mut w.fm2);
            w.fm1 += &w.fm2;
            k.left_into(truth.R.as_slice(), m, &mut w.fm2);
            w.fm1 += &w.fm2;
            shaped(&mut w.next_f, n_f, m + kept);
            w.next_f.columns_mut(0, m).copy_from(&w.fm1);
            g.left_into(&w.z_t.as_slice()[..n_t * kept], kept, &mut w.fk1);
            l.left_into(&w.z_f.as_slice()[..n_f * kept], kept, &mut w.fk2);
            w.fk1 += &w.fk2;
            w.next_f.columns_mut(m, kept).copy_from(&w.fk1);
            shaped(&mut w.next_t, n_t, m + kept);
            w.next_t.columns_mut(0, m).copy_from(&w.w_t);
            w.next_t
                .columns_mut(m, kept)
                .copy_from(&w.z_t.columns(0, kept));
            std::mem::swap(&mut self.window_t, &mut w.next_t);
            std::mem::swap(&mut self.window_f, &mut w.next_f);
        }
        // The histories, most recent first, `lags` steps long.
        if self.lags > 0 {
            self.held = (self.held + 1).min(self.lags);
            let len = self.held * m;
            self.s_diag_hist.resize(len, 0.0);
            self.comp_z_hist.resize(len, 0.0);
            self.s_diag_hist.copy_within(0..len - m, m);
            self.comp_z_hist.copy_within(0..len - m, m);
            for j in 0..m {
                self.s_diag_hist[j] = s_diag(j);
            }
            self.comp_z_hist[..m].copy_from_slice(&out.comp_z);
        }
        std::mem::swap(&mut self.mu_f, &mut w.mu_f);
        std::mem::swap(&mut self.s_tf, &mut w.s_tf);
        std::mem::swap(&mut self.s_ff, &mut w.s_ff);
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
/// `B = M⁻¹ Σ`, in plain loops (a few states: no packing), in the storage of `scratch`.
fn gaussian_quadratic_moments(
    minv: &DMatrix<f64>,
    sigma: &DMatrix<f64>,
    mu: &DVector<f64>,
    scratch: &mut QuadScratch,
) -> (f64, f64) {
    let n = mu.len();
    let (w, s) = (minv.as_slice(), sigma.as_slice());
    let QuadScratch {
        b,
        minv_mu,
        s_minv_mu,
    } = scratch;
    b.clear();
    b.resize(n * n, 0.0);
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
    sized(minv_mu, n);
    minv.mul_to(mu, minv_mu);
    let q = mu.dot(minv_mu);
    sized(s_minv_mu, n);
    sigma.mul_to(minv_mu, s_minv_mu);
    let cross = minv_mu.dot(s_minv_mu);
    (
        tr + q,
        tr * tr + 2.0 * tr2 + 4.0 * cross + 2.0 * tr * q + q * q,
    )
}

/// The storage [`gaussian_quadratic_moments`] works in: `B`, `M⁻¹ μ` and `Σ M⁻¹ μ`.
#[derive(Default)]
struct QuadScratch {
    b: Vec<f64>,
    minv_mu: DVector<f64>,
    s_minv_mu: DVector<f64>,
}

/// The expected per-run values of one step.
#[derive(Default)]
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
    /// The lags with a step behind them (up to the configured lags).
    lags: usize,
    /// `white[(l − 1) m + j]` = E[u_k,j u_{k−l},j].
    white: Vec<f64>,
    /// `lagged_b2[(l − 1) m + j]` = E[u_{k−l},j²].
    lagged_b2: Vec<f64>,
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
            && self.lags == o.lags
            && all(&self.white, &o.white)
            && all(&self.lagged_b2, &o.lagged_b2)
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
        for lag in 1..=lags.min(k - 1).min(self.lags) {
            for j in 0..m {
                let o = (lag - 1) * m + j;
                acc.white_ab[o] += runs * self.white[o];
                acc.white_a2[o] += runs * self.comp_z[j];
                acc.white_b2[o] += runs * self.lagged_b2[o];
                acc.white_pairs[o] += runs;
            }
        }
    }
}
