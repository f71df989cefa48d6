//! The linear fast path: for a linear filter measured on a fixed schedule, P_k, S_k and
//! K_k do not depend on the data, so they are computed once per evaluation and every run
//! only propagates its mean. Runs are processed a chunk at a time as the columns of n × B
//! matrices, so each step is a handful of small matrix products instead of B·(several)
//! matrix-vector products with their per-call overhead.

#![allow(non_snake_case)]

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::{Accumulator, RunScratch, Settings, run_chunked, run_rng};
use crate::filter::{Filter, FilterError, KalmanFilter};
use crate::linalg::{cholesky, inverse_cholesky_factor};
use crate::model::{LinearGaussianModel, sample_gaussian};
use crate::stats::NeesNullVariance;

/// The data-independent part of the filter, per step.
struct Schedule {
    K: Vec<DMatrix<f64>>,
    /// `L_P⁻¹`, so NEES = |W e|².
    W: Vec<DMatrix<f64>>,
    /// `L_S⁻¹`, so NIS = |V ν|².
    V: Vec<DMatrix<f64>>,
    /// 1 / P_jj.
    p_inv_diag: Vec<DVector<f64>>,
    /// 1 / √S_jj.
    s_inv_sqrt_diag: Vec<DVector<f64>>,
    null_var: f64,
}

impl Schedule {
    fn compute(f: &KalmanFilter, steps: usize) -> Result<Self, FilterError> {
        let n = f.n_x();
        let mut s = Schedule {
            K: Vec::with_capacity(steps),
            W: Vec::with_capacity(steps),
            V: Vec::with_capacity(steps),
            p_inv_diag: Vec::with_capacity(steps),
            s_inv_sqrt_diag: Vec::with_capacity(steps),
            null_var: 0.0,
        };
        let mut P = f.P0.clone();
        let mut nv = NeesNullVariance::new(n);
        for k in 1..=steps {
            let Pp = f.predict_covariance(&P);
            let cu = f.update_covariance(&Pp, k)?;
            P = cu.P;
            let chol = cholesky(&P).ok_or(FilterError::NotPositiveDefinite { which: "P", step: k })?;
            nv.step(&(&cu.IKH * &f.F), &P, &chol);
            s.W.push(inverse_cholesky_factor(&chol));
            s.V.push(inverse_cholesky_factor(&cu.chol));
            s.p_inv_diag.push(P.diagonal().map(|v| 1.0 / v));
            s.s_inv_sqrt_diag.push(cu.S.diagonal().map(|v| 1.0 / v.sqrt()));
            s.K.push(cu.K);
        }
        s.null_var = nv.variance();
        Ok(s)
    }
}

/// Run the Monte Carlo test of a linear Kalman filter against a linear-Gaussian truth.
///
/// Gives the same statistics as [`super::run_generic`] on the same pair (to rounding: the
/// random draws are the same, the arithmetic is reordered), several times faster.
pub fn run_linear(truth: &LinearGaussianModel, filter: &KalmanFilter, settings: &Settings) -> Accumulator {
    let n = filter.n_x();
    let m = filter.H.nrows();
    match Schedule::compute(filter, settings.steps) {
        Ok(sched) => run_chunked(settings, n, m, |range, acc| chunk(truth, filter, &sched, settings, range, acc)),
        Err(e) => {
            // The covariance recursion is the same in every run, so every run diverges at
            // the same step.
            let mut acc = Accumulator::new(settings.steps, n, m, settings.lags);
            for run in 0..settings.runs {
                acc.record_divergence(run, &e);
            }
            acc.runs = settings.runs;
            acc
        }
    }
}

fn chunk(
    truth: &LinearGaussianModel,
    f: &KalmanFilter,
    sched: &Schedule,
    settings: &Settings,
    range: Range<usize>,
    acc: &mut Accumulator,
) {
    let n = f.n_x();
    let m = f.H.nrows();
    let b = range.len();
    let lq = &truth.factors.q;
    let lr = &truth.factors.r;
    let (rq, rr) = (lq.ncols(), lr.ncols());

    let mut rngs: Vec<_> = range.clone().map(|i| run_rng(settings.seed, i)).collect();
    let mut scratch: Vec<RunScratch> = (0..b).map(|_| RunScratch::new(n, m, settings.lags)).collect();

    let mut xt = DMatrix::zeros(n, b);
    for (c, rng) in rngs.iter_mut().enumerate() {
        xt.set_column(c, &sample_gaussian(&truth.x0, &truth.factors.p0, rng));
    }
    let mut xh = DMatrix::from_fn(n, b, |r, _| f.x0[r]);
    let mut tmp = DMatrix::zeros(n, b);
    let mut wq = DMatrix::zeros(rq, b);
    let mut wr = DMatrix::zeros(rr, b);
    let mut z = DMatrix::zeros(m, b);
    let mut nu = DMatrix::zeros(m, b);
    let mut e = DMatrix::zeros(n, b);
    let mut we = DMatrix::zeros(n, b);
    let mut vn = DMatrix::zeros(m, b);

    for k in 1..=settings.steps {
        let i = k - 1;
        // Per column: process noise first, then measurement noise, as the generic path does.
        for (c, rng) in rngs.iter_mut().enumerate() {
            for r in 0..rq {
                wq[(r, c)] = rng.sample(StandardNormal);
            }
            for r in 0..rr {
                wr[(r, c)] = rng.sample(StandardNormal);
            }
        }
        tmp.gemm(1.0, &truth.F, &xt, 0.0);
        tmp.gemm(1.0, lq, &wq, 1.0);
        std::mem::swap(&mut xt, &mut tmp);
        z.gemm(1.0, &truth.H, &xt, 0.0);
        z.gemm(1.0, lr, &wr, 1.0);

        tmp.gemm(1.0, &f.F, &xh, 0.0);
        std::mem::swap(&mut xh, &mut tmp);
        nu.copy_from(&z);
        nu.gemm(-1.0, &f.H, &xh, 1.0);
        xh.gemm(1.0, &sched.K[i], &nu, 1.0);
        e.copy_from(&xt);
        e -= &xh;
        we.gemm(1.0, &sched.W[i], &e, 0.0);
        vn.gemm(1.0, &sched.V[i], &nu, 0.0);

        let pinv = &sched.p_inv_diag[i];
        let srt = &sched.s_inv_sqrt_diag[i];
        for (c, sc) in scratch.iter_mut().enumerate() {
            let nees = we.column(c).norm_squared();
            let nis = vn.column(c).norm_squared();
            acc.nees_sum[i] += nees;
            acc.nees_sq[i] += nees * nees;
            acc.nis_sum[i] += nis;
            acc.nis_sq[i] += nis * nis;
            let ec = e.column(c);
            sc.state_step(acc, (0..n).map(|j| ec[j] * ec[j] * pinv[j]));
            for j in 0..m {
                sc.innovation(acc, j, nu[(j, c)] * srt[j]);
            }
            sc.end_step(acc, k);
        }
        acc.nees_dof[i] += (n * b) as f64;
        acc.nees_count[i] += b as f64;
        acc.nis_dof[i] += (m * b) as f64;
        acc.nis_count[i] += b as f64;
    }
    for sc in &scratch {
        sc.end_run(acc);
    }
    acc.nees_null_var += sched.null_var * b as f64;
}
