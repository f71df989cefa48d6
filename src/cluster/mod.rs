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
use crate::montecarlo::{McConfig, RunOptions};
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
    Accumulator::new(
        mc.steps(),
        experiment.state_names().len(),
        experiment.measurement_names().len(),
        mc.lags(),
    )
}
