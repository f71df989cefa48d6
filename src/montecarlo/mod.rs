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
mod share;
mod tape;
mod truth_moments;

pub use config::{DEFAULT_ALPHA, DEFAULT_LAGS, MAX_RUNS, MAX_STEPS, McConfig};
pub use expected::{
    expected_accumulator, expected_accumulator_mapped, expected_accumulator_tracked, models_match,
};
pub use generic::{
    NULL_VAR_STRIDE, innovation_scales, run_generic, run_generic_cached, run_generic_with,
};
pub use linear::{run_linear, run_linear_with};
pub use share::{CHUNK, ChunkSink, MergeError, RunMerge, Share, ShareOf};
pub use tape::{TapeUsage, TruthCache, TruthTape};
pub use truth_moments::{SharedTrack, TruthTrack};

use std::ops::Range;

use rand::SeedableRng;
use rayon::prelude::*;

use crate::filter::FilterError;
use crate::rng::SimRng;
use crate::stats::{Accumulator, StopCause};

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
///
/// With a share ([`RunOptions::share`]) only the share's chunks are evaluated, and each
/// chunk's own sums go to the share's sink, in chunk order, instead of being merged: the
/// whole evaluation's sums are those chunks merged in chunk order with every other share's
/// ([`Share::merge`]), which is the merge below, bit for bit. The returned sums are then
/// empty.
fn run_chunked<G>(
    mc: &McConfig,
    n_x: usize,
    n_z: usize,
    options: RunOptions<'_>,
    chunk: G,
) -> Accumulator
where
    G: Fn(Range<usize>, &mut Accumulator) + Sync,
{
    let runs = mc.runs();
    let chunks = runs.div_ceil(CHUNK);
    let range = |c: usize| c * CHUNK..(c * CHUNK).saturating_add(CHUNK).min(runs);
    let share = options.share.map_or(Share::WHOLE, |s| s.share);
    let mut total = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
    if let Some(s) = options.share.filter(|s| s.share.by_runs()) {
        run_slices(mc, n_x, n_z, s, options.progress, chunk);
        return total;
    }
    let mut done = 0;
    // Only the merge order matters for the result, so the wave size may follow the pool.
    let wave = 2 * rayon::current_num_threads().max(1);
    let mut own = share.chunks(chunks).peekable();
    while own.peek().is_some() {
        let ids: Vec<usize> = own.by_ref().take(wave).collect();
        let parts: Vec<Accumulator> = ids
            .par_iter()
            .map(|&c| {
                let mut acc = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
                chunk(range(c), &mut acc);
                acc
            })
            .collect();
        for (c, p) in ids.into_iter().zip(parts) {
            done += p.runs;
            match options.share {
                Some(s) => (s.sink)(c, p),
                None => total.merge(&p),
            }
        }
        if let Some(report) = options.progress {
            report(done);
        }
    }
    total
}

/// [`run_chunked`] for a share dealt by runs: each chunk's runs of the share, side by side,
/// each into sums of its own handed to the share's sink in run order. `chunk` on a range
/// of one run is that run's own sums; the engines that sum a chunk run after run
/// ([`crate::experiment::Sampling::splits_runs`]) add those in run order into a chunk's
/// sums, which is what [`Share::merge_runs`] does with them.
fn run_slices<G>(
    mc: &McConfig,
    n_x: usize,
    n_z: usize,
    share: ShareOf<'_>,
    progress: Progress<'_>,
    chunk: G,
) where
    G: Fn(Range<usize>, &mut Accumulator) + Sync,
{
    let runs = mc.runs();
    let mut done = 0;
    for c in share.share.chunks(runs.div_ceil(CHUNK)) {
        let own = share.share.runs_in_chunk(c, runs);
        let parts: Vec<Accumulator> = own
            .clone()
            .into_par_iter()
            .map(|r| {
                let mut acc = Accumulator::new(mc.steps(), n_x, n_z, mc.lags());
                chunk(r..r + 1, &mut acc);
                acc
            })
            .collect();
        for (r, p) in own.zip(parts) {
            done += 1;
            (share.sink)(r, p);
        }
        if let Some(report) = progress {
            report(done);
        }
    }
}

/// An optional callback told the number of runs completed so far (for progress bars).
pub type Progress<'a> = Option<&'a (dyn Fn(usize) + Sync)>;

/// How one Monte Carlo evaluation runs: the engine path, a progress callback, and which of
/// its chunks this process computes.
#[derive(Clone, Copy, Default)]
pub struct RunOptions<'a> {
    /// The engine path; an experiment without a linear fast path runs its generic one for
    /// [`Engine::Auto`] and [`Engine::Linear`] alike.
    pub engine: Engine,
    /// Told the number of runs completed (of this process's chunks) after each parallel
    /// wave.
    pub progress: Progress<'a>,
    /// `None`: every chunk, merged into the returned sums. Some share: only its chunks, each
    /// chunk's sums handed to its sink (the returned sums are then empty); what the shards
    /// of `autotune check --shard` and the ranks of an MPI job compute.
    pub share: Option<ShareOf<'a>>,
}

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
    all_stopped_with(mc, n_x, n_z, err, RunOptions::default())
}

/// [`all_stopped`] by chunks, for a share of them.
fn all_stopped_with(
    mc: &McConfig,
    n_x: usize,
    n_z: usize,
    err: &FilterError,
    options: RunOptions<'_>,
) -> Accumulator {
    run_chunked(mc, n_x, n_z, options, |range, acc| {
        for run in range {
            record_divergence(acc, run, err);
            acc.runs += 1;
        }
    })
}
