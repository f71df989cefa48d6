//! Shares of an evaluation: its chunks dealt out to several processes (the shards of
//! `autotune check --shard i/n`, the ranks of an MPI job), each computing only its own and
//! handing on each chunk's sums, so that the chunk sums merged in chunk order, wherever they
//! were computed, are the one-process sums bit for bit.

use crate::input::SettingError;
use crate::stats::Accumulator;

/// Runs per chunk: the unit of parallel work and of summation order.
pub const CHUNK: usize = 64;

/// Share `index` of `count` of an evaluation's runs, dealt one of two ways:
/// - [`Share::new`], by chunks: chunk `c` (runs `64 c .. 64 c + 64`) belongs to share
///   `c mod count`. Dealing chunks round-robin keeps the shares within one chunk of each
///   other at every N, and a rank's share of the search's N runs and of the refinement's
///   4 N runs starts at the same runs (its taped truth serves both).
/// - [`Share::runs`], by runs within every chunk: share `i` computes offsets
///   `⌊n i / count⌋ .. ⌊n (i + 1) / count⌋` of each chunk of `n` runs (64, or fewer in
///   the last), and hands on each run's own
///   sums, which the merge adds in run order into the chunk's sums
///   ([`Share::merge_runs`]): what one process computes, bit for bit, for an engine that
///   sums a chunk run after run ([`crate::experiment::Sampling::splits_runs`]). An
///   evaluation of fewer chunks than shares (a search's 60 runs are one chunk) is then
///   still computed by every share.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Share {
    index: usize,
    count: usize,
    by_runs: bool,
}

impl Share {
    /// Every chunk: the one-process evaluation.
    pub const WHOLE: Share = Share {
        index: 0,
        count: 1,
        by_runs: false,
    };

    /// Share `index` (0-based) of `count`, dealt by chunks; `index < count`.
    pub fn new(index: usize, count: usize) -> Result<Share, SettingError> {
        if count == 0 || index >= count {
            return Err(SettingError::new(
                "share",
                format!("{index} of {count}: the index must be below the count"),
            ));
        }
        Ok(Share {
            index,
            count,
            by_runs: false,
        })
    }

    /// Share `index` (0-based) of `count`, dealt by runs within every chunk; `index <
    /// count`.
    pub fn runs(index: usize, count: usize) -> Result<Share, SettingError> {
        let mut s = Share::new(index, count)?;
        s.by_runs = count > 1;
        Ok(s)
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

    /// Whether the runs of every chunk are dealt ([`Share::runs`]) rather than the chunks.
    pub fn by_runs(&self) -> bool {
        self.by_runs
    }

    /// Whether chunk `c` is this share's, whole or in part.
    pub fn owns_chunk(&self, c: usize) -> bool {
        self.by_runs || c % self.count == self.index
    }

    /// Whether run `r` of an evaluation of `runs` runs is one this share computes.
    pub fn owns_run(&self, r: usize, runs: usize) -> bool {
        self.runs_in_chunk(r / CHUNK, runs).contains(&r)
    }

    /// The runs of chunk `c` of an evaluation of `runs` runs that this share computes
    /// (empty if none).
    pub fn runs_in_chunk(&self, c: usize, runs: usize) -> std::ops::Range<usize> {
        let first = (c * CHUNK).min(runs);
        let n = (runs - first).min(CHUNK);
        if !self.owns_chunk(c) {
            return first..first;
        }
        if !self.by_runs {
            return first..first + n;
        }
        first + n * self.index / self.count..first + n * (self.index + 1) / self.count
    }

    /// This share's chunks of `chunks`, whole or in part, ascending.
    pub fn chunks(&self, chunks: usize) -> impl Iterator<Item = usize> + use<> {
        let (from, step) = if self.by_runs {
            (0, 1)
        } else {
            (self.index, self.count)
        };
        (from..chunks).step_by(step)
    }

    /// What this share hands on for an evaluation of `runs` runs, ascending: its chunks'
    /// indices when dealt by chunks, its runs' indices when dealt by runs.
    pub fn pieces(&self, runs: usize) -> Vec<usize> {
        let chunks = self.chunks(runs.div_ceil(CHUNK));
        if self.by_runs {
            chunks.flat_map(|c| self.runs_in_chunk(c, runs)).collect()
        } else {
            chunks.collect()
        }
    }

    /// Runs of `0..runs` that this share computes.
    pub fn runs_of(&self, runs: usize) -> usize {
        self.chunks(runs.div_ceil(CHUNK))
            .map(|c| self.runs_in_chunk(c, runs).len())
            .sum()
    }

    /// The first run of `0..runs` this share computes (`runs` if none).
    pub fn first_run(&self, runs: usize) -> usize {
        self.chunks(runs.div_ceil(CHUNK))
            .map(|c| self.runs_in_chunk(c, runs))
            .find(|r| !r.is_empty())
            .map_or(runs, |r| r.start)
    }
}

/// Told each piece's own sums, with the piece's index, as a share computes them: a chunk's
/// sums and its index, or (a share dealt by runs) a run's sums and its index.
pub type ChunkSink<'a> = dyn Fn(usize, Accumulator) + Sync + 'a;

/// A share of an evaluation's chunks and where their sums go.
#[derive(Clone, Copy)]
pub struct ShareOf<'a> {
    /// Which chunks, or which runs of each.
    pub share: Share,
    /// Told each of them, in order.
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
    /// A run's sums are missing.
    #[error("run {0} is in none of them")]
    RunMissing(usize),
    /// A run's sums came twice.
    #[error("run {0} is in two of them")]
    RunTwice(usize),
    /// A run beyond the evaluation's runs, or sums of more than one run.
    #[error("run {0} does not belong to an evaluation of {1} runs")]
    RunStray(usize, usize),
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

