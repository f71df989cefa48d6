//! Past one process: an evaluation's chunks computed by several processes and merged into
//! the one-process sums, bit for bit.
//!
//! - [`share_sums`]: one share's chunk sums ([`Share`]: chunk `c` is share `c mod n`'s).
//! - [`shard`]: a share's sums in a file (`autotune check --shard i/n --sums-out FILE`) and
//!   the files of every share merged into one check (`autotune merge`): any scheduler (a
//!   Slurm job array, a CI matrix, GNU parallel) runs the shards.
//! - `mpi` (the cargo feature `mpi`): the ranks of an MPI job share every evaluation of a
//!   check or a tune, rank 0 searching.
//!
//! Chunk sums are merged in chunk order wherever they were computed ([`Share::merge`]),
//! which is the merge one process does: the statistics, verdicts, reports and tuned configs
//! do not depend on how many processes computed them.

#[cfg(feature = "mpi")]
pub mod mpi;
pub mod shard;

pub use crate::montecarlo::{ChunkSink, MergeError, Share, ShareOf};

use std::sync::{Mutex, PoisonError};

use crate::experiment::{Experiment, ExperimentError};
use crate::montecarlo::{CHUNK, McConfig, RunOptions};
use crate::records::{ChunkShape, ChunkSums, WireError, decode_sums_bytes, encode_sums_bytes};
use crate::stats::Accumulator;

/// The sums of `share`'s chunks of `experiment`'s evaluation at `theta` under `mc` (with
/// `options`' engine and progress), each with its chunk's index, in chunk order.
///
/// Fails as the evaluation fails, and when the experiment does not split into shares
/// ([`Experiment::splits`]: recorded sums) or computed other chunks than the share's (an
/// [`Experiment`] implementation that ignores [`RunOptions::share`]).
pub fn share_sums(
    experiment: &dyn Experiment,
    theta: &[f64],
    mc: &McConfig,
    options: RunOptions<'_>,
    share: Share,
) -> Result<Vec<(usize, Accumulator)>, ExperimentError> {
    let unsplit = || ExperimentError::Unsplit {
        source_label: experiment.info().source.label(),
    };
    if !experiment.splits() {
        return Err(unsplit());
    }
    let parts = Mutex::new(Vec::new());
    let sink = |c: usize, sums: Accumulator| {
        parts
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push((c, sums));
    };
    let options = RunOptions {
        share: Some(ShareOf { share, sink: &sink }),
        ..options
    };
    experiment.monte_carlo_with(theta, mc, options)?;
    let mut parts = parts.into_inner().unwrap_or_else(PoisonError::into_inner);
    parts.sort_by_key(|(c, _)| *c);
    let own: Vec<usize> = share
        .chunks(mc.runs().div_ceil(crate::montecarlo::CHUNK))
        .collect();
    if !parts.iter().map(|(c, _)| *c).eq(own.iter().copied()) {
        return Err(unsplit());
    }
    Ok(parts)
}

/// Fresh sums of the shape of `experiment`'s evaluations under `mc`, to merge chunks into.
pub fn empty_sums(experiment: &dyn Experiment, mc: &McConfig) -> Accumulator {
    SumsShape::of(experiment, mc).empty()
}

/// The shape of an evaluation's sums, which each chunk's bytes are checked against when they
/// come back from another process (a shard file, a rank's answer).
#[derive(Debug, Clone, Copy)]
struct SumsShape {
    runs: usize,
    steps: usize,
    lags: usize,
    n_x: usize,
    n_z: usize,
}

impl SumsShape {
    fn of(experiment: &dyn Experiment, mc: &McConfig) -> Self {
        SumsShape {
            runs: mc.runs(),
            steps: mc.steps(),
            lags: mc.lags(),
            n_x: experiment.state_names().len(),
            n_z: experiment.measurement_names().len(),
        }
    }

    fn empty(&self) -> Accumulator {
        Accumulator::new(self.steps, self.n_x, self.n_z, self.lags)
    }

    /// Chunks of the evaluation.
    fn chunks(&self) -> usize {
        self.runs.div_ceil(CHUNK)
    }

    fn chunk(&self, c: usize) -> ChunkShape {
        ChunkShape {
            runs: c * CHUNK..(c * CHUNK + CHUNK).min(self.runs),
            steps: self.steps,
            lags: self.lags,
            n_x: self.n_x,
            n_z: self.n_z,
        }
    }

    /// Chunk `c`'s sums in the sums format (the runs' fingerprints, which only a worker's
    /// seed-contract check reads, as zeros).
    fn encode(&self, c: usize, sums: &Accumulator) -> Vec<u8> {
        let shape = self.chunk(c);
        let chunk = ChunkSums {
            sums: sums.clone(),
            prints: vec![0; shape.runs.len()],
        };
        encode_sums_bytes(&chunk, &shape)
    }

    /// Chunk `c`'s sums from the sums format, checked against its shape.
    fn decode(&self, c: usize, bytes: &[u8]) -> Result<Accumulator, WireError> {
        decode_sums_bytes(bytes, &self.chunk(c)).map(|chunk| chunk.sums)
    }
}
