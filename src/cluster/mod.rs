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
use crate::input::SettingError;
use crate::montecarlo::{CHUNK, McConfig, RunOptions};
use crate::records::{
    ChunkShape, WireError, decode_packed_sums_bytes_into, decode_sums_bytes,
    encode_packed_sums_into, encode_sums_into,
};
use crate::stats::Accumulator;

/// The sums of `share`'s pieces of `experiment`'s evaluation at `theta` under `mc` (with
/// `options`' engine and progress), each with its index, in order: its chunks' sums, or
/// for a share dealt by runs ([`Share::runs`]) its runs' own sums.
///
/// Fails as the evaluation fails, and when the experiment does not split into such shares
/// ([`Sampling::splits`]: recorded sums; [`Sampling::splits_runs`]) or computed other
/// pieces than the share's (an [`Experiment`] implementation that ignores
/// [`RunOptions::share`]).
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
    if !experiment.splits() || (share.by_runs() && !experiment.splits_runs()) {
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
    let own = share.pieces(mc.runs());
    if !parts.iter().map(|(c, _)| *c).eq(own.iter().copied()) {
        return Err(unsplit());
    }
    Ok(parts)
}

/// Whether K ranks share an evaluation of `runs` runs by runs within every chunk rather
/// than by chunks: where the experiment allows it (`splits_runs`) and it gives the busiest
/// rank at least a tenth fewer runs. Dealt by runs, each rank answers its runs' own sums,
/// 64 times the bytes of its chunks' sums (about 60 kB a run for ins_gnss's 900 steps),
/// which is why chunks stay the unit wherever they balance: a check of thousands of runs.
/// Dealt by chunks, the 200 runs of ctrv's search (chunks of 64, 64, 64 and 8 runs) give
/// rank 0 of 2 ranks 128 runs; dealt by runs, 104.
pub fn deal_by_runs(runs: usize, ranks: usize, splits_runs: bool) -> bool {
    let chunks = runs.div_ceil(CHUNK);
    if !splits_runs || ranks <= 1 || chunks == 0 || chunks >= 4 * ranks {
        return false;
    }
    let busiest = |share: fn(usize, usize) -> Result<Share, SettingError>| {
        (0..ranks)
            .filter_map(|k| share(k, ranks).ok())
            .map(|s| s.runs_of(runs))
            .max()
            .unwrap_or(0)
    };
    10 * busiest(Share::runs) <= 9 * busiest(Share::new)
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
        self.runs(c * CHUNK..(c * CHUNK + CHUNK).min(self.runs))
    }

    fn runs(&self, runs: std::ops::Range<usize>) -> ChunkShape {
        ChunkShape {
            runs,
            steps: self.steps,
            lags: self.lags,
            n_x: self.n_x,
            n_z: self.n_z,
        }
    }

    /// Chunk `c`'s sums in the sums format (the runs' fingerprints, which only a worker's
    /// seed-contract check reads, as zeros).
    fn encode(&self, c: usize, sums: &Accumulator) -> Vec<u8> {
        let mut out = Vec::new();
        self.encode_into(&mut out, c, sums, false);
        out
    }

    /// The shape of piece `i`: chunk `i`, or with `run`, run `i` alone.
    fn piece(&self, i: usize, run: bool) -> ChunkShape {
        if run {
            self.runs(i..i + 1)
        } else {
            self.chunk(i)
        }
    }

    /// Appends piece `i`'s sums in the sums format to `out`: chunk `i`'s, or with `run`, run
    /// `i`'s own.
    fn encode_into(&self, out: &mut Vec<u8>, i: usize, sums: &Accumulator, run: bool) {
        let shape = self.piece(i, run);
        encode_sums_into(out, sums, &vec![0; shape.runs.len()], &shape);
    }

    /// [`SumsShape::encode_into`] in the packed form that ranks send each other.
    #[cfg_attr(not(feature = "mpi"), allow(dead_code))]
    fn encode_packed_into(&self, out: &mut Vec<u8>, i: usize, sums: &Accumulator, run: bool) {
        let shape = self.piece(i, run);
        encode_packed_sums_into(out, sums, &vec![0; shape.runs.len()], &shape);
    }

    /// Piece `i`'s sums from [`SumsShape::encode_packed_into`]'s bytes, checked against its
    /// shape.
    #[cfg(test)]
    fn decode_packed(&self, i: usize, bytes: &[u8], run: bool) -> Result<Accumulator, WireError> {
        crate::records::decode_packed_sums_bytes(bytes, &self.piece(i, run)).map(|c| c.sums)
    }

    /// [`SumsShape::decode_packed`] into `into`, keeping its allocations.
    #[cfg_attr(not(feature = "mpi"), allow(dead_code))]
    fn decode_packed_into(
        &self,
        i: usize,
        bytes: &[u8],
        run: bool,
        into: &mut Accumulator,
    ) -> Result<(), WireError> {
        decode_packed_sums_bytes_into(bytes, &self.piece(i, run), into).map(|_| ())
    }

    /// Chunk `c`'s sums from the sums format, checked against its shape.
    fn decode(&self, c: usize, bytes: &[u8]) -> Result<Accumulator, WireError> {
        decode_sums_bytes(bytes, &self.chunk(c)).map(|chunk| chunk.sums)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::problem::Problem;
    use crate::tune::tests::Mock;

    fn cv2d() -> Problem {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/problems/cv2d.toml");
        Problem::load(Path::new(path)).unwrap()
    }

    #[test]
    fn three_shares_merged_in_chunk_order_are_the_one_process_sums_bit_for_bit() {
        let p = cv2d();
        let e = p.experiment();
        // 130 runs: chunks of 64, 64 and 2 runs, one for each share.
        let mc = McConfig::new(130, 25).unwrap().with_seed(7);
        let theta = e.params().values();
        let whole = e.monte_carlo(&theta, &mc).unwrap();
        let mut parts = Vec::new();
        for i in (0..3).rev() {
            let share = Share::new(i, 3).unwrap();
            let own = share_sums(e, &theta, &mc, RunOptions::default(), share).unwrap();
            assert_eq!(own.iter().map(|(c, _)| *c).collect::<Vec<_>>(), vec![i]);
            parts.extend(own);
        }
        let merged = Share::merge(mc.runs(), empty_sums(e, &mc), parts.clone()).unwrap();
        assert_eq!(merged, whole);
        // A chunk missing or twice is refused, not merged.
        let missing = parts[1..].to_vec();
        assert!(Share::merge(mc.runs(), empty_sums(e, &mc), missing).is_err());
        let mut twice = parts.clone();
        twice.push(parts[0].clone());
        assert!(Share::merge(mc.runs(), empty_sums(e, &mc), twice).is_err());
    }

    fn ctrv() -> Problem {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/problems/ctrv.toml");
        Problem::load(Path::new(path)).unwrap()
    }

    #[test]
    fn shares_dealt_by_runs_merged_in_run_order_are_the_one_process_sums_bit_for_bit() {
        let p = ctrv();
        let e = p.experiment();
        assert!(e.splits_runs());
        let theta = e.params().values();
        // A whole chunk and a part one (64 + 36 runs), on a taped seed set and a fresh one:
        // the catalog model tapes its truth at a seed set's second evaluation.
        for seed in [5, 5, 5, 6] {
            let mc = McConfig::new(100, 20).unwrap().with_seed(seed);
            let whole = e.monte_carlo(&theta, &mc).unwrap();
            for count in [2, 3, 7] {
                let mut parts = Vec::new();
                for i in (0..count).rev() {
                    let share = Share::runs(i, count).unwrap();
                    let own = share_sums(e, &theta, &mc, RunOptions::default(), share).unwrap();
                    assert_eq!(
                        own.iter().map(|(r, _)| *r).collect::<Vec<_>>(),
                        share.pieces(mc.runs())
                    );
                    parts.extend(own);
                }
                let empty = || empty_sums(e, &mc);
                let chunks = Share::merge_runs(mc.runs(), empty, parts.clone()).unwrap();
                let merged = Share::merge(mc.runs(), empty_sums(e, &mc), chunks).unwrap();
                assert_eq!(merged, whole, "seed {seed}, {count} shares");
                // A run missing, twice, or beyond the runs is refused.
                let missing = parts[1..].to_vec();
                assert!(Share::merge_runs(mc.runs(), empty, missing).is_err());
                let mut twice = parts.clone();
                twice.push(parts[0].clone());
                assert!(Share::merge_runs(mc.runs(), empty, twice).is_err());
                let mut stray = parts.clone();
                stray[0].0 = mc.runs();
                assert!(Share::merge_runs(mc.runs(), empty, stray).is_err());
            }
        }
        // The linear fast path sums a step over a batch of runs: no shares by runs.
        let linear = cv2d();
        let l = linear.experiment();
        assert!(!l.splits_runs());
        let mc = McConfig::new(64, 5).unwrap();
        let share = Share::runs(0, 2).unwrap();
        let got = share_sums(l, &l.params().values(), &mc, RunOptions::default(), share);
        assert!(
            matches!(got, Err(ExperimentError::Unsplit { .. })),
            "{got:?}"
        );
    }

    /// One share of `count` dealt by runs of `e`'s evaluation at its values, with the
    /// progress it reported last.
    fn by_runs(
        e: &dyn Experiment,
        mc: &McConfig,
        i: usize,
        count: usize,
    ) -> (Vec<(usize, Accumulator)>, usize) {
        let done = Mutex::new(0);
        let progress = |n: usize| *done.lock().unwrap() = n;
        let options = RunOptions {
            progress: Some(&progress),
            ..RunOptions::default()
        };
        let share = Share::runs(i, count).unwrap();
        let own = share_sums(e, &e.params().values(), mc, options, share).unwrap();
        let done = *done.lock().unwrap();
        (own, done)
    }

    #[test]
    fn models_held_as_code_split_by_runs_through_every_wrapper_and_report_their_runs_done() {
        use crate::experiment::{Rebounded, RustModel, Sampling};
        use crate::filter::KalmanFilter;
        use crate::model::LinearGaussianModel;
        use crate::montecarlo::RunMerge;
        use crate::params::{ParamDef, Target};
        use nalgebra::{DMatrix, DVector};
        let (catalog, linear) = (ctrv(), cv2d());
        assert!(catalog.splits_runs() && !linear.splits_runs());
        let bounds = vec![(1e-9, 1e9); catalog.params().params.len()];
        assert!(Rebounded::new(&catalog, &bounds).splits_runs());
        let bounds = vec![(1e-9, 1e9); linear.params().params.len()];
        assert!(!Rebounded::new(&linear, &bounds).splits_runs());
        // A Rust model runs the generic engine: its shares by runs are its sums.
        let one = DMatrix::identity(1, 1);
        let truth = LinearGaussianModel::new(
            one.clone(),
            one.clone(),
            &one * 0.1,
            &one * 2.0,
            DVector::zeros(1),
            one.clone(),
        )
        .unwrap();
        let filter = |theta: &[f64]| KalmanFilter {
            F: DMatrix::identity(1, 1),
            H: DMatrix::identity(1, 1),
            Q: DMatrix::identity(1, 1) * 0.1,
            R: DMatrix::identity(1, 1) * theta[0],
            x0: DVector::zeros(1),
            P0: DMatrix::identity(1, 1),
        };
        let mc = McConfig::new(70, 15).unwrap().with_seed(4);
        let model = RustModel::builder("walk", truth, filter)
            .states(["x"])
            .measurements(["z"])
            .param(ParamDef::new("r", 2.0), Target::measurement(&[0]))
            .montecarlo(mc)
            .build()
            .unwrap();
        let whole = model.monte_carlo(&[2.0], &mc).unwrap();
        let mut merge = RunMerge::new(mc.runs(), || empty_sums(&model, &mc));
        for i in 0..2 {
            let (own, done) = by_runs(&model, &mc, i, 2);
            assert_eq!(done, Share::runs(i, 2).unwrap().runs_of(mc.runs()));
            for (r, sums) in &own {
                merge.add(*r, sums).unwrap();
            }
        }
        let chunks = merge.finish().unwrap();
        assert_eq!(
            Share::merge(mc.runs(), empty_sums(&model, &mc), chunks).unwrap(),
            whole
        );
    }

    #[test]
    fn evaluations_are_dealt_by_runs_where_that_gives_the_busiest_rank_a_tenth_fewer() {
        // One chunk: by runs on any ranks, if the experiment allows.
        assert!(deal_by_runs(60, 2, true));
        assert!(deal_by_runs(60, 16, true));
        assert!(!deal_by_runs(60, 2, false));
        assert!(!deal_by_runs(60, 1, true));
        assert!(!deal_by_runs(0, 2, true));
        // 200 runs (64, 64, 64, 8) on 2 ranks: 128 runs by chunks, 104 by runs.
        assert!(deal_by_runs(200, 2, true));
        // 256 runs on 2 ranks balance by chunks (128 each); on 3, 128 against 88.
        assert!(!deal_by_runs(256, 2, true));
        assert!(deal_by_runs(256, 3, true));
        // 800 runs on 2 ranks: 416 by chunks, 400 by runs, under a tenth.
        assert!(!deal_by_runs(800, 2, true));
        // At four chunks a rank and more, chunks: 13 chunks of 64 on 8 ranks are 128 runs
        // for the busiest by chunks and 104 by runs; 33 on 8 are past four a rank.
        assert!(deal_by_runs(64 * 13, 8, true));
        assert!(!deal_by_runs(64 * 32 + 1, 8, true));
        assert!(!deal_by_runs(64 * 8 + 1, 2, true));
    }

    #[test]
    fn a_chunk_goes_over_the_wire_bit_for_bit_and_only_with_its_own_shape() {
        let p = cv2d();
        let e = p.experiment();
        let mc = McConfig::new(70, 12).unwrap().with_seed(3);
        let theta = e.params().values();
        let shape = SumsShape::of(e, &mc);
        assert_eq!(shape.chunks(), 2);
        let parts = share_sums(
            e,
            &theta,
            &mc,
            RunOptions::default(),
            Share::new(0, 1).unwrap(),
        )
        .unwrap();
        for (c, sums) in &parts {
            let bytes = shape.encode(*c, sums);
            assert_eq!(&shape.decode(*c, &bytes).unwrap(), sums);
        }
        // The second chunk holds 6 runs, the first 64: each one's bytes are refused as
        // the other's.
        let first = shape.encode(0, &parts[0].1);
        assert!(shape.decode(1, &first).is_err());
        let other = SumsShape { n_z: 3, ..shape };
        assert!(other.decode(0, &first).is_err());
        // A run's own sums, dealt by runs, go over the wire as that run's alone.
        let share = Share::runs(1, 2).unwrap();
        let runs = share_sums(e, &theta, &mc, RunOptions::default(), share);
        assert!(runs.is_err(), "cv2d's linear path does not split by runs");
        let q = ctrv();
        let c = q.experiment();
        let cshape = SumsShape::of(c, &mc);
        let (own, _) = by_runs(c, &mc, 1, 2);
        for (r, sums) in &own {
            let mut bytes = Vec::new();
            cshape.encode_packed_into(&mut bytes, *r, sums, true);
            assert_eq!(&cshape.decode_packed(*r, &bytes, true).unwrap(), sums);
            let mut into = cshape.empty();
            cshape
                .decode_packed_into(*r, &bytes, true, &mut into)
                .unwrap();
            assert_eq!(&into, sums);
            assert!(cshape.decode_packed(r + 1, &bytes, true).is_err());
            assert!(
                cshape
                    .decode_packed_into(r + 1, &bytes, true, &mut into)
                    .is_err()
            );
            assert!(cshape.decode_packed(0, &bytes, false).is_err());
            assert!(cshape.decode(0, &bytes).is_err());
            // A run's own sums pack smaller: its squares are sent as such, its counts and
            // degrees of freedom as bytes (62% at 12 steps).
            let mut plain = Vec::new();
            cshape.encode_into(&mut plain, *r, sums, true);
            assert!(
                bytes.len() * 3 < plain.len() * 2,
                "{} of {}",
                bytes.len(),
                plain.len()
            );
        }
        // Chunks pack too, and come back whole.
        for (c, sums) in &parts {
            let mut bytes = Vec::new();
            shape.encode_packed_into(&mut bytes, *c, sums, false);
            assert_eq!(&shape.decode_packed(*c, &bytes, false).unwrap(), sums);
        }
    }

    #[test]
    fn a_run_of_ctrv_packs_to_a_third_of_its_plain_sums() {
        // At ctrv's 250 steps the per-step sums are most of a run's: 6157 bytes of 17600
        // (35%); were the squares or the counts sent whole, it would be 48% or 64%.
        let q = ctrv();
        let c = q.experiment();
        let mc = McConfig::new(100, 250).unwrap().with_seed(3);
        let shape = SumsShape::of(c, &mc);
        let (own, _) = by_runs(c, &mc, 1, 16);
        assert_eq!(own.len(), 6);
        for (r, sums) in &own {
            let (mut packed, mut plain) = (Vec::new(), Vec::new());
            shape.encode_packed_into(&mut packed, *r, sums, true);
            shape.encode_into(&mut plain, *r, sums, true);
            assert_eq!(&shape.decode_packed(*r, &packed, true).unwrap(), sums);
            assert!(
                packed.len() * 20 < plain.len() * 7,
                "{} of {}",
                packed.len(),
                plain.len()
            );
        }
    }

    #[test]
    fn an_experiment_that_ignores_its_share_or_does_not_split_is_refused() {
        // The mock computes every run whatever it is asked: its sums hold no chunk of the
        // share's, which share_sums says rather than returning the whole as a share.
        let mock = Mock::new(&[1.0], &[&[1.0]]);
        let mc = McConfig::new(128, 5).unwrap();
        let share = Share::new(1, 2).unwrap();
        let got = share_sums(&mock, &[1.0], &mc, RunOptions::default(), share);
        assert!(
            matches!(got, Err(ExperimentError::Unsplit { .. })),
            "{got:?}"
        );
        let recorded = Mock::new(&[1.0], &[&[1.0]]).recorded();
        let got = share_sums(&recorded, &[1.0], &mc, RunOptions::default(), share);
        assert!(
            matches!(got, Err(ExperimentError::Unsplit { .. })),
            "{got:?}"
        );
    }
}
