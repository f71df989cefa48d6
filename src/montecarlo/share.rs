//! Shares of an evaluation: its chunks dealt out to several processes (the shards of
//! `autotune check --shard i/n`, the ranks of an MPI job), each computing only its own and
//! handing on each chunk's sums, so that the chunk sums merged in chunk order, wherever they
//! were computed, are the one-process sums bit for bit.

use crate::input::SettingError;
use crate::stats::Accumulator;

/// Runs per chunk: the unit of parallel work and of summation order.
pub const CHUNK: usize = 64;

/// Share `index` of `count`: chunk `c` (runs `64 c .. 64 c + 64`) belongs to share
/// `c mod count`. Dealing chunks round-robin keeps the shares within one chunk of each
/// other at every N, and a rank's share of the search's N runs and of the refinement's 4 N
/// runs starts at the same runs (its taped truth serves both).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Share {
    index: usize,
    count: usize,
}

impl Share {
    /// Every chunk: the one-process evaluation.
    pub const WHOLE: Share = Share { index: 0, count: 1 };

    /// Share `index` (0-based) of `count`; `index < count`.
    pub fn new(index: usize, count: usize) -> Result<Share, SettingError> {
        if count == 0 || index >= count {
            return Err(SettingError::new(
                "share",
                format!("{index} of {count}: the index must be below the count"),
            ));
        }
        Ok(Share { index, count })
    }

    /// This share's index, 0-based.
    pub fn index(&self) -> usize {
        self.index
    }

    /// How many shares there are.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Whether this is every chunk.
    pub fn is_whole(&self) -> bool {
        self.count == 1
    }

    /// Whether chunk `c` is this share's.
    pub fn owns_chunk(&self, c: usize) -> bool {
        c % self.count == self.index
    }

    /// Whether run `r` is in one of this share's chunks.
    pub fn owns_run(&self, r: usize) -> bool {
        self.owns_chunk(r / CHUNK)
    }

    /// This share's chunks of `chunks`, ascending.
    pub fn chunks(&self, chunks: usize) -> impl Iterator<Item = usize> + use<> {
        (self.index..chunks).step_by(self.count)
    }

    /// Runs of `0..runs` that are in this share's chunks.
    pub fn runs_of(&self, runs: usize) -> usize {
        self.chunks(runs.div_ceil(CHUNK))
            .map(|c| (runs - c * CHUNK).min(CHUNK))
            .sum()
    }
}

/// Told each chunk's own sums, with the chunk's index, as a share computes them.
pub type ChunkSink<'a> = dyn Fn(usize, Accumulator) + Sync + 'a;

/// A share of an evaluation's chunks and where their sums go.
#[derive(Clone, Copy)]
pub struct ShareOf<'a> {
    /// Which chunks.
    pub share: Share,
    /// Told each of them, in chunk order.
    pub sink: &'a ChunkSink<'a>,
}

impl std::fmt::Debug for ShareOf<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ShareOf")
            .field("share", &self.share)
            .finish_non_exhaustive()
    }
}

/// Why chunk sums do not make up one evaluation.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MergeError {
    /// A chunk is missing.
    #[error("chunk {0} (runs {from}..{to}) is in none of them", from = .0 * CHUNK, to = (.0 + 1) * CHUNK)]
    Missing(usize),
    /// A chunk came twice.
    #[error("chunk {0} is in two of them")]
    Twice(usize),
    /// A chunk beyond the evaluation's runs, or of another shape.
    #[error("chunk {0} does not belong to an evaluation of {1} runs")]
    Stray(usize, usize),
}

impl Share {
    /// The sums of an evaluation of `runs` runs from its chunks' own sums (any order, from
    /// any shares): merged in chunk order into `empty` (fresh sums of the evaluation's
    /// shape), which is what one process computes, bit for bit. Every chunk must be there
    /// once, with the runs its range holds.
    pub fn merge(
        runs: usize,
        mut empty: Accumulator,
        mut parts: Vec<(usize, Accumulator)>,
    ) -> Result<Accumulator, MergeError> {
        let chunks = runs.div_ceil(CHUNK);
        parts.sort_by_key(|(c, _)| *c);
        for (k, w) in parts.windows(2).enumerate() {
            if w[0].0 == w[1].0 {
                return Err(MergeError::Twice(parts[k].0));
            }
        }
        let mut next = 0;
        for (c, p) in &parts {
            if *c >= chunks || p.runs != (runs - c * CHUNK).min(CHUNK) {
                return Err(MergeError::Stray(*c, runs));
            }
            if *c != next {
                return Err(MergeError::Missing(next));
            }
            empty.merge(p);
            next += 1;
        }
        if next < chunks {
            return Err(MergeError::Missing(next));
        }
        Ok(empty)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_deal_every_chunk_once() {
        for count in 1..6 {
            for chunks in 0..20 {
                let mut seen = vec![0; chunks];
                for index in 0..count {
                    let s = Share::new(index, count).unwrap();
                    for c in s.chunks(chunks) {
                        assert!(s.owns_chunk(c));
                        seen[c] += 1;
                    }
                }
                assert!(seen.iter().all(|&n| n == 1), "{count} shares of {chunks}");
            }
        }
        let runs = 3 * CHUNK + 5;
        let total: usize = (0..3)
            .map(|i| Share::new(i, 3).unwrap().runs_of(runs))
            .sum();
        assert_eq!(total, runs);
        assert_eq!(Share::new(0, 3).unwrap().runs_of(runs), CHUNK + 5);
        assert!(Share::new(3, 3).is_err() && Share::new(0, 0).is_err());
    }

    fn part(runs: usize) -> Accumulator {
        let mut a = Accumulator::new(2, 1, 1, 1);
        a.runs = runs;
        a
    }

    #[test]
    fn merge_refuses_missing_doubled_and_stray_chunks() {
        let runs = 2 * CHUNK + 1;
        let empty = || Accumulator::new(2, 1, 1, 1);
        let ok = vec![(2, part(1)), (0, part(CHUNK)), (1, part(CHUNK))];
        assert_eq!(Share::merge(runs, empty(), ok).unwrap().runs, runs);
        let missing = vec![(0, part(CHUNK)), (2, part(1))];
        assert_eq!(
            Share::merge(runs, empty(), missing),
            Err(MergeError::Missing(1))
        );
        let short = vec![(0, part(CHUNK)), (1, part(CHUNK))];
        assert_eq!(
            Share::merge(runs, empty(), short),
            Err(MergeError::Missing(2))
        );
        let twice = vec![(0, part(CHUNK)), (0, part(CHUNK)), (1, part(CHUNK))];
        assert_eq!(
            Share::merge(runs, empty(), twice),
            Err(MergeError::Twice(0))
        );
        let stray = vec![(0, part(CHUNK)), (1, part(CHUNK)), (2, part(2))];
        assert_eq!(
            Share::merge(runs, empty(), stray),
            Err(MergeError::Stray(2, runs))
        );
    }
}
