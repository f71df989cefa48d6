//! The estimation error's own moments, where the filter's model matches the truth's.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::filter_step::FilterStep;
use super::values::{QuadScratch, StepValues, gaussian_quadratic_moments};
use crate::filter::KalmanFilter;
use crate::linalg::products::Sparse;
use crate::model::LinearGaussianModel;

/// The estimation error's mean and covariance, and the innovation cross-moments the
/// whiteness sums need, propagated step by step (F and H as [`Sparse`] operands).
pub(super) struct ErrorMoments {
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
    pub(super) fn new(truth: &LinearGaussianModel, f: &KalmanFilter, lags: usize) -> Self {
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
    pub(super) fn advance(
        &mut self,
        truth: &LinearGaussianModel,
        f: &KalmanFilter,
        step: &FilterStep,
        out: &mut StepValues,
    ) {
        let cu = &step.up.cu;
        let (k, l) = (&step.up.k_op, &step.up.ikh_op);
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
