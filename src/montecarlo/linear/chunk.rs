//! One chunk of the linear fast path's runs, as the rows of B × n matrices.

#![allow(non_snake_case)]

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::kernels::{
    col, col_mut, dot, from_abs_bits, gemm_rows, max_abs_bits, row_norms, zero_row,
};
use super::schedule::Schedule;
use crate::filter::{Filter, KalmanFilter};
use crate::model::{LinearGaussianModel, sample_gaussian};
use crate::montecarlo::generic::{Fault, MAX_RATIO_SQ};
use crate::montecarlo::{McConfig, run_rng};
use crate::stats::Accumulator;

/// What every chunk of one evaluation shares.
pub(super) struct Job<'a> {
    pub(super) truth: &'a LinearGaussianModel,
    pub(super) f: &'a KalmanFilter,
    /// The truth-to-filter map, transposed (n_t × n_f), to multiply run rows from the right.
    pub(super) map_t: Option<&'a DMatrix<f64>>,
    pub(super) sched: &'a Schedule,
    pub(super) mc: &'a McConfig,
}

/// Runs `range` as the rows of B × n matrices (one row per run), so every product is a few
/// vector operations of length B. A run that faults ([`Fault`]) is recorded as diverged at
/// that step and its rows are zeroed from then on (its error and innovation contribute
/// nothing; the counts are of the live runs), so the sums equal the generic path's.
///
/// Every stage is `#[inline(always)]`, so that the whole step loop is compiled as one body
/// for the AVX2 build of [`run_chunk_dispatch`].
#[inline(always)]
pub(super) fn run_chunk(job: &Job<'_>, range: Range<usize>, acc: &mut Accumulator) {
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
