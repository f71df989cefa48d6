//! The Monte Carlo engine: N independent runs of truth simulation and filter, in parallel,
//! with streaming accumulation of everything the statistics need.
//!
//! Reproducibility: run `i` draws from its own stream seeded by `(seed, i)`; runs are
//! grouped into fixed chunks of [`CHUNK`] runs whatever the thread count, each chunk sums
//! its runs in order, and chunk sums are merged in chunk order. The result is therefore
//! bit-identical on any number of threads. Memory is O(T·(n + m)) per chunk in flight and
//! does not grow with N.

mod expected;
mod linear;

pub use expected::{expected_accumulator, models_match};
pub use linear::{run_linear, run_linear_with_progress};

use std::ops::Range;

use nalgebra::DVector;
use rand::SeedableRng;
use rayon::prelude::*;

use crate::SimRng;
use crate::filter::{Filter, FilterError, check_measurement};
use crate::linalg::cholesky;
use crate::model::{Measurement, TruthModel};
use crate::stats::{Divergence, NeesNullVariance};

/// Runs per chunk: the unit of parallel work and of summation order.
pub const CHUNK: usize = 64;

/// How many divergences are kept with their details.
const MAX_DIVERGENCES: usize = 10;

/// Monte Carlo settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Number of runs N (≥ 1).
    pub runs: usize,
    /// Steps per run T (≥ 1).
    pub steps: usize,
    /// Base seed; run i uses the stream derived from (seed, i).
    pub seed: u64,
    /// Largest lag of the innovation autocorrelation.
    pub lags: usize,
}

/// SplitMix64 finalizer: a bijective mix of 64 bits.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The random stream of run `run` under base seed `seed`.
pub fn run_rng(seed: u64, run: usize) -> SimRng {
    SimRng::seed_from_u64(splitmix64(seed ^ splitmix64(run as u64)))
}

/// Sufficient statistics of a Monte Carlo evaluation, summed over runs.
///
/// Per-step vectors have length T (index k − 1 for step k); component vectors have length
/// n_x or n_z (all sensors' components concatenated in sensor order); whiteness vectors
/// have length `lags · n_z`, lag-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Accumulator {
    /// Runs completed or diverged.
    pub runs: usize,
    /// Steps per run.
    pub steps: usize,
    /// Largest autocorrelation lag.
    pub lags: usize,
    /// Σ_i NEES_ik.
    pub nees_sum: Vec<f64>,
    /// Σ_i NEES_ik².
    pub nees_sq: Vec<f64>,
    /// Σ_i n_x (degrees of freedom of the step's NEES sum).
    pub nees_dof: Vec<f64>,
    /// Number of runs contributing a NEES at the step.
    pub nees_count: Vec<f64>,
    /// Σ over the runs counted in `null_var_runs` of the variance of the per-run NEES sum
    /// the filter predicts under consistency (see [`NeesNullVariance`]); read it through
    /// [`Accumulator::nees_null_variance`].
    pub nees_null_var: f64,
    /// Runs whose predicted NEES-sum variance is in `nees_null_var`: all of them on the
    /// linear and exact paths, every [`NULL_VAR_STRIDE`]-th on the generic one.
    pub null_var_runs: usize,
    /// Σ_i NIS_ik.
    pub nis_sum: Vec<f64>,
    /// Σ_i NIS_ik².
    pub nis_sq: Vec<f64>,
    /// Σ_i n_z,ik (the dimension of the measurement each run used at the step).
    pub nis_dof: Vec<f64>,
    /// Number of runs with a measurement at the step.
    pub nis_count: Vec<f64>,
    /// Σ_{i,k} e_j²/P_jj per state component.
    pub state_comp_total: Vec<f64>,
    /// Samples behind `state_comp_total`.
    pub state_comp_samples: Vec<f64>,
    /// Σ_i of the per-run time average of e_j²/P_jj.
    pub state_comp_run_sum: Vec<f64>,
    /// Σ_i of its square.
    pub state_comp_run_sq: Vec<f64>,
    /// Σ_{i,k} ν_j²/S_jj per measurement component.
    pub meas_comp_total: Vec<f64>,
    /// Samples behind `meas_comp_total`.
    pub meas_comp_samples: Vec<f64>,
    /// Σ_i of the per-run time average of ν_j²/S_jj.
    pub meas_comp_run_sum: Vec<f64>,
    /// Σ_i of its square.
    pub meas_comp_run_sq: Vec<f64>,
    /// Runs in which the component was measured at least once.
    pub meas_comp_runs: Vec<usize>,
    /// Σ u_k u_{k−l} with u = ν_j/√S_jj.
    pub white_ab: Vec<f64>,
    /// Σ u_k².
    pub white_a2: Vec<f64>,
    /// Σ u_{k−l}².
    pub white_b2: Vec<f64>,
    /// Number of pairs.
    pub white_pairs: Vec<f64>,
    /// Number of runs whose filter diverged.
    pub diverged_runs: usize,
    /// The first few divergences, by run index.
    pub divergences: Vec<Divergence>,
}

