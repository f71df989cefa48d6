//! The data-independent part of the linear fast path: each step's gains, the NEES and NIS
//! weights and the null variances, computed once per evaluation.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use crate::filter::conditioning::check_conditioned;
use crate::filter::{Filter, FilterError, KalmanFilter};
use crate::linalg::{cholesky, inverse_cholesky_factor, spd_inverse};
use crate::stats::{ComponentNullVariance, NeesNullVariance};

/// Relative change below which a covariance entry or increment counts as unchanged.
const STEADY_RTOL: f64 = 1e-14;

/// Unchanged steps in a row after which the recursion is in steady state.
pub(in crate::montecarlo) const STEADY_STEPS: usize = 3;

/// Whether every entry of `a` equals `b`'s to [`STEADY_RTOL`] relative to the geometric
/// mean of the two diagonal entries it couples (a unit-free test).
pub(in crate::montecarlo) fn same_covariance(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
    let n = a.nrows();
    (0..n).all(|i| {
        (0..n).all(|j| {
            let scale = (a[(i, i)] * a[(j, j)]).abs().sqrt();
            (a[(i, j)] - b[(i, j)]).abs() <= STEADY_RTOL * scale
        })
    })
}

/// The data-independent part of the filter, per step.
pub(super) struct Schedule {
    /// Gains, transposed (m × n), to multiply run rows from the right.
    pub(super) Kt: Vec<DMatrix<f64>>,
    /// `(L_P⁻¹)'`, so NEES = |e' Wt|².
    pub(super) Wt: Vec<DMatrix<f64>>,
    /// `(L_S⁻¹)'`, so NIS = |ν' Vt|².
    pub(super) Vt: Vec<DMatrix<f64>>,
    /// 1 / P_jj.
    pub(super) p_inv_diag: Vec<DVector<f64>>,
    /// 1 / √S_jj.
    pub(super) s_inv_sqrt_diag: Vec<DVector<f64>>,
    pub(super) null_var: f64,
    /// The predicted variance of each state component's per-run sum (empty when the gate
    /// does not test components).
    pub(super) comp_null_var: Vec<f64>,
    /// The predicted variance of each state component's per-run sum of `e_j/√P_jj` (empty
    /// when the gate does not test components).
    pub(super) mean_null_var: Vec<f64>,
    /// 1 / √P_jj.
    pub(super) p_inv_sqrt_diag: Vec<DVector<f64>>,
}

impl Schedule {
    /// Index of the stored matrices for step index `i` (the last stored ones once steady).
    pub(super) fn at(&self, i: usize) -> usize {
        i.min(self.Kt.len() - 1)
    }

    /// The schedule of `f` over `steps` steps, the NEES and the state components taken on
    /// its first `judged` states (all n but for a filter with states the truth lacks).
    pub(super) fn compute(
        f: &KalmanFilter,
        steps: usize,
        components: bool,
        judged: usize,
    ) -> Result<Self, FilterError> {
        let n = f.n_x();
        let mut s = Schedule {
            Kt: Vec::with_capacity(steps),
            Wt: Vec::with_capacity(steps),
            Vt: Vec::with_capacity(steps),
            p_inv_diag: Vec::with_capacity(steps),
            s_inv_sqrt_diag: Vec::with_capacity(steps),
            null_var: 0.0,
            comp_null_var: Vec::new(),
            mean_null_var: Vec::new(),
            p_inv_sqrt_diag: Vec::with_capacity(steps),
        };
        let mut P = f.P0.clone();
        let mut nv = NeesNullVariance::judged(n, judged);
        let mut cv = components.then(|| ComponentNullVariance::new(n));
        let mut last_cinc: Vec<f64> = Vec::new();
        // A time-invariant filter's covariance converges; once P and the null-variance
        // increment have stopped changing for a few steps, the last step's matrices serve
        // all remaining steps ([`Schedule::at`]) and the increment is extrapolated.
        let (mut quiet_p, mut quiet_v, mut last_inc) = (0usize, 0usize, f64::NAN);
        let mut p_steady = false;
        for k in 1..=steps {
            if p_steady && quiet_v >= STEADY_STEPS {
                nv.extend_steady(last_inc, steps - k + 1);
                if let Some(cv) = &mut cv {
                    cv.extend_steady(&last_cinc, steps - k + 1);
                }
                break;
            }
            let Pp = f.predict_covariance(&P);
            let cu = f.update_covariance(&Pp, k)?;
            let chol = cholesky(&cu.P).ok_or(FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            })?;
            check_conditioned("P", &cu.P, &chol, k)?;
            let chol = if judged == n {
                chol
            } else {
                cholesky(&cu.P.view((0, 0), (judged, judged)).clone_owned()).ok_or(
                    FilterError::NotPositiveDefinite {
                        which: "P",
                        step: k,
                    },
                )?
            };
            let map = &cu.IKH * &f.F;
            let inc = nv.step_judged(&map, &cu.P, &spd_inverse(chol.l_dirty()));
            let cinc = cv
                .as_mut()
                .map(|cv| cv.step(&map, &cu.P))
                .unwrap_or_default();
            let comps_quiet = cinc.len() == last_cinc.len()
                && cinc
                    .iter()
                    .zip(&last_cinc)
                    .all(|(a, b)| (a - b).abs() <= STEADY_RTOL * a.abs());
            last_cinc = cinc;
            quiet_v = if (inc - last_inc).abs() <= STEADY_RTOL * inc.abs() && comps_quiet {
                quiet_v + 1
            } else {
                0
            };
            last_inc = inc;
            if !p_steady {
                quiet_p = if same_covariance(&cu.P, &P) {
                    quiet_p + 1
                } else {
                    0
                };
                p_steady = quiet_p >= STEADY_STEPS;
                s.Wt.push(inverse_cholesky_factor(&chol).transpose());
                s.Vt.push(inverse_cholesky_factor(&cu.chol).transpose());
                let judged_diag = cu.P.diagonal().rows(0, judged).clone_owned();
                s.p_inv_diag.push(judged_diag.map(|v| 1.0 / v));
                s.p_inv_sqrt_diag.push(judged_diag.map(|v| 1.0 / v.sqrt()));
                s.s_inv_sqrt_diag
                    .push(cu.S.diagonal().map(|v| 1.0 / v.sqrt()));
                s.Kt.push(cu.K.transpose());
            }
            P = cu.P;
        }
        s.null_var = nv.variance();
        if let Some(cv) = &cv {
            s.comp_null_var = cv.variances()[..judged].to_vec();
            s.mean_null_var = cv.mean_variances()[..judged].to_vec();
        }
        Ok(s)
    }
}
