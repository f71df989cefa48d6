//! One step of the filter's covariance recursion as the exact scoring reads it.

#![allow(non_snake_case)]

use nalgebra::DMatrix;

use crate::filter::{CovarianceUpdate, FilterError, KalmanFilter};
use crate::linalg::products::Sparse;
use crate::linalg::{cholesky, spd_inverse};

/// One step of the filter's covariance recursion, and what the moments read of it.
pub(super) struct FilterStep {
    pub(super) cu: CovarianceUpdate,
    /// K and `I − K H` as product operands.
    pub(super) k_op: Sparse,
    pub(super) ikh_op: Sparse,
    /// The error map `A = (I − K H) F`, n × n.
    pub(super) a: DMatrix<f64>,
    /// The inverse of P's judged block (its first `judged` states), and of S: the weights
    /// of the NEES and NIS.
    pub(super) p_inv: DMatrix<f64>,
    pub(super) s_inv: DMatrix<f64>,
}

impl FilterStep {
    /// Step `k` of `f` (its F and H as product operands, `f_op` and `h_op`) from the
    /// posterior `P` of the step before.
    ///
    /// The update is [`KalmanFilter::update_covariance_sparse`]: its products run over the
    /// models' nonzeros, and its K and I − K H serve the moment recursions as operands.
    pub(super) fn after(
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