impl Accumulator {
    /// Zeroed sums for T steps, n_x states, n_z measurement components and `lags` lags.
    pub fn new(steps: usize, n_x: usize, n_z: usize, lags: usize) -> Self {
        let z = |len| vec![0.0; len];
        Accumulator {
            runs: 0,
            steps,
            lags,
            nees_sum: z(steps),
            nees_sq: z(steps),
            nees_dof: z(steps),
            nees_count: z(steps),
            nees_null_var: 0.0,
            null_var_runs: 0,
            nis_sum: z(steps),
            nis_sq: z(steps),
            nis_dof: z(steps),
            nis_count: z(steps),
            state_comp_total: z(n_x),
            state_comp_samples: z(n_x),
            state_comp_run_sum: z(n_x),
            state_comp_run_sq: z(n_x),
            meas_comp_total: z(n_z),
            meas_comp_samples: z(n_z),
            meas_comp_run_sum: z(n_z),
            meas_comp_run_sq: z(n_z),
            meas_comp_runs: vec![0; n_z],
            white_ab: z(lags * n_z),
            white_a2: z(lags * n_z),
            white_b2: z(lags * n_z),
            white_pairs: z(lags * n_z),
            diverged_runs: 0,
            divergences: Vec::new(),
        }
    }

    /// The variance of the NEES sum over all runs that the filters predict under
    /// consistency: the sampled runs' mean, times the runs that finished.
    pub fn nees_null_variance(&self) -> f64 {
        if self.null_var_runs == 0 {
            return 0.0;
        }
        let finished = self.runs.saturating_sub(self.diverged_runs);
        self.nees_null_var * finished as f64 / self.null_var_runs as f64
    }

    /// Add another accumulator's sums to this one.
    pub fn merge(&mut self, o: &Accumulator) {
        fn add(a: &mut [f64], b: &[f64]) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
        self.runs += o.runs;
        add(&mut self.nees_sum, &o.nees_sum);
        add(&mut self.nees_sq, &o.nees_sq);
        add(&mut self.nees_dof, &o.nees_dof);
        add(&mut self.nees_count, &o.nees_count);
        self.nees_null_var += o.nees_null_var;
        self.null_var_runs += o.null_var_runs;
        add(&mut self.nis_sum, &o.nis_sum);
        add(&mut self.nis_sq, &o.nis_sq);
        add(&mut self.nis_dof, &o.nis_dof);
        add(&mut self.nis_count, &o.nis_count);
        add(&mut self.state_comp_total, &o.state_comp_total);
        add(&mut self.state_comp_samples, &o.state_comp_samples);
        add(&mut self.state_comp_run_sum, &o.state_comp_run_sum);
        add(&mut self.state_comp_run_sq, &o.state_comp_run_sq);
        add(&mut self.meas_comp_total, &o.meas_comp_total);
        add(&mut self.meas_comp_samples, &o.meas_comp_samples);
        add(&mut self.meas_comp_run_sum, &o.meas_comp_run_sum);
        add(&mut self.meas_comp_run_sq, &o.meas_comp_run_sq);
        for (a, b) in self.meas_comp_runs.iter_mut().zip(&o.meas_comp_runs) {
            *a += b;
        }
        add(&mut self.white_ab, &o.white_ab);
        add(&mut self.white_a2, &o.white_a2);
        add(&mut self.white_b2, &o.white_b2);
        add(&mut self.white_pairs, &o.white_pairs);
        self.diverged_runs += o.diverged_runs;
        let room = MAX_DIVERGENCES.saturating_sub(self.divergences.len());
        self.divergences
            .extend(o.divergences.iter().take(room).cloned());
    }

    fn record_divergence(&mut self, run: usize, err: &FilterError) {
        self.diverged_runs += 1;
        if self.divergences.len() < MAX_DIVERGENCES {
            let step = match err {
                FilterError::NotPositiveDefinite { step, .. } => *step,
                FilterError::BadMeasurement { .. } | FilterError::Unsupported { .. } => 0,
            };
            self.divergences.push(Divergence {
                run,
                step,
                reason: err.to_string(),
            });
        }
    }
}

/// Per-run working state for the component and whiteness statistics.
struct RunScratch {
    n_x: usize,
    n_z: usize,
    lags: usize,
    comp_x: Vec<f64>,
    comp_x_n: f64,
    comp_z: Vec<f64>,
    comp_z_n: Vec<f64>,
    /// The last `lags` normalized innovation vectors (NaN where not measured), ring-indexed
    /// by step.
    ring: Vec<f64>,
    /// The current step's normalized innovations.
    u: Vec<f64>,
}