    /// Each chunk's sums of an evaluation of `runs` runs from every run's own sums (any
    /// order, from any shares dealt by runs), through a [`RunMerge`] in run order. Every run
    /// must be there once, with the sums of one run. The chunks, in order, are what
    /// [`Share::merge`] takes.
    pub fn merge_runs(
        runs: usize,
        empty: impl Fn() -> Accumulator,
        mut parts: Vec<(usize, Accumulator)>,
    ) -> Result<Vec<(usize, Accumulator)>, MergeError> {
        parts.sort_by_key(|(r, _)| *r);
        let mut merge = RunMerge::new(runs, empty);
        for (r, p) in &parts {
            merge.add(*r, p)?;
        }
        merge.finish()
    }
}

/// Chunk sums built from runs' own sums as they arrive: each run added into its chunk's
/// sums, which must get its runs in run order (runs of different chunks may interleave).
/// That is how one process sums a chunk, bit for bit. Shares dealt by runs
/// ([`Share::runs`]) handed in share by share, in index order, give every chunk its runs in
/// order: memory is one set of sums a chunk, however many runs arrive.
#[derive(Debug)]
pub struct RunMerge {
    runs: usize,
    /// Each chunk's sums so far, and its next run.
    chunks: Vec<(Accumulator, usize)>,
}

impl RunMerge {
    /// For an evaluation of `runs` runs; `empty` gives fresh sums of its shape.
    pub fn new(runs: usize, empty: impl Fn() -> Accumulator) -> Self {
        RunMerge {
            runs,
            chunks: (0..runs.div_ceil(CHUNK))
                .map(|c| (empty(), c * CHUNK))
                .collect(),
        }
    }

    /// Run `r`'s own sums `sums`, which must be one run's and the next run of its chunk.
    pub fn add(&mut self, r: usize, sums: &Accumulator) -> Result<(), MergeError> {
        let stray = MergeError::RunStray(r, self.runs);
        let Some((acc, next)) = self.chunks.get_mut(r / CHUNK) else {
            return Err(stray);
        };
        if r >= self.runs || sums.runs != 1 {
            return Err(stray);
        }
        if r < *next {
            return Err(MergeError::RunTwice(r));
        }
        if r > *next {
            return Err(MergeError::RunMissing(*next));
        }
        acc.merge(sums);
        *next += 1;
        Ok(())
    }

