//! The linear fast path: for a linear filter measured on a fixed schedule, P_k, S_k and
//! K_k do not depend on the data, so they are computed once per evaluation and every run
//! only propagates its mean. Runs are processed a chunk at a time as the rows of B × n
//! matrices, so each step is a handful of products whose inner loops run over the B runs,
//! instead of B·(several) tiny matrix-vector products with their per-call overhead.

#![allow(non_snake_case)]

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::generic::{Fault, MAX_RATIO_SQ};
use super::{McConfig, run_chunked, run_rng};
use crate::filter::conditioning::check_conditioned;
use crate::filter::{Filter, FilterError, KalmanFilter};
use crate::linalg::{cholesky, inverse_cholesky_factor};
use crate::model::{LinearGaussianModel, sample_gaussian};
use crate::stats::Accumulator;
use crate::stats::{ComponentNullVariance, GateMode, NeesNullVariance};

/// The data-independent part of the filter, per step.
struct Schedule {
    /// Gains, transposed (m × n), to multiply run rows from the right.
    Kt: Vec<DMatrix<f64>>,
    /// `(L_P⁻¹)'`, so NEES = |e' Wt|².
    Wt: Vec<DMatrix<f64>>,
    /// `(L_S⁻¹)'`, so NIS = |ν' Vt|².
    Vt: Vec<DMatrix<f64>>,
    /// 1 / P_jj.
    p_inv_diag: Vec<DVector<f64>>,
    /// 1 / √S_jj.
    s_inv_sqrt_diag: Vec<DVector<f64>>,
    null_var: f64,
    /// The predicted variance of each state component's per-run sum (empty when the gate
    /// does not test components).
    comp_null_var: Vec<f64>,
    /// The predicted variance of each state component's per-run sum of `e_j/√P_jj` (empty
    /// when the gate does not test components).
    mean_null_var: Vec<f64>,
    /// 1 / √P_jj.
    p_inv_sqrt_diag: Vec<DVector<f64>>,
}

/// Relative change below which a covariance entry or increment counts as unchanged.
const STEADY_RTOL: f64 = 1e-14;

/// Unchanged steps in a row after which the recursion is in steady state.
const STEADY_STEPS: usize = 3;

/// Whether every entry of `a` equals `b`'s to [`STEADY_RTOL`] relative to the geometric
/// mean of the two diagonal entries it couples (a unit-free test).
fn same_covariance(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
    let n = a.nrows();
    (0..n).all(|i| {
        (0..n).all(|j| {
            let scale = (a[(i, i)] * a[(j, j)]).abs().sqrt();
            (a[(i, j)] - b[(i, j)]).abs() <= STEADY_RTOL * scale
        })
    })
}

impl Schedule {
    /// Index of the stored matrices for step index `i` (the last stored ones once steady).
    fn at(&self, i: usize) -> usize {
        i.min(self.Kt.len() - 1)
    }

    fn compute(f: &KalmanFilter, steps: usize, components: bool) -> Result<Self, FilterError> {
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
        let mut nv = NeesNullVariance::new(n);
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
            let map = &cu.IKH * &f.F;
            let inc = nv.step(&map, &cu.P, &chol);
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
                s.p_inv_diag.push(cu.P.diagonal().map(|v| 1.0 / v));
                s.p_inv_sqrt_diag
                    .push(cu.P.diagonal().map(|v| 1.0 / v.sqrt()));
                s.s_inv_sqrt_diag
                    .push(cu.S.diagonal().map(|v| 1.0 / v.sqrt()));
                s.Kt.push(cu.K.transpose());
            }
            P = cu.P;
        }
        s.null_var = nv.variance();
        if let Some(cv) = &cv {
            s.comp_null_var = cv.variances().to_vec();
            s.mean_null_var = cv.mean_variances().to_vec();
        }
        Ok(s)
    }
}

/// Run the Monte Carlo test of a linear Kalman filter against a linear-Gaussian truth.
///
/// Gives the same statistics as [`super::run_generic`] on the same pair (to rounding: the
/// random draws are the same, the arithmetic is reordered), several times faster.
pub fn run_linear(
    truth: &LinearGaussianModel,
    filter: &KalmanFilter,
    mc: &McConfig,
) -> Accumulator {
    run_linear_with_progress(truth, filter, None, mc, None)
}