impl RunScratch {
    fn new(n_x: usize, n_z: usize, lags: usize) -> Self {
        RunScratch {
            n_x,
            n_z,
            lags,
            comp_x: vec![0.0; n_x],
            comp_x_n: 0.0,
            comp_z: vec![0.0; n_z],
            comp_z_n: vec![0.0; n_z],
            ring: vec![f64::NAN; lags.max(1) * n_z],
            u: vec![f64::NAN; n_z],
        }
    }

    fn reset(&mut self) {
        self.comp_x.fill(0.0);
        self.comp_x_n = 0.0;
        self.comp_z.fill(0.0);
        self.comp_z_n.fill(0.0);
        self.ring.fill(f64::NAN);
        self.u.fill(f64::NAN);
    }

    /// Record normalized state errors `e_j/√P_jj` for one step.
    fn state_step(&mut self, acc: &mut Accumulator, scaled_sq: impl Iterator<Item = f64>) {
        for (j, v) in scaled_sq.enumerate() {
            self.comp_x[j] += v;
            acc.state_comp_total[j] += v;
            acc.state_comp_samples[j] += 1.0;
        }
        self.comp_x_n += 1.0;
    }

    /// Record one normalized innovation component `u = ν_j/√S_jj` at the current step.
    fn innovation(&mut self, acc: &mut Accumulator, j: usize, u: f64) {
        let v = u * u;
        self.comp_z[j] += v;
        self.comp_z_n[j] += 1.0;
        acc.meas_comp_total[j] += v;
        acc.meas_comp_samples[j] += 1.0;
        self.u[j] = u;
    }

    /// Close step `k` (1-based): pair this step's innovations with earlier steps' and
    /// store them for later lags.
    fn end_step(&mut self, acc: &mut Accumulator, k: usize) {
        let (m, lags) = (self.n_z, self.lags);
        if lags > 0 {
            for lag in 1..=lags.min(k - 1) {
                let slot = ((k - lag) % lags) * m;
                for j in 0..m {
                    let (a, b) = (self.u[j], self.ring[slot + j]);
                    if a.is_finite() && b.is_finite() {
                        let idx = (lag - 1) * m + j;
                        acc.white_ab[idx] += a * b;
                        acc.white_a2[idx] += a * a;
                        acc.white_b2[idx] += b * b;
                        acc.white_pairs[idx] += 1.0;
                    }
                }
            }
            let slot = (k % lags) * m;
            self.ring[slot..slot + m].copy_from_slice(&self.u);
        }
        self.u.fill(f64::NAN);
    }

    /// Close the run: fold its per-run component averages into the accumulator.
    fn end_run(&self, acc: &mut Accumulator) {
        if self.comp_x_n > 0.0 {
            for j in 0..self.n_x {
                let a = self.comp_x[j] / self.comp_x_n;
                acc.state_comp_run_sum[j] += a;
                acc.state_comp_run_sq[j] += a * a;
            }
        }
        for j in 0..self.n_z {
            if self.comp_z_n[j] > 0.0 {
                let a = self.comp_z[j] / self.comp_z_n[j];
                acc.meas_comp_run_sum[j] += a;
                acc.meas_comp_run_sq[j] += a * a;
                acc.meas_comp_runs[j] += 1;
            }
        }
        acc.runs += 1;
    }
}

/// Split `runs` into fixed chunks, evaluate them in parallel waves, and merge the chunk sums
/// in chunk order.
fn run_chunked<G>(
    settings: &Settings,
    n_x: usize,
    n_z: usize,
    progress: Progress<'_>,
    chunk: G,
) -> Accumulator
where
    G: Fn(Range<usize>, &mut Accumulator) + Sync,
{
    let ranges: Vec<Range<usize>> = (0..settings.runs)
        .step_by(CHUNK)
        .map(|s| s..(s + CHUNK).min(settings.runs))
        .collect();
    let mut total = Accumulator::new(settings.steps, n_x, n_z, settings.lags);
    // Only the merge order matters for the result, so the wave size may follow the pool.
    let wave = 2 * rayon::current_num_threads().max(1);
    for group in ranges.chunks(wave) {
        let parts: Vec<Accumulator> = group
            .par_iter()
            .map(|r| {
                let mut acc = Accumulator::new(settings.steps, n_x, n_z, settings.lags);
                chunk(r.clone(), &mut acc);
                acc
            })
            .collect();
        for p in &parts {
            total.merge(p);
        }
        if let Some(report) = progress {
            report(total.runs);
        }
    }
    total
}

/// An optional callback told the number of runs completed so far (for progress bars).
pub type Progress<'a> = Option<&'a (dyn Fn(usize) + Sync)>;

