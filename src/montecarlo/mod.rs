//! The Monte Carlo engine: N independent runs of truth simulation and filter, in parallel,
//! with streaming accumulation of everything the statistics need.
//!
//! Reproducibility: run `i` draws from its own stream seeded by `(seed, i)`; runs are
//! grouped into fixed chunks of [`CHUNK`] runs whatever the thread count, each chunk sums
//! its runs in order, and chunk sums are merged in chunk order. The result is therefore
//! bit-identical on any number of threads. An evaluation of fewer chunks than threads (60
//! runs are one chunk) computes a chunk's runs side by side, each into sums of its own,
//! added in run order: a run adds to each sum at most once (`crate::stats::RunRecorder`
//! sums a run's own steps first), so that too is the sequential result, bit for bit. Memory is O(T·(n + m)) per chunk in flight and
//! does not grow with N.

mod config;
mod expected;
mod generic;
mod linear;
mod tape;

pub use config::{DEFAULT_ALPHA, DEFAULT_LAGS, MAX_RUNS, MAX_STEPS, McConfig};
pub use expected::{expected_accumulator, models_match};
pub use generic::{NULL_VAR_STRIDE, run_generic, run_generic_cached, run_generic_with_progress};
pub use linear::{run_linear, run_linear_with_progress};
pub use tape::{TapeUsage, TruthCache, TruthTape};

use std::ops::Range;

use rand::SeedableRng;
use rayon::prelude::*;

use crate::SimRng;
use crate::filter::FilterError;
use crate::stats::{Accumulator, StopCause};

/// Runs per chunk: the unit of parallel work and of summation order.
pub const CHUNK: usize = 64;

/// Which Monte Carlo path runs a linear problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Engine {
    /// The fastest path valid for the experiment (the linear fast path for linear problems,
    /// the generic one otherwise).
    #[default]
    Auto,
    /// Precompute the data-independent covariance recursion once and batch the runs
    /// (linear filters only).
    Linear,
    /// One run at a time through the truth-model and filter traits (any model).
    Generic,
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

/// Split `runs` into fixed chunks, evaluate them in parallel waves, and merge the chunk sums
/// in chunk order.
///
/// The chunks are generated wave by wave, never listed: memory holds one wave's
/// accumulators (two chunks per thread) whatever N, so a test of 10¹⁰ runs takes time, not
/// memory. Chunk `c` covers runs `64 c .. min(64 c + 64, N)`.
fn run_chunked<G>(
    mc: &McConfig,
    n_x: usize,
    n_z: usize,
    progress: Progress<'_>,
    chunk: G,
) -> Accumulator
where
    G: Fn(Range<usize>, &mut Accumulator) + Sync,
{
    let runs = mc.runs();
    let chunks = runs.div_ceil(CHUNK);
    let range = |c: usize| c * CHUNK..(c * CHUNK).saturating_add(CHUNK).min(runs);
    let mut total = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
    // Only the merge order matters for the result, so the wave size may follow the pool.
    let wave = 2 * rayon::current_num_threads().max(1);
    for first in (0..chunks).step_by(wave) {
        let parts: Vec<Accumulator> = (first..chunks.min(first.saturating_add(wave)))
            .into_par_iter()
            .map(|c| {
                let mut acc = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
                chunk(range(c), &mut acc);
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

/// Record that run `run` stopped on `err`.
fn record_divergence(acc: &mut Accumulator, run: usize, err: &FilterError) {
    let (step, cause) = match err {
        FilterError::NotPositiveDefinite { step, .. } => (*step, StopCause::Diverged),
        FilterError::IllConditioned { step, .. } => (*step, StopCause::IllConditioned),
        FilterError::BadMeasurement { .. } | FilterError::Unsupported { .. } => {
            (0, StopCause::Diverged)
        }
    };
    acc.record_stop(run, step, cause, err.to_string());
}

/// The sums of `mc.runs()` runs that all stopped on `err` before contributing anything: a
/// data-independent covariance recursion (the linear fast path's, the exact path's) fails
/// at the same step in every run.
pub fn all_stopped(mc: &McConfig, n_x: usize, n_z: usize, err: &FilterError) -> Accumulator {
    let mut acc = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
    for run in 0..mc.runs() {
        record_divergence(&mut acc, run, err);
    }
    acc.runs = mc.runs();
    acc
}