/// [`run_linear`] for a filter whose state is `map · x_true` (n_f × n_t; `None`: the
/// truth's state), the NEES taken on `map · x_true − x̂`, reporting the runs completed after
/// each parallel wave. A run whose numbers stop meaning anything (the truth overflows, the
/// state outgrows double precision, the NEES or NIS overflows) stops there as a divergence,
/// as on the generic path.
pub fn run_linear_with_progress(
    truth: &LinearGaussianModel,
    filter: &KalmanFilter,
    map: Option<&DMatrix<f64>>,
    mc: &McConfig,
    progress: super::Progress<'_>,
) -> Accumulator {
    let n = filter.n_x();
    let m = filter.H.nrows();
    let map_t = map.map(|m| m.transpose());
    match Schedule::compute(filter, mc.steps(), mc.gate() == GateMode::Full) {
        Ok(sched) => run_chunked(mc, n, m, progress, |range, acc| {
            let job = Job {
                truth,
                f: filter,
                map_t: map_t.as_ref(),
                sched: &sched,
                mc,
            };
            chunk_dispatch(&job, range, acc)
        }),
        // The covariance recursion is the same in every run, so every run stops at the same
        // step.
        Err(e) => super::all_stopped(mc, n, m, &e),
    }
}

/// `Σ a_i b_i` with four independent partial sums, so the additions pipeline instead of
/// forming one long dependency chain (the order is fixed, so results stay reproducible).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut p = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            p[l] += x[l] * y[l];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (p[0] + p[1]) + (p[2] + p[3]) + tail
}

/// `c ← α a b + β c` where `a` and `c` hold one run per row (B × k and B × n) and `b` is a
/// small k × n matrix. Each output column is a sum of k scaled columns of `a`, so the inner
/// loop runs over the B runs on contiguous memory and vectorizes. (nalgebra's `gemm` takes
/// the same approach below six columns but through strided generic iterators that cost
/// several times more per element here.)
#[inline(always)]
fn gemm_rows(c: &mut DMatrix<f64>, alpha: f64, a: &DMatrix<f64>, b: &DMatrix<f64>, beta: f64) {
    let rows = a.nrows();
    debug_assert_eq!(a.ncols(), b.nrows());
    debug_assert_eq!(c.shape(), (rows, b.ncols()));
    for j in 0..b.ncols() {
        let cj = col_mut(c, j);
        if beta == 0.0 {
            cj.fill(0.0);
        } else if beta != 1.0 {
            cj.iter_mut().for_each(|v| *v *= beta);
        }
        for l in 0..a.ncols() {
            let s = alpha * b[(l, j)];
            if s != 0.0 {
                for (x, y) in cj.iter_mut().zip(col(a, l)) {
                    *x += s * y;
                }
            }
        }
    }
}

/// Column `j` of a column-major B-row matrix as a slice.
#[inline(always)]
fn col(m: &DMatrix<f64>, j: usize) -> &[f64] {
    let b = m.nrows();
    &m.as_slice()[j * b..(j + 1) * b]
}

#[inline(always)]
fn col_mut(m: &mut DMatrix<f64>, j: usize) -> &mut [f64] {
    let b = m.nrows();
    &mut m.as_mut_slice()[j * b..(j + 1) * b]
}

/// [`chunk`] compiled for AVX2 where the CPU has it (checked at run time), else for the
/// baseline. The arithmetic is the same element by element (Rust never fuses a multiply and
/// an add on its own, and every reduction has a fixed order), so results are identical;
/// only the vector width changes.
fn chunk_dispatch(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        unsafe { chunk_avx2(job, range, acc) };
        return;
    }
    chunk(job, range, acc);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn chunk_avx2(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    chunk(job, range, acc);
}

/// What every chunk of one evaluation shares.
struct Job<'a> {
    truth: &'a LinearGaussianModel,
    f: &'a KalmanFilter,
    /// The truth-to-filter map, transposed (n_t × n_f), to multiply run rows from the right.
    map_t: Option<&'a DMatrix<f64>>,
    sched: &'a Schedule,
    mc: &'a McConfig,
}

/// The largest magnitude in `v` as a bit pattern: the bits of `|x|` order as the numbers do
/// and a NaN's lie above infinity's, so one integer maximum (which vectorizes) finds both.
#[inline(always)]
fn max_abs_bits(acc: i64, v: f64) -> i64 {
    acc.max(v.to_bits() as i64 & i64::MAX)
}

/// `|x|` from [`max_abs_bits`].
#[inline(always)]
fn from_abs_bits(b: i64) -> f64 {
    f64::from_bits(b as u64)
}