/// Offsets of each sensor's first component in the concatenated measurement components.
pub fn sensor_offsets(dims: &[usize]) -> Vec<usize> {
    let mut off = Vec::with_capacity(dims.len());
    let mut acc = 0;
    for d in dims {
        off.push(acc);
        acc += d;
    }
    off
}

/// The generic engine computes the NEES-sum variance its filter predicts (an O(n³) matrix
/// recursion per step, as costly as a 15-state filter itself) on every this-many-th run
/// only. The predicted variance depends on the data only through the linearization
/// points, so it varies little between runs; the sampled mean stands for all of them (for
/// a linear filter it is the same in every run, and the estimate is exact).
pub const NULL_VAR_STRIDE: usize = 8;

/// Run the Monte Carlo test with any truth model and filter, one run at a time (the general
/// path: nonlinear models, filters whose gain depends on the data, changing measurements).
pub fn run_generic<M, F>(truth: &M, filter: &F, settings: &Settings) -> Accumulator
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    run_generic_with_progress(truth, filter, settings, None)
}

/// [`run_generic`], reporting the runs completed after each parallel wave.
pub fn run_generic_with_progress<M, F>(
    truth: &M,
    filter: &F,
    settings: &Settings,
    progress: Progress<'_>,
) -> Accumulator
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    let n_x = filter.n_x();
    let dims = filter.sensor_dims();
    let offsets = sensor_offsets(&dims);
    let n_z: usize = dims.iter().sum();
    run_chunked(settings, n_x, n_z, progress, |range, acc| {
        let mut scratch = RunScratch::new(n_x, n_z, settings.lags);
        let mut meas: Vec<Measurement> = Vec::new();
        for run in range {
            scratch.reset();
            if let Err(e) = one_run(
                truth,
                filter,
                settings,
                run,
                &offsets,
                &dims,
                acc,
                &mut scratch,
                &mut meas,
            ) {
                acc.record_divergence(run, &e);
                acc.runs += 1;
            } else {
                scratch.end_run(acc);
            }
        }
    })
}

#[allow(clippy::too_many_arguments)]
fn one_run<M, F>(
    truth: &M,
    filter: &F,
    settings: &Settings,
    run: usize,
    offsets: &[usize],
    dims: &[usize],
    acc: &mut Accumulator,
    scratch: &mut RunScratch,
    meas: &mut Vec<Measurement>,
) -> Result<(), FilterError>
where
    M: TruthModel + ?Sized,
    F: Filter + ?Sized,
{
    let n_x = filter.n_x();
    let mut rng = run_rng(settings.seed, run);
    let mut x = truth.initial_state(&mut rng);
    let mut est = filter.initial();
    let mut null_var = NeesNullVariance::new(n_x);
    let sample_null_var = run % NULL_VAR_STRIDE == 0;
    for k in 1..=settings.steps {
        let i = k - 1;
        x = truth.propagate(k, &x, &mut rng);
        let input = truth.input(k, &x, &mut rng);
        meas.clear();
        truth.measure(k, &x, &mut rng, meas);
        match &input {
            Some(u) => filter.predict_with_input(k, &mut est, u)?,
            None => filter.predict(k, &mut est)?,
        }
        let (mut nis, mut dof) = (0.0, 0usize);
        for m in meas.iter() {
            check_measurement(dims.get(m.sensor).copied(), m)?;
            let inn = filter.update(k, &mut est, m)?;
            nis += inn.nis;
            dof += m.z.len();
            for j in 0..m.z.len() {
                scratch.innovation(acc, offsets[m.sensor] + j, inn.nu[j] / inn.S[(j, j)].sqrt());
            }
        }
        if dof > 0 {
            acc.nis_sum[i] += nis;
            acc.nis_sq[i] += nis * nis;
            acc.nis_dof[i] += dof as f64;
            acc.nis_count[i] += 1.0;
        }
        scratch.end_step(acc, k);

        let e: DVector<f64> = filter.state_error(&x, &est.x);
        let chol = cholesky(&est.P).ok_or(FilterError::NotPositiveDefinite {
            which: "P",
            step: k,
        })?;
        let nees = crate::linalg::mahalanobis_sq(&chol, &e);
        acc.nees_sum[i] += nees;
        acc.nees_sq[i] += nees * nees;
        acc.nees_dof[i] += n_x as f64;
        acc.nees_count[i] += 1.0;
        scratch.state_step(acc, (0..n_x).map(|j| e[j] * e[j] / est.P[(j, j)]));
        if sample_null_var {
            null_var.step(&est.error_map, &est.P, &chol);
        }
    }
    if sample_null_var {
        acc.nees_null_var += null_var.variance();
        acc.null_var_runs += 1;
    }
    Ok(())
}