    /// Each chunk's sums with its index, in chunk order, once every run was added.
    pub fn finish(self) -> Result<Vec<(usize, Accumulator)>, MergeError> {
        let runs = self.runs;
        self.chunks
            .into_iter()
            .enumerate()
            .map(|(c, (acc, next))| {
                if next < (c * CHUNK + CHUNK).min(runs) {
                    Err(MergeError::RunMissing(next))
                } else {
                    Ok((c, acc))
                }
            })
            .collect()
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

    #[test]
    fn shares_by_runs_deal_every_run_once_in_slices_of_each_chunk() {
        for count in 2..9 {
            for runs in [0, 1, 5, 60, 64, 100, 200, 257] {
                let mut seen = vec![0; runs];
                let mut most = 0;
                for index in 0..count {
                    let s = Share::runs(index, count).unwrap();
                    let pieces = s.pieces(runs);
                    assert!(pieces.windows(2).all(|w| w[0] < w[1]));
                    assert_eq!(pieces.len(), s.runs_of(runs));
                    assert_eq!(pieces.first().copied().unwrap_or(runs), s.first_run(runs));
                    for r in 0..runs {
                        assert_eq!(s.owns_run(r, runs), pieces.contains(&r), "run {r}");
                    }
                    for r in pieces {
                        seen[r] += 1;
                    }
                    most = most.max(s.runs_of(runs));
                }
                assert!(seen.iter().all(|&n| n == 1), "{count} shares of {runs}");
                // Each chunk's slices differ by at most one run.
                let chunks = runs.div_ceil(CHUNK);
                assert!(most <= chunks * CHUNK.div_ceil(count), "{count} of {runs}");
            }
        }
        // Dealt by chunks, a share's runs are whole chunks.
        let s = Share::new(1, 2).unwrap();
        assert_eq!(s.runs_in_chunk(1, 100), 64..100);
        assert_eq!(s.runs_in_chunk(0, 100), 0..0);
        assert_eq!(s.first_run(100), 64);
        assert_eq!(s.pieces(200), vec![1, 3]);
        // By runs, a chunk of 36 runs is sliced 18 and 18 between two shares.
        let s = Share::runs(1, 2).unwrap();
        assert_eq!(s.runs_in_chunk(1, 100), 82..100);
        assert!(!Share::runs(0, 1).unwrap().by_runs());
    }

    #[test]
    fn a_run_merge_takes_each_chunks_runs_in_run_order_and_every_run_once() {
        let runs = CHUNK + 3;
        let empty = || Accumulator::new(2, 1, 1, 1);
        // Shares by runs, in index order: chunks interleave, each chunk's runs in order.
        let mut m = RunMerge::new(runs, empty);
        for i in 0..3 {
            for r in Share::runs(i, 3).unwrap().pieces(runs) {
                m.add(r, &part(1)).unwrap();
            }
        }
        let chunks = m.finish().unwrap();
        assert_eq!(
            chunks.iter().map(|(c, a)| (*c, a.runs)).collect::<Vec<_>>(),
            [(0, CHUNK), (1, 3)]
        );
        // Out of order within a chunk, twice, beyond the runs, more than one run's sums.
        let mut m = RunMerge::new(runs, empty);
        assert_eq!(m.add(1, &part(1)), Err(MergeError::RunMissing(0)));
        m.add(0, &part(1)).unwrap();
        assert_eq!(m.add(0, &part(1)), Err(MergeError::RunTwice(0)));
        assert_eq!(m.add(runs, &part(1)), Err(MergeError::RunStray(runs, runs)));
        assert_eq!(m.add(1, &part(2)), Err(MergeError::RunStray(1, runs)));
        // A run never given.
        assert_eq!(m.finish().unwrap_err(), MergeError::RunMissing(1));
        // The second chunk short of its end.
        let mut m = RunMerge::new(runs, empty);
        for r in 0..CHUNK + 2 {
            m.add(r, &part(1)).unwrap();
        }
        assert_eq!(m.finish().unwrap_err(), MergeError::RunMissing(CHUNK + 2));
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