/// Per-row `Σ_j mat[r, j]²` into `sq`, and its total.
#[inline(always)]
fn row_norms(sq: &mut [f64], mat: &DMatrix<f64>) -> f64 {
    sq.fill(0.0);
    for j in 0..mat.ncols() {
        for (s, v) in sq.iter_mut().zip(col(mat, j)) {
            *s += v * v;
        }
    }
    sq.iter().sum::<f64>()
}

/// Zero row `r` of each matrix.
fn zero_row(r: usize, mats: &mut [&mut DMatrix<f64>]) {
    for m in mats.iter_mut() {
        m.row_mut(r).fill(0.0);
    }
}

/// Runs `range` as the rows of B × n matrices (one row per run), so every product is a few
/// vector operations of length B. A run that faults ([`Fault`]) is recorded as diverged at
/// that step and its rows are zeroed from then on (its error and innovation contribute
/// nothing; the counts are of the live runs), so the sums equal the generic path's.
#[inline(always)]
fn chunk(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    let Job {
        truth,
        f,
        map_t,
        sched,
        mc,
    } = *job;
    let n = f.n_x();
    let nt = truth.F.nrows();
    let m = f.H.nrows();
    let b = range.len();
    let lags = mc.lags();
    let lq_t = truth.factors.q.transpose();
    let lr_t = truth.factors.r.transpose();
    let (rq, rr) = (lq_t.nrows(), lr_t.nrows());
    let ft_t = truth.F.transpose();
    let ht_t = truth.H.transpose();
    let ff_t = f.F.transpose();
    let hf_t = f.H.transpose();

    let mut rngs: Vec<_> = range.clone().map(|i| run_rng(mc.seed(), i)).collect();
    let mut xt = DMatrix::zeros(b, nt);
    for (c, rng) in rngs.iter_mut().enumerate() {
        xt.set_row(
            c,
            &sample_gaussian(&truth.x0, &truth.factors.p0, rng).transpose(),
        );
    }
    let mut xh = DMatrix::from_fn(b, n, |_, j| f.x0[j]);
    let mut tmp_t = DMatrix::zeros(b, nt);
    let mut tmp = DMatrix::zeros(b, n);
    // The truth in the filter's state, when it has its own.
    let mut mx = DMatrix::zeros(if map_t.is_some() { b } else { 0 }, n);
    let mut wq = DMatrix::zeros(b, rq);
    let mut wr = DMatrix::zeros(b, rr);
    let mut z = DMatrix::zeros(b, m);
    let mut nu = DMatrix::zeros(b, m);
    let mut e = DMatrix::zeros(b, n);
    let mut we = DMatrix::zeros(b, n);
    let mut vn = DMatrix::zeros(b, m);
    let (mut sq_x, mut sq_z) = (vec![0.0; b], vec![0.0; b]);
    // Each run's NEES sum over its steps.
    let mut run_nees = vec![0.0; b];
    // Per-run sums of e_j²/P_jj and u_j², and the last `lags` normalized innovations.
    let mut run_x = DMatrix::<f64>::zeros(b, n);
    // Per-run sums of e_j/√P_jj.
    let mut run_mx = DMatrix::<f64>::zeros(b, n);
    let mut run_z = DMatrix::<f64>::zeros(b, m);
    let mut u = DMatrix::<f64>::zeros(b, m);
    let mut ring: Vec<DMatrix<f64>> = (0..lags).map(|_| DMatrix::zeros(b, m)).collect();
    let mut ring_sq = vec![0.0; lags * m];
    // Runs stopped by a fault, and (run, step, fault) in the order found.
    let mut dead = vec![false; b];
    let mut faults: Vec<(usize, usize, Fault)> = Vec::new();

    for k in 1..=mc.steps() {
        let i = k - 1;
        let si = sched.at(i);
        // Per run: process noise first, then measurement noise, as the generic path does.
        for (c, rng) in rngs.iter_mut().enumerate() {
            for r in 0..rq {
                wq[(c, r)] = rng.sample(StandardNormal);
            }
            for r in 0..rr {
                wr[(c, r)] = rng.sample(StandardNormal);
            }
        }
        gemm_rows(&mut tmp_t, 1.0, &xt, &ft_t, 0.0);
        gemm_rows(&mut tmp_t, 1.0, &wq, &lq_t, 1.0);
        std::mem::swap(&mut xt, &mut tmp_t);
        gemm_rows(&mut z, 1.0, &xt, &ht_t, 0.0);
        gemm_rows(&mut z, 1.0, &wr, &lr_t, 1.0);

        gemm_rows(&mut tmp, 1.0, &xh, &ff_t, 0.0);
        std::mem::swap(&mut xh, &mut tmp);
        nu.copy_from(&z);
        gemm_rows(&mut nu, -1.0, &xh, &hf_t, 1.0);
        gemm_rows(&mut xh, 1.0, &nu, &sched.Kt[si], 1.0);
        let pinv = &sched.p_inv_diag[si];
        // e = (map ·) x_true − x̂, noting the largest magnitude of the estimate. A truth that
        // overflows needs no screen of its own: it makes e, and so the NEES, non-finite.
        let truth_f = match map_t {
            Some(mt) => {
                gemm_rows(&mut mx, 1.0, &xt, mt, 0.0);
                &mx
            }
            None => &xt,
        };
        let mut suspect = false;
        for j in 0..n {
            let mut hb = 0;
            let (tj, hj) = (col(truth_f, j), col(&xh, j));
            for ((ev, t), h) in col_mut(&mut e, j).iter_mut().zip(tj).zip(hj) {
                *ev = t - h;
                hb = max_abs_bits(hb, *h);
            }
            let h = from_abs_bits(hb);
            // A NaN (an overflowed estimate) is suspect too.
            let r = h * h * pinv[j];
            suspect |= r > MAX_RATIO_SQ || r.is_nan();
        }
        // Truth states the map leaves out can overflow unseen by e.
        suspect |= map_t.is_some() && xt.iter().any(|v| !v.is_finite());
        for r in (0..b).filter(|&r| dead[r]) {
            zero_row(r, &mut [&mut e, &mut nu]);
        }
        gemm_rows(&mut we, 1.0, &e, &sched.Wt[si], 0.0);
        gemm_rows(&mut vn, 1.0, &nu, &sched.Vt[si], 0.0);
        // NEES and NIS per run are row norms.
        let mut tot_x = row_norms(&mut sq_x, &we);
        let mut tot_z = row_norms(&mut sq_z, &vn);
        if suspect || !tot_x.is_finite() || !tot_z.is_finite() {
            for r in 0..b {
                let fault = if dead[r] {
                    None
                } else if xt.row(r).iter().any(|v| !v.is_finite()) {
                    Some(Fault::TruthOverflow)
                } else if let Some(f) = Fault::resolution(n, |j| {
                    xh[(r, j)].powi(2) / (1.0 / pinv[j]).max(e[(r, j)].powi(2))
                }) {
                    Some(f)
                } else if !sq_x[r].is_finite() || !sq_z[r].is_finite() {
                    Some(Fault::Overflow)
                } else {
                    None
                };
                if let Some(fault) = fault {
                    dead[r] = true;
                    faults.push((range.start + r, k, fault));
                }
                if dead[r] {
                    // Restart the stopped run's rows from zero so that they stay finite.
                    zero_row(r, &mut [&mut e, &mut nu, &mut xt, &mut xh]);
                }
            }
            gemm_rows(&mut we, 1.0, &e, &sched.Wt[si], 0.0);
            gemm_rows(&mut vn, 1.0, &nu, &sched.Vt[si], 0.0);
            tot_x = row_norms(&mut sq_x, &we);
            tot_z = row_norms(&mut sq_z, &vn);
        }
        let live = dead.iter().filter(|d| !**d).count();
        acc.nees_sum[i] += tot_x;
        acc.nees_sq[i] += dot(&sq_x, &sq_x);
        acc.nis_sum[i] += tot_z;
        acc.nis_sq[i] += dot(&sq_z, &sq_z);
        for (r, s) in run_nees.iter_mut().zip(&sq_x) {
            *r += s;
        }
        acc.nees_dof[i] += (n * live) as f64;
        acc.nees_count[i] += live as f64;
        acc.nis_dof[i] += (m * live) as f64;
        acc.nis_count[i] += live as f64;

        let pis = &sched.p_inv_sqrt_diag[si];
        for j in 0..n {
            let ej = col(&e, j);
            acc.state_comp_total[j] += dot(ej, ej) * pinv[j];
            acc.state_comp_samples[j] += live as f64;
            acc.state_mean_samples[j] += live as f64;
            for (r, v) in col_mut(&mut run_x, j).iter_mut().zip(ej) {
                *r += v * v * pinv[j];
            }
            // Stopped runs' rows are zero, so they add nothing.
            let mut sum = 0.0;
            for (r, v) in col_mut(&mut run_mx, j).iter_mut().zip(ej) {
                let y = v * pis[j];
                *r += y;
                sum += y;
            }
            acc.state_mean_total[j] += sum;
        }
        let srt = &sched.s_inv_sqrt_diag[si];
        let slot = if lags > 0 { k % lags } else { 0 };
        for j in 0..m {
            for (uv, nv) in col_mut(&mut u, j).iter_mut().zip(col(&nu, j)) {
                *uv = nv * srt[j];
            }
            let uj = col(&u, j);
            let total = dot(uj, uj);
            acc.meas_mean_total[j] += uj.iter().sum::<f64>();
            for (r, v) in col_mut(&mut run_z, j).iter_mut().zip(uj) {
                *r += v * v;
            }
            acc.meas_comp_total[j] += total;
            acc.meas_comp_samples[j] += live as f64;
            for lag in 1..=lags.min(k - 1) {
                let prev = (k - lag) % lags;
                let o = (lag - 1) * m + j;
                acc.white_ab[o] += dot(uj, col(&ring[prev], j));
                acc.white_a2[o] += total;
                acc.white_b2[o] += ring_sq[prev * m + j];
                acc.white_pairs[o] += live as f64;
            }
            if lags > 0 {
                ring_sq[slot * m + j] = total;
            }
        }
        if lags > 0 {
            ring[slot].copy_from(&u);
        }
    }
    let t = mc.steps() as f64;
    let live = dead.iter().filter(|d| !**d).count();
    for (j, col) in run_x.column_iter().enumerate() {
        for (v, _) in col.iter().zip(&dead).filter(|(_, d)| !**d) {
            acc.add_run_component(true, j, v / t);
        }
    }
    for (j, col) in run_mx.column_iter().enumerate() {
        for (v, _) in col.iter().zip(&dead).filter(|(_, d)| !**d) {
            acc.state_mean_run_sq[j] += v * v;
        }
    }
    for (j, col) in run_z.column_iter().enumerate() {
        for (v, _) in col.iter().zip(&dead).filter(|(_, d)| !**d) {
            acc.add_run_component(false, j, v / t);
        }
        acc.meas_comp_runs[j] += live;
    }
    for (&total, _) in run_nees.iter().zip(&dead).filter(|(_, d)| !**d) {
        acc.add_run_nees_total(total);
    }
    // In run order, as the generic path records them.
    faults.sort_by_key(|&(run, ..)| run);
    for (run, step, fault) in faults {
        acc.record_stop(run, step, fault.cause(), fault.reason(step));
    }
    acc.runs += b;
    acc.nees_null_var += sched.null_var * live as f64;
    acc.null_var_runs += live;
    if !sched.comp_null_var.is_empty() {
        for (s, v) in acc.state_comp_null_var.iter_mut().zip(&sched.comp_null_var) {
            *s += v * live as f64;
        }
        for (s, v) in acc.state_mean_null_var.iter_mut().zip(&sched.mean_null_var) {
            *s += v * live as f64;
        }
        acc.comp_null_var_runs += live;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::dwna_block;

    #[test]
    fn avx2_build_gives_the_same_sums_as_the_baseline() {
        let F = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
        let H = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
        let truth = LinearGaussianModel::new(
            F.clone(),
            H.clone(),
            dwna_block(1.0) * 0.5,
            DMatrix::from_element(1, 1, 1.0),
            DVector::from_column_slice(&[0.0, 1.0]),
            DMatrix::from_diagonal(&DVector::from_column_slice(&[4.0, 1.0])),
        )
        .unwrap();
        let kf = KalmanFilter {
            F,
            H,
            Q: dwna_block(1.0) * 0.2,
            R: DMatrix::from_element(1, 1, 2.0),
            x0: truth.x0.clone(),
            P0: truth.P0.clone(),
        };
        let mc = McConfig::new(100, 50)
            .unwrap()
            .with_seed(7)
            .with_lags(3)
            .unwrap();
        let sched = Schedule::compute(&kf, mc.steps(), true).unwrap();
        let mut base = Accumulator::new(50, 2, 1, 3);
        let job = Job {
            truth: &truth,
            f: &kf,
            map_t: None,
            sched: &sched,
            mc: &mc,
        };
        chunk(&job, 0..100, &mut base);
        let mut fast = Accumulator::new(50, 2, 1, 3);
        chunk_dispatch(&job, 0..100, &mut fast);
        assert_eq!(base, fast);
        assert!(base.nees_sum.iter().all(|v| *v > 0.0));
    }
}
