//! One step of the filter's covariance recursion as the exact scoring reads it.

#![allow(non_snake_case)]

use nalgebra::{Cholesky, DMatrix, Dyn};

use crate::filter::{FilterError, KalmanFilter, SparseUpdate};
use crate::linalg::products::{Sparse, shaped};
use crate::linalg::{cholesky_reusing, spd_inverse_into, symmetrize};

/// One step of the filter's covariance recursion, and what the moments read of it.
pub(super) struct FilterStep {
    /// The update (K, S, P, `I − K H`) with K and `I − K H` as product operands.
    pub(super) up: SparseUpdate,
    /// The error map `A = (I − K H) F`, n × n.
    pub(super) a: DMatrix<f64>,
    /// The inverse of P's judged block (its first `judged` states), and of S: the weights
    /// of the NEES and NIS.
    pub(super) p_inv: DMatrix<f64>,
    pub(super) s_inv: DMatrix<f64>,
    /// The intermediate products, kept for the step this storage computes next.
    work: StepWork,
}

/// A step's intermediate products: `P⁻` and its factor, the judged block of P and its
/// factor, and the scratch of the prediction and the inverses.
#[derive(Default)]
struct StepWork {
    pp: DMatrix<f64>,
    pp_chol: Option<Cholesky<f64, Dyn>>,
    judged: DMatrix<f64>,
    judged_chol: Option<Cholesky<f64, Dyn>>,
    scratch: DMatrix<f64>,
    inverse: Vec<f64>,
}

impl FilterStep {
    /// Step `k` of `f` (its F and H as product operands, `f_op` and `h_op`) from the
    /// posterior `P` of the step before, in new storage: [`FilterStep::advance`].
    pub(super) fn after(
        f: &KalmanFilter,
        ops: (&Sparse, &Sparse),
        P: &DMatrix<f64>,
        judged: usize,
        k: usize,
    ) -> Result<Self, FilterError> {
        let mut step = FilterStep {
            up: SparseUpdate::default(),
            a: DMatrix::zeros(0, 0),
            p_inv: DMatrix::zeros(0, 0),
            s_inv: DMatrix::zeros(0, 0),
            work: StepWork::default(),
        };
        step.advance(f, ops, P, judged, k)?;
        Ok(step)
    }

    /// This storage set to step `k` of `f` from the posterior `P` of the step before (the
    /// step before that gives its storage up, so a recursion allocates nothing from step
    /// to step).
    ///
    /// The prediction `F P F' + Q` with F's zeros skipped, then
    /// [`KalmanFilter::update_covariance_sparse`] (the update over H's nonzeros, with its
    /// checks of P⁻ and S), then P's judged block factored and inverted, and the error map
    /// `(I − K H) F`. The storage is left partly written when a check fails.
    pub(super) fn advance(
        &mut self,
        f: &KalmanFilter,
        (f_op, h_op): (&Sparse, &Sparse),
        P: &DMatrix<f64>,
        judged: usize,
        k: usize,
    ) -> Result<(), FilterError> {
        let w = &mut self.work;
        // `predict_covariance`'s F P F' + Q.
        f_op.sandwich_into(P, f_op, &mut w.scratch, &mut w.pp);
        w.pp += &f.Q;
        symmetrize(&mut w.pp);
        f.update_covariance_sparse(&w.pp, h_op, k, &mut self.up, &mut w.pp_chol)?;
        let cu = &self.up.cu;
        // P's judged block (P is finite: the update checked it).
        shaped(&mut w.judged, judged, judged);
        w.judged.copy_from(&cu.P.view((0, 0), (judged, judged)));
        w.judged_chol = cholesky_reusing(&w.judged, w.judged_chol.take());
        let Some(judged_chol) = &w.judged_chol else {
            return Err(FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            });
        };
        f_op.right_into(&cu.IKH, &mut self.a);
        spd_inverse_into(judged_chol.l_dirty(), &mut w.inverse, &mut self.p_inv);
        spd_inverse_into(cu.chol.l_dirty(), &mut w.inverse, &mut self.s_inv);
        Ok(())
    }
}
