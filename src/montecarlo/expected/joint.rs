//! The joint moments of the truth's state and the filter's estimate, where the models differ.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::filter_step::FilterStep;
use super::values::{QuadScratch, StepValues, gaussian_quadratic_moments, sized};
use crate::filter::{CovarianceUpdate, KalmanFilter};
use crate::linalg::products::{Sparse, shaped};
use crate::model::LinearGaussianModel;
use crate::montecarlo::truth_moments::{TruthStep, TruthTrack};

/// The joint mean and second moments of the truth's state and the filter's estimate,
/// `s = [x; x̂]`, and the innovation cross-moments the whiteness sums need, propagated step
/// by step (the module's second case).
///
/// Held by blocks: `Φ` is block-diagonal and `B` the identity over the truth's rows, so the
/// truth's block is only propagated, never updated, and is read from its [`TruthTrack`].
/// The models' matrices are products' sparse operands ([`Sparse`]): a misfit trial spends
/// most of its scoring time here, so every product writes into a buffer of [`JointWork`]
/// kept from step to step (tens of allocations a step were a fifth of the time).
pub(super) struct JointMoments<'a> {
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
        let cu = &step.up.cu;
        let (mp_t, p_tt) = (&ts.mean, &ts.cov);
        // The update leaves the truth alone and sets x̂ = K H_t x + (I − K H_f) x̂⁻ + K v.
        // With G = K H_t: Cov(x, x̂) = P_tt G' + P_tf L', Cov(x̂) = Cov(x̂, x) G' +
        // (G P_tf + L P_ff) L' + K R K'.
        let JointGains { g_dense, g } = gains;
        let (k, l) = (&step.up.k_op, &step.up.ikh_op);
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

/// The transpose of `a` into `out` (reshaped).
fn transpose_into(a: &DMatrix<f64>, out: &mut DMatrix<f64>) {
    shaped(out, a.ncols(), a.nrows());
    a.transpose_to(out);
}

impl<'a> JointMoments<'a> {
    pub(super) fn new(
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
    pub(super) fn step(
        &mut self,
        i: usize,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        fs: &FilterStep,
        frozen: bool,
        out: &mut StepValues,
    ) {
        let cu = &fs.up.cu;
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
        let cu = &step.up.cu;
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
        let (k, l, g) = (&step.up.k_op, &step.up.ikh_op, &gains.g);

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
