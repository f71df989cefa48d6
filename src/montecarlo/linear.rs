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
use super::{McConfig, RunOptions, run_chunked, run_rng};
use crate::filter::conditioning::check_conditioned;
use crate::filter::{Filter, FilterError, KalmanFilter};
use crate::linalg::{cholesky, inverse_cholesky_factor, spd_inverse};
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
pub(super) const STEADY_RTOL: f64 = 1e-14;

/// Unchanged steps in a row after which the recursion is in steady state.
pub(super) const STEADY_STEPS: usize = 3;

/// Whether every entry of `a` equals `b`'s to [`STEADY_RTOL`] relative to the geometric
/// mean of the two diagonal entries it couples (a unit-free test).
pub(super) fn same_covariance(a: &DMatrix<f64>, b: &DMatrix<f64>) -> bool {
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

    /// The schedule of `f` over `steps` steps, the NEES and the state components taken on
    /// its first `judged` states (all n but for a filter with states the truth lacks).
    fn compute(
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

/// Run the Monte Carlo test of a linear Kalman filter against a linear-Gaussian truth.
///
/// Gives the same statistics as [`super::run_generic`] on the same pair (to rounding: the
/// random draws are the same, the arithmetic is reordered), several times faster.
pub fn run_linear(
    truth: &LinearGaussianModel,
    filter: &KalmanFilter,
    mc: &McConfig,
) -> Accumulator {
    run_linear_with(truth, filter, None, mc, RunOptions::default())
}

/// [`run_linear`] for a filter whose state is `map · x_true` (n_f × n_t; `None`: the
/// truth's state), the NEES taken on `map · x_true − x̂`, with options: progress after each
/// parallel wave, and a share of the chunks (the engine path in the options is not read).
/// A run whose numbers stop meaning anything (the truth overflows, the
/// state outgrows double precision, the NEES or NIS overflows) stops there as a divergence,
/// as on the generic path.
pub fn run_linear_with(
    truth: &LinearGaussianModel,
    filter: &KalmanFilter,
    map: Option<&DMatrix<f64>>,
    mc: &McConfig,
    options: RunOptions<'_>,
) -> Accumulator {
    // A map with fewer rows than the filter has states judges its first ones only.
    let n = map.map_or(filter.n_x(), |m| m.nrows());
    let m = filter.H.nrows();
    let map_t = map.map(|m| m.transpose());
    match Schedule::compute(filter, mc.steps(), mc.gate() == GateMode::Full, n) {
        Ok(sched) => run_chunked(mc, n, m, options, |range, acc| {
            let job = Job {
                truth,
                f: filter,
                map_t: map_t.as_ref(),
                sched: &sched,
                mc,
            };
            run_chunk_dispatch(&job, range, acc)
        }),
        // The covariance recursion is the same in every run, so every run stops at the same
        // step.
        Err(e) => super::all_stopped_with(mc, n, m, &e, options),
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

/// [`run_chunk`] compiled for AVX2 where the CPU has it (checked at run time), else for the
/// baseline. The arithmetic is the same element by element (Rust never fuses a multiply and
/// an add on its own, and every reduction has a fixed order), so results are identical;
/// only the vector width changes.
fn run_chunk_dispatch(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        unsafe { run_chunk_avx2(job, range, acc) };
        return;
    }
    run_chunk(job, range, acc);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_chunk_avx2(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    run_chunk(job, range, acc);
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
///
/// Every stage is `#[inline(always)]`, so that the whole step loop is compiled as one body
/// for the AVX2 build of [`run_chunk_dispatch`].
#[inline(always)]
fn run_chunk(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
    let mut c = Chunk::new(job, range);
    for k in 1..=job.mc.steps() {
        let si = job.sched.at(k - 1);
        c.simulate_and_filter(job, si);
        let suspect = c.estimation_errors(job, si);
        let (tot_x, tot_z) = c.normalize(job, si, k, suspect);
        c.add_step_sums(job, acc, k, tot_x, tot_z);
        c.add_state_component_sums(job, acc, si);
        c.add_measurement_component_sums(job, acc, si, k);
    }
    c.finish(job, acc);
}

/// The model's matrices transposed, to multiply run rows from the right.
struct Transposed {
    /// Truth: process and measurement noise factors, transition, measurement.
    lq: DMatrix<f64>,
    lr: DMatrix<f64>,
    ft: DMatrix<f64>,
    ht: DMatrix<f64>,
    /// Filter: transition, measurement.
    ff: DMatrix<f64>,
    hf: DMatrix<f64>,
}

/// One chunk's runs as matrix rows: their streams, truth and estimate, this step's
/// quantities, and the per-run sums kept until the runs end.
struct Chunk {
    first_run: usize,
    t: Transposed,
    rngs: Vec<crate::rng::SimRng>,
    /// True state (B × n_t) and estimate (B × n).
    xt: DMatrix<f64>,
    xh: DMatrix<f64>,
    tmp_t: DMatrix<f64>,
    tmp: DMatrix<f64>,
    /// The truth in the filter's state, when it has its own.
    mx: DMatrix<f64>,
    /// This step's standard normal draws for process and measurement noise.
    wq: DMatrix<f64>,
    wr: DMatrix<f64>,
    z: DMatrix<f64>,
    nu: DMatrix<f64>,
    e: DMatrix<f64>,
    /// `e' (L_P⁻¹)'` and `ν' (L_S⁻¹)'`: NEES and NIS are their row norms.
    we: DMatrix<f64>,
    vn: DMatrix<f64>,
    sq_x: Vec<f64>,
    sq_z: Vec<f64>,
    /// Each run's NEES sum over its steps.
    run_nees: Vec<f64>,
    /// Per-run sums of e_j²/P_jj.
    run_x: DMatrix<f64>,
    /// Per-run sums of e_j/√P_jj.
    run_mx: DMatrix<f64>,
    /// Per-run sums of u_j².
    run_z: DMatrix<f64>,
    /// Each run's own sum of `ν_j/√S_jj` (runs × n_z), for the run-to-run spread of the
    /// innovations' first moment.
    run_mz: DMatrix<f64>,
    /// This step's normalized innovations, and the last `lags` steps' with their squares.
    u: DMatrix<f64>,
    ring: Vec<DMatrix<f64>>,
    ring_sq: Vec<f64>,
    /// Runs stopped by a fault, and (run, step, fault) in the order found.
    dead: Vec<bool>,
    faults: Vec<(usize, usize, Fault)>,
    /// Runs not stopped.
    live: usize,
}

impl Chunk {
    /// The runs of `range` at their initial states.
    #[inline(always)]
    fn new(job: &Job<'_>, range: Range<usize>) -> Chunk {
        let (truth, f, mc) = (job.truth, job.f, job.mc);
        let (n, nt, m, b) = (f.n_x(), truth.F.nrows(), f.H.nrows(), range.len());
        // The judged states: the map's rows, or all of them.
        let ne = job.map_t.map_or(n, |mt| mt.ncols());
        let lags = mc.lags();
        let t = Transposed {
            lq: truth.factors.q.transpose(),
            lr: truth.factors.r.transpose(),
            ft: truth.F.transpose(),
            ht: truth.H.transpose(),
            ff: f.F.transpose(),
            hf: f.H.transpose(),
        };
        let (rq, rr) = (t.lq.nrows(), t.lr.nrows());
        let mut rngs: Vec<_> = range.clone().map(|i| run_rng(mc.seed(), i)).collect();
        let mut xt = DMatrix::zeros(b, nt);
        for (c, rng) in rngs.iter_mut().enumerate() {
            xt.set_row(
                c,
                &sample_gaussian(&truth.x0, &truth.factors.p0, rng).transpose(),
            );
        }
        Chunk {
            first_run: range.start,
            t,
            rngs,
            xt,
            xh: DMatrix::from_fn(b, n, |_, j| f.x0[j]),
            tmp_t: DMatrix::zeros(b, nt),
            tmp: DMatrix::zeros(b, n),
            mx: DMatrix::zeros(if job.map_t.is_some() { b } else { 0 }, ne),
            wq: DMatrix::zeros(b, rq),
            wr: DMatrix::zeros(b, rr),
            z: DMatrix::zeros(b, m),
            nu: DMatrix::zeros(b, m),
            e: DMatrix::zeros(b, ne),
            we: DMatrix::zeros(b, ne),
            vn: DMatrix::zeros(b, m),
            sq_x: vec![0.0; b],
            sq_z: vec![0.0; b],
            run_nees: vec![0.0; b],
            run_x: DMatrix::zeros(b, ne),
            run_mx: DMatrix::zeros(b, ne),
            run_z: DMatrix::zeros(b, m),
            run_mz: DMatrix::zeros(b, m),
            u: DMatrix::zeros(b, m),
            ring: (0..lags).map(|_| DMatrix::zeros(b, m)).collect(),
            ring_sq: vec![0.0; lags * m],
            dead: vec![false; b],
            faults: Vec::new(),
            live: b,
        }
    }

    /// One step of every run: the truth moves and is measured, and the filter predicts and
    /// updates with the step's gain (schedule index `si`).
    #[inline(always)]
    fn simulate_and_filter(&mut self, job: &Job<'_>, si: usize) {
        let t = &self.t;
        let (rq, rr) = (t.lq.nrows(), t.lr.nrows());
        // Per run: process noise first, then measurement noise, as the generic path does.
        for (c, rng) in self.rngs.iter_mut().enumerate() {
            for r in 0..rq {
                self.wq[(c, r)] = rng.sample(StandardNormal);
            }
            for r in 0..rr {
                self.wr[(c, r)] = rng.sample(StandardNormal);
            }
        }
        gemm_rows(&mut self.tmp_t, 1.0, &self.xt, &t.ft, 0.0);
        gemm_rows(&mut self.tmp_t, 1.0, &self.wq, &t.lq, 1.0);
        std::mem::swap(&mut self.xt, &mut self.tmp_t);
        gemm_rows(&mut self.z, 1.0, &self.xt, &t.ht, 0.0);
        gemm_rows(&mut self.z, 1.0, &self.wr, &t.lr, 1.0);

        gemm_rows(&mut self.tmp, 1.0, &self.xh, &t.ff, 0.0);
        std::mem::swap(&mut self.xh, &mut self.tmp);
        self.nu.copy_from(&self.z);
        gemm_rows(&mut self.nu, -1.0, &self.xh, &t.hf, 1.0);
        gemm_rows(&mut self.xh, 1.0, &self.nu, &job.sched.Kt[si], 1.0);
    }

    /// e = (map ·) x_true − x̂; whether some run may have faulted: an estimate too large for
    /// its covariance to resolve, or a truth state that overflowed.
    #[inline(always)]
    fn estimation_errors(&mut self, job: &Job<'_>, si: usize) -> bool {
        let pinv = &job.sched.p_inv_diag[si];
        // A truth that overflows needs no screen of its own: it makes e, and so the NEES,
        // non-finite.
        let truth_f = match job.map_t {
            Some(mt) => {
                gemm_rows(&mut self.mx, 1.0, &self.xt, mt, 0.0);
                &self.mx
            }
            None => &self.xt,
        };
        let mut suspect = false;
        for j in 0..self.e.ncols() {
            let mut hb = 0;
            let (tj, hj) = (col(truth_f, j), col(&self.xh, j));
            for ((ev, t), h) in col_mut(&mut self.e, j).iter_mut().zip(tj).zip(hj) {
                *ev = t - h;
                hb = max_abs_bits(hb, *h);
            }
            let h = from_abs_bits(hb);
            // A NaN (an overflowed estimate) is suspect too.
            let r = h * h * pinv[j];
            suspect |= r > MAX_RATIO_SQ || r.is_nan();
        }
        // Truth states the map leaves out can overflow unseen by e.
        suspect |= job.map_t.is_some() && self.xt.iter().any(|v| !v.is_finite());
        suspect
    }

    /// The whitened error and innovation, and the totals of their squares over the live
    /// runs; when a run may have faulted, it is found, stopped and its rows zeroed first.
    #[inline(always)]
    fn normalize(&mut self, job: &Job<'_>, si: usize, k: usize, suspect: bool) -> (f64, f64) {
        for r in (0..self.dead.len()).filter(|&r| self.dead[r]) {
            zero_row(r, &mut [&mut self.e, &mut self.nu]);
        }
        let sched = job.sched;
        gemm_rows(&mut self.we, 1.0, &self.e, &sched.Wt[si], 0.0);
        gemm_rows(&mut self.vn, 1.0, &self.nu, &sched.Vt[si], 0.0);
        // NEES and NIS per run are row norms.
        let tot_x = row_norms(&mut self.sq_x, &self.we);
        let tot_z = row_norms(&mut self.sq_z, &self.vn);
        if !suspect && tot_x.is_finite() && tot_z.is_finite() {
            return (tot_x, tot_z);
        }
        self.stop_faulted(&sched.p_inv_diag[si], k);
        gemm_rows(&mut self.we, 1.0, &self.e, &sched.Wt[si], 0.0);
        gemm_rows(&mut self.vn, 1.0, &self.nu, &sched.Vt[si], 0.0);
        (
            row_norms(&mut self.sq_x, &self.we),
            row_norms(&mut self.sq_z, &self.vn),
        )
    }

    /// Stop each live run whose numbers at step `k` have stopped meaning anything, and
    /// restart every stopped run's rows from zero so that they stay finite.
    #[cold]
    fn stop_faulted(&mut self, pinv: &DVector<f64>, k: usize) {
        let n = self.e.ncols();
        for r in 0..self.dead.len() {
            let fault = if self.dead[r] {
                None
            } else if self.xt.row(r).iter().any(|v| !v.is_finite()) {
                Some(Fault::TruthOverflow)
            } else if let Some(f) = Fault::resolution(n, |j| {
                self.xh[(r, j)].powi(2) / (1.0 / pinv[j]).max(self.e[(r, j)].powi(2))
            }) {
                Some(f)
            } else if !self.sq_x[r].is_finite() || !self.sq_z[r].is_finite() {
                Some(Fault::Overflow)
            } else {
                None
            };
            if let Some(fault) = fault {
                self.dead[r] = true;
                self.live -= 1;
                self.faults.push((self.first_run + r, k, fault));
            }
            if self.dead[r] {
                zero_row(
                    r,
                    &mut [&mut self.e, &mut self.nu, &mut self.xt, &mut self.xh],
                );
            }
        }
    }

    /// The step's NEES and NIS sums (totals `tot_x`, `tot_z`) and counts.
    #[inline(always)]
    fn add_step_sums(
        &mut self,
        job: &Job<'_>,
        acc: &mut Accumulator,
        k: usize,
        tot_x: f64,
        tot_z: f64,
    ) {
        let i = k - 1;
        let (n, m, live) = (self.e.ncols(), job.f.H.nrows(), self.live);
        acc.nees_sum[i] += tot_x;
        acc.nees_sq[i] += dot(&self.sq_x, &self.sq_x);
        acc.nis_sum[i] += tot_z;
        acc.nis_sq[i] += dot(&self.sq_z, &self.sq_z);
        for (r, s) in self.run_nees.iter_mut().zip(&self.sq_x) {
            *r += s;
        }
        acc.nees_dof[i] += (n * live) as f64;
        acc.nees_count[i] += live as f64;
        acc.nis_dof[i] += (m * live) as f64;
        acc.nis_count[i] += live as f64;
    }

    /// Per state component: the step's `e_j²/P_jj` and `e_j/√P_jj` sums, and each run's.
    #[inline(always)]
    fn add_state_component_sums(&mut self, job: &Job<'_>, acc: &mut Accumulator, si: usize) {
        let (pinv, pis) = (&job.sched.p_inv_diag[si], &job.sched.p_inv_sqrt_diag[si]);
        let live = self.live as f64;
        for j in 0..self.e.ncols() {
            let ej = col(&self.e, j);
            acc.state_comp_total[j] += dot(ej, ej) * pinv[j];
            acc.state_comp_samples[j] += live;
            acc.state_mean_samples[j] += live;
            for (r, v) in col_mut(&mut self.run_x, j).iter_mut().zip(ej) {
                *r += v * v * pinv[j];
            }
            // Stopped runs' rows are zero, so they add nothing.
            let mut sum = 0.0;
            for (r, v) in col_mut(&mut self.run_mx, j).iter_mut().zip(ej) {
                let y = v * pis[j];
                *r += y;
                sum += y;
            }
            acc.state_mean_total[j] += sum;
        }
    }

    /// Per measurement component: the normalized innovations' sums, each run's sum of
    /// squares, and their products with the last `lags` steps' (whiteness).
    #[inline(always)]
    fn add_measurement_component_sums(
        &mut self,
        job: &Job<'_>,
        acc: &mut Accumulator,
        si: usize,
        k: usize,
    ) {
        let srt = &job.sched.s_inv_sqrt_diag[si];
        let (m, lags, live) = (self.u.ncols(), job.mc.lags(), self.live as f64);
        let slot = if lags > 0 { k % lags } else { 0 };
        for j in 0..m {
            for (uv, nv) in col_mut(&mut self.u, j).iter_mut().zip(col(&self.nu, j)) {
                *uv = nv * srt[j];
            }
            let uj = col(&self.u, j);
            let total = dot(uj, uj);
            acc.meas_mean_total[j] += uj.iter().sum::<f64>();
            for (r, v) in col_mut(&mut self.run_z, j).iter_mut().zip(uj) {
                *r += v * v;
            }
            for (r, v) in col_mut(&mut self.run_mz, j).iter_mut().zip(uj) {
                *r += v;
            }
            acc.meas_comp_total[j] += total;
            acc.meas_comp_samples[j] += live;
            for lag in 1..=lags.min(k - 1) {
                let prev = (k - lag) % lags;
                let o = (lag - 1) * m + j;
                acc.white_ab[o] += dot(uj, col(&self.ring[prev], j));
                acc.white_a2[o] += total;
                acc.white_b2[o] += self.ring_sq[prev * m + j];
                acc.white_pairs[o] += live;
            }
            if lags > 0 {
                self.ring_sq[slot * m + j] = total;
            }
        }
        if lags > 0 {
            self.ring[slot].copy_from(&self.u);
        }
    }

    /// The live runs' own sums, the faults in run order, and the runs' share of the null
    /// variances.
    fn finish(mut self, job: &Job<'_>, acc: &mut Accumulator) {
        let t = job.mc.steps() as f64;
        let (dead, live) = (&self.dead, self.live);
        for (j, col) in self.run_x.column_iter().enumerate() {
            for (v, _) in col.iter().zip(dead).filter(|(_, d)| !**d) {
                acc.add_run_component(true, j, v / t);
            }
        }
        for (j, col) in self.run_mx.column_iter().enumerate() {
            for (v, _) in col.iter().zip(dead).filter(|(_, d)| !**d) {
                acc.state_mean_run_sq[j] += v * v;
            }
        }
        for (j, col) in self.run_mz.column_iter().enumerate() {
            for (v, _) in col.iter().zip(dead).filter(|(_, d)| !**d) {
                acc.meas_mean_run_sq[j] += v * v;
            }
        }
        for (j, col) in self.run_z.column_iter().enumerate() {
            for (v, _) in col.iter().zip(dead).filter(|(_, d)| !**d) {
                acc.add_run_component(false, j, v / t);
            }
            acc.meas_comp_runs[j] += live;
        }
        for (&total, _) in self.run_nees.iter().zip(dead).filter(|(_, d)| !**d) {
            acc.add_run_nees_total(total);
        }
        // In run order, as the generic path records them.
        self.faults.sort_by_key(|&(run, ..)| run);
        for (run, step, fault) in self.faults {
            acc.record_stop(run, step, fault.cause(), fault.reason(step));
        }
        let sched = job.sched;
        acc.runs += self.dead.len();
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
        let sched = Schedule::compute(&kf, mc.steps(), true, kf.n_x()).unwrap();
        let mut base = Accumulator::new(50, 2, 1, 3);
        let job = Job {
            truth: &truth,
            f: &kf,
            map_t: None,
            sched: &sched,
            mc: &mc,
        };
        run_chunk(&job, 0..100, &mut base);
        let mut fast = Accumulator::new(50, 2, 1, 3);
        run_chunk_dispatch(&job, 0..100, &mut fast);
        assert_eq!(base, fast);
        assert!(base.nees_sum.iter().all(|v| *v > 0.0));
    }
}
