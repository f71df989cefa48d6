//! Truth tapes: a seed set's truth trajectories, inputs and measurements, simulated once and
//! replayed to every filter evaluated on that seed set.
//!
//! Under common random numbers a tuner evaluates every candidate θ on the same seeds. When θ
//! enters only the filter (its Q and R), the truth a run simulates does not depend on θ: the
//! filter draws no random numbers, so run `i`'s stream `(seed, i)` gives the same states
//! and measurements to every candidate. A [`TruthCache`] keeps those runs after the second
//! evaluation of a seed set and hands them to the generic engine, which replays them
//! instead of simulating; the sums are bit-identical to simulating (the tests compare).
//!
//! Memory is one tape per seed set in use: N × T × (n_x + n_u + n_z) numbers and a small
//! per-vector overhead, a few MB for the catalog's search runs. The cache holds at most
//! [`TruthCache::DEFAULT_LIMIT`] bytes (the least recently used tape goes first) and
//! simulates, as before, a seed set whose tape would not fit.

use std::sync::{Arc, Mutex, PoisonError};

use nalgebra::DVector;
use rayon::prelude::*;

use super::{McConfig, Share, run_rng};
use crate::measurement::Measurement;
use crate::model::TruthModel;
use crate::rng::SimRng;

/// What one step of a run's truth gives the filter: the true state, the control input, the
/// measurements. The engine advances it step by step, simulating or replaying.
pub(super) trait TruthSource {
    /// Move to step `k` (1-based, in order); `false` if the truth state stopped being
    /// finite there (the run ends).
    fn advance(&mut self, k: usize) -> bool;
    /// The true state at the current step.
    fn state(&self) -> &DVector<f64>;
    /// The control input of the prediction into the current step.
    fn input(&self) -> Option<&DVector<f64>>;
    /// The measurements of the current step.
    fn measurements(&self) -> &[Measurement];
}

/// A run's truth simulated as the engine goes, from the run's own random stream.
pub(super) struct Live<'a, M: ?Sized> {
    truth: &'a M,
    rng: SimRng,
    x: DVector<f64>,
    input: Option<DVector<f64>>,
    meas: &'a mut Vec<Measurement>,
}

impl<'a, M: TruthModel + ?Sized> Live<'a, M> {
    /// Run `run` of seed set `seed`, its initial state drawn; `meas` is reused storage.
    pub(super) fn new(truth: &'a M, seed: u64, run: usize, meas: &'a mut Vec<Measurement>) -> Self {
        let mut rng = run_rng(seed, run);
        let x = truth.initial_state(&mut rng);
        meas.clear();
        Live {
            truth,
            rng,
            x,
            input: None,
            meas,
        }
    }
}

impl<M: TruthModel + ?Sized> TruthSource for Live<'_, M> {
    #[inline]
    fn advance(&mut self, k: usize) -> bool {
        self.x = self.truth.propagate(k, &self.x, &mut self.rng);
        if self.x.iter().any(|v| !v.is_finite()) {
            return false;
        }
        self.input = self.truth.input(k, &self.x, &mut self.rng);
        self.meas.clear();
        self.truth.measure(k, &self.x, &mut self.rng, self.meas);
        true
    }

    fn state(&self) -> &DVector<f64> {
        &self.x
    }

    fn input(&self) -> Option<&DVector<f64>> {
        self.input.as_ref()
    }

    fn measurements(&self) -> &[Measurement] {
        self.meas
    }
}

/// One run's truth as simulated: the states and inputs of steps 1..=len and every step's
/// measurements; `len` is short of T when the truth overflowed at step `len + 1`.
#[derive(Debug)]
pub(super) struct RunTape {
    states: Vec<DVector<f64>>,
    inputs: Vec<Option<DVector<f64>>>,
    meas: Vec<Measurement>,
    /// Step k's measurements are `meas[ends[k − 1]..ends[k]]` (`ends[0] = 0`).
    ends: Vec<usize>,
}

impl RunTape {
    fn record<M: TruthModel + ?Sized>(truth: &M, seed: u64, run: usize, steps: usize) -> Self {
        let mut scratch = Vec::new();
        let mut live = Live::new(truth, seed, run, &mut scratch);
        let mut tape = RunTape {
            states: Vec::with_capacity(steps),
            inputs: Vec::with_capacity(steps),
            meas: Vec::new(),
            ends: Vec::with_capacity(steps + 1),
        };
        tape.ends.push(0);
        for k in 1..=steps {
            if !live.advance(k) {
                break;
            }
            tape.states.push(live.x.clone());
            tape.inputs.push(live.input.take());
            tape.meas.append(live.meas);
            tape.ends.push(tape.meas.len());
        }
        tape
    }

    /// Heap bytes held, counting each vector's allocation overhead.
    fn bytes(&self) -> usize {
        const VEC: usize = 48;
        let v = |x: &DVector<f64>| 8 * x.len() + VEC;
        self.states.iter().map(v).sum::<usize>()
            + self.inputs.iter().flatten().map(v).sum::<usize>()
            + self.meas.iter().map(|m| v(&m.z)).sum::<usize>()
            + 8 * self.ends.len()
            + 3 * VEC
    }
}

/// A run replayed from its tape.
pub(super) struct Replay<'a> {
    tape: &'a RunTape,
    step: usize,
}

impl<'a> Replay<'a> {
    pub(super) fn new(tape: &'a RunTape) -> Self {
        Replay { tape, step: 0 }
    }
}

impl TruthSource for Replay<'_> {
    #[inline]
    fn advance(&mut self, k: usize) -> bool {
        self.step = k;
        k <= self.tape.states.len()
    }

    fn state(&self) -> &DVector<f64> {
        &self.tape.states[self.step - 1]
    }

    fn input(&self) -> Option<&DVector<f64>> {
        self.tape.inputs[self.step - 1].as_ref()
    }

    fn measurements(&self) -> &[Measurement] {
        &self.tape.meas[self.tape.ends[self.step - 1]..self.tape.ends[self.step]]
    }
}

/// The truth of runs of `0..runs.len()` of one seed set over `steps` steps: those of the
/// shares ([`Share`]) this process computed them for (the whole, but for a shard or an MPI
/// rank, whose evaluations of one seed set are dealt by chunks or by runs as their run
/// counts make them, and whose tape holds the union).
#[derive(Debug)]
pub struct TruthTape {
    seed: u64,
    steps: usize,
    /// Run i's tape at index i; `None` for the runs no share held computed.
    runs: Vec<Option<RunTape>>,
    bytes: usize,
}

impl TruthTape {
    /// Simulate runs `0..runs` of seed set `seed` over `steps` steps (in parallel; each
    /// run from its own stream, so the tape does not depend on the thread count).
    pub fn record<M: TruthModel + ?Sized>(truth: &M, seed: u64, steps: usize, runs: usize) -> Self {
        Self::record_share(truth, seed, steps, runs, Share::WHOLE)
    }

    /// [`Self::record`] of the runs of `0..runs` in `share`'s chunks only.
    pub fn record_share<M: TruthModel + ?Sized>(
        truth: &M,
        seed: u64,
        steps: usize,
        runs: usize,
        share: Share,
    ) -> Self {
        let mut tape = TruthTape {
            seed,
            steps,
            runs: Vec::new(),
            bytes: 0,
        };
        tape.extend(truth, runs, share);
        tape
    }

    /// Simulate the share's runs of `0..runs` that the tape does not hold yet.
    fn extend<M: TruthModel + ?Sized>(&mut self, truth: &M, runs: usize, share: Share) {
        self.runs.resize_with(self.runs.len().max(runs), || None);
        let missing: Vec<usize> = (0..runs)
            .filter(|&r| share.owns_run(r, runs) && self.runs[r].is_none())
            .collect();
        self.record_runs(truth, &missing, runs);
    }

    /// Simulate and hold runs `which` (below `runs`, none held yet), in parallel.
    fn record_runs<M: TruthModel + ?Sized>(&mut self, truth: &M, which: &[usize], runs: usize) {
        let (seed, steps) = (self.seed, self.steps);
        let which: Vec<usize> = which.iter().copied().filter(|&r| r < runs).collect();
        self.runs.resize_with(self.runs.len().max(runs), || None);
        let more: Vec<RunTape> = which
            .par_iter()
            .map(|&run| RunTape::record(truth, seed, run, steps))
            .collect();
        self.bytes += more.iter().map(RunTape::bytes).sum::<usize>();
        for (r, t) in which.into_iter().zip(more) {
            self.runs[r] = Some(t);
        }
    }

    /// Runs held.
    pub fn runs(&self) -> usize {
        self.runs.len()
    }

    /// Heap bytes held (an estimate that counts each vector's allocation overhead).
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Whether this tape replays `mc`'s runs of `share`.
    pub fn covers(&self, mc: &McConfig, share: Share) -> bool {
        self.seed == mc.seed()
            && self.steps == mc.steps()
            && self.runs.len() >= mc.runs()
            && (0..mc.runs()).all(|r| !share.owns_run(r, mc.runs()) || self.runs[r].is_some())
    }

    /// Run `run`'s tape: one of the share's runs below [`Self::runs`].
    pub(super) fn run(&self, run: usize) -> &RunTape {
        self.runs[run]
            .as_ref()
            .expect("the engine replays only the runs of the tape's share")
    }
}

/// The truth tapes of the seed sets an experiment is evaluated on more than once, for an
/// experiment whose truth does not depend on θ ([`super::run_generic_cached`]).
#[derive(Debug)]
pub struct TruthCache {
    limit: usize,
    state: Mutex<CacheState>,
}

/// What a [`TruthCache`] has served so far: evaluations that replayed a tape, evaluations
/// that simulated their truth (a seed set's first and second evaluations, the second
/// recording its tape, and every evaluation of one whose tape is too large), and whether any
/// seed set's tape was too large for the limit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TapeUsage {
    /// Evaluations whose truth was replayed from a tape.
    pub replayed: usize,
    /// Evaluations whose truth was simulated.
    pub simulated: usize,
    /// A seed set's tape would have exceeded the cache's limit.
    pub too_large: bool,
}

#[derive(Debug, Default)]
struct CacheState {
    /// Least recently used first.
    tapes: Vec<Arc<TruthTape>>,
    /// Seed sets `(seed, steps, runs)` evaluated once: the next evaluation records.
    seen: Vec<(u64, usize, usize, Share)>,
    /// Seed sets `(seed, steps)` whose tape was found too large for the limit.
    too_large: Vec<(u64, usize, Share)>,
    /// What the cache has served.
    usage: TapeUsage,
}

/// Seed sets remembered as seen once; a tuner uses a handful.
const SEEN: usize = 64;

impl Default for TruthCache {
    fn default() -> Self {
        TruthCache::with_limit(TruthCache::DEFAULT_LIMIT)
    }
}

impl TruthCache {
    /// Bytes of tapes a cache holds by default: 512 MiB.
    pub const DEFAULT_LIMIT: usize = 512 << 20;

    /// A cache holding at most `limit` bytes of tapes (0: never records).
    pub fn with_limit(limit: usize) -> Self {
        TruthCache {
            limit,
            state: Mutex::new(CacheState::default()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, CacheState> {
        // A panic while the lock was held leaves nothing half-done that a reader could
        // see: tapes are inserted whole.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Bytes of tapes held now.
    pub fn bytes(&self) -> usize {
        self.lock().tapes.iter().map(|t| t.bytes).sum()
    }

    /// The limit, bytes.
    pub fn limit(&self) -> usize {
        self.limit
    }

    /// What the cache has served so far.
    pub fn usage(&self) -> TapeUsage {
        self.lock().usage
    }

    /// [`Self::tape`], counted in [`Self::usage`]: the tape of `mc`'s runs in `share`'s chunks.
    pub fn tape<M: TruthModel + ?Sized>(
        &self,
        truth: &M,
        mc: &McConfig,
        share: Share,
    ) -> Option<Arc<TruthTape>> {
        let (tape, replayed) = self.find_or_record(truth, mc, share);
        let mut s = self.lock();
        if replayed {
            s.usage.replayed += 1;
        } else {
            s.usage.simulated += 1;
        }
        s.usage.too_large |= !s.too_large.is_empty();
        tape
    }

    /// The tape of `mc`'s runs if this seed set was evaluated before and its tape fits the
    /// limit, recording (or extending) it now; `None`: simulate as usual. With it, whether
    /// the tape was there already (the truth is replayed, not simulated), as one process
    /// holding every run would have it: a tape of at least `mc`'s runs. A share's runs
    /// depend on the evaluation's run count when it is dealt by runs (an MPI rank's), so a
    /// rank may find such a tape without the runs of its share, and tapes them now; the
    /// count stays one process's, so that what a tune reports does not depend on the
    /// ranks.
    fn find_or_record<M: TruthModel + ?Sized>(
        &self,
        truth: &M,
        mc: &McConfig,
        share: Share,
    ) -> (Option<Arc<TruthTape>>, bool) {
        let key = (mc.seed(), mc.steps(), share);
        let shorter = {
            let mut s = self.lock();
            if let Some(i) = s.tapes.iter().position(|t| t.covers(mc, share)) {
                let t = s.tapes.remove(i);
                s.tapes.push(Arc::clone(&t));
                return (Some(t), true);
            }
            if s.too_large.contains(&key) {
                return (None, false);
            }
            let shorter = s
                .tapes
                .iter()
                .position(|t| (t.seed, t.steps) == (mc.seed(), mc.steps()))
                .map(|i| s.tapes.remove(i));
            let full = (mc.seed(), mc.steps(), mc.runs(), share);
            if shorter.is_none() && !s.seen.contains(&full) {
                if s.seen.len() == SEEN {
                    s.seen.remove(0);
                }
                s.seen.push(full);
                return (None, false);
            }
            shorter
        };
        // Recorded without the lock: an evaluation running beside this one (the engine is
        // parallel inside) must not wait on it, and a duplicate recording is only work.
        let long_enough = shorter.as_ref().is_some_and(|t| t.runs.len() >= mc.runs());
        let mut tape = match shorter {
            Some(t) => Arc::try_unwrap(t).unwrap_or_else(|t| TruthTape {
                seed: t.seed,
                steps: t.steps,
                runs: Vec::new(),
                bytes: 0,
            }),
            // The share's first run tells its size.
            None => {
                let mut tape = TruthTape {
                    seed: mc.seed(),
                    steps: mc.steps(),
                    runs: Vec::new(),
                    bytes: 0,
                };
                tape.record_runs(truth, &[share.first_run(mc.runs())], mc.runs());
                tape
            }
        };
        let held = tape.runs.iter().flatten().count();
        let per_run = tape.bytes.div_ceil(held.max(1)).max(1);
        if per_run.saturating_mul(share.runs_of(mc.runs())) > self.limit {
            self.lock().too_large.push(key);
            return (None, false);
        }
        tape.extend(truth, mc.runs(), share);
        let tape = Arc::new(tape);
        let mut s = self.lock();
        s.tapes
            .retain(|t| (t.seed, t.steps) != (mc.seed(), mc.steps()));
        let mut held: usize = s.tapes.iter().map(|t| t.bytes).sum();
        while held + tape.bytes > self.limit && !s.tapes.is_empty() {
            held -= s.tapes.remove(0).bytes;
        }
        s.tapes.push(Arc::clone(&tape));
        (Some(tape), long_enough)
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};

    use super::*;
    use crate::model::LinearGaussianModel;

    fn walk() -> LinearGaussianModel {
        let one = DMatrix::identity(1, 1);
        LinearGaussianModel::new(
            one.clone(),
            one.clone(),
            &one * 0.1,
            one.clone(),
            DVector::zeros(1),
            one,
        )
        .unwrap()
    }

    #[test]
    fn a_tape_holds_the_runs_of_the_shares_it_was_given_and_covers_only_those() {
        let truth = walk();
        let mc = McConfig::new(100, 5).unwrap().with_seed(3);
        let (first, second) = (Share::runs(0, 2).unwrap(), Share::runs(1, 2).unwrap());
        let whole = TruthTape::record(&truth, 3, 5, 100);
        let mut tape = TruthTape::record_share(&truth, 3, 5, 100, second);
        assert_eq!(tape.runs(), 100);
        assert!(tape.covers(&mc, second));
        assert!(!tape.covers(&mc, first) && !tape.covers(&mc, Share::WHOLE));
        assert!(!tape.covers(&mc.with_seed(4), second));
        assert!(!tape.covers(&mc.with_steps(6).unwrap(), second));
        assert!(!tape.covers(&mc.with_runs(101).unwrap(), second));
        // Fewer runs, dealt by runs, are other runs of each chunk: not held.
        assert!(!tape.covers(&mc.with_runs(90).unwrap(), second));
        let half = tape.bytes();
        assert!(half > 0 && half < whole.bytes());
        // The other share's runs join them, each run once: the whole tape's bytes.
        tape.extend(&truth, 100, first);
        assert!(tape.covers(&mc, Share::WHOLE) && tape.covers(&mc, first));
        assert_eq!(tape.bytes(), whole.bytes());
        tape.extend(&truth, 100, Share::WHOLE);
        assert_eq!(tape.bytes(), whole.bytes());
        // More runs than held: the tape grows to them.
        tape.extend(&truth, 130, second);
        assert_eq!(tape.runs(), 130);
        assert!(tape.covers(&mc.with_runs(130).unwrap(), second));
        // A run at or past the runs asked for is not recorded.
        let before = tape.bytes();
        tape.record_runs(&truth, &[130], 130);
        assert_eq!((tape.runs(), tape.bytes()), (130, before));
    }

    #[test]
    fn a_cache_tapes_at_the_second_evaluation_and_counts_as_one_process_across_deals() {
        let truth = walk();
        let mc = |runs: usize, seed: u64| McConfig::new(runs, 5).unwrap().with_seed(seed);
        let cache = TruthCache::default();
        let usage = |c: &TruthCache| (c.usage().simulated, c.usage().replayed);
        assert!(cache.tape(&truth, &mc(200, 3), Share::WHOLE).is_none());
        let t = cache.tape(&truth, &mc(200, 3), Share::WHOLE).unwrap();
        assert!(t.covers(&mc(200, 3), Share::WHOLE));
        assert!(cache.tape(&truth, &mc(200, 4), Share::WHOLE).is_none());
        assert!(cache.tape(&truth, &mc(200, 4), Share::WHOLE).is_some());
        assert_eq!(usage(&cache), (4, 0));
        // Fewer runs replay; more runs extend the same seed set's tape, the other kept.
        assert!(cache.tape(&truth, &mc(100, 3), Share::WHOLE).is_some());
        let t = cache.tape(&truth, &mc(300, 3), Share::WHOLE).unwrap();
        assert!(t.covers(&mc(300, 3), Share::WHOLE) && t.seed == 3);
        assert_eq!(usage(&cache), (5, 1));
        assert!(cache.tape(&truth, &mc(200, 4), Share::WHOLE).is_some());
        assert_eq!(usage(&cache), (5, 2));
        let whole = TruthTape::record(&truth, 3, 5, 300).bytes();
        assert_eq!(
            cache.bytes(),
            whole + TruthTape::record(&truth, 4, 5, 200).bytes()
        );
        // A rank's share: taped by chunks at 200 runs, then dealt by runs at 100, whose runs
        // it lacks: taped now, and counted as the one process counts it, replayed.
        let rank = TruthCache::default();
        let chunks = Share::new(0, 3).unwrap();
        rank.tape(&truth, &mc(200, 3), chunks);
        rank.tape(&truth, &mc(200, 3), chunks);
        let runs = Share::runs(0, 3).unwrap();
        let t = rank.tape(&truth, &mc(100, 3), runs).unwrap();
        assert!(t.covers(&mc(100, 3), runs));
        assert_eq!(usage(&rank), (2, 1));
    }

    #[test]
    fn a_tape_that_fits_the_limit_exactly_is_kept_and_one_a_byte_over_is_not() {
        let truth = walk();
        let mc = McConfig::new(100, 5).unwrap().with_seed(3);
        let size = TruthTape::record(&truth, 3, 5, 100).bytes();
        for (limit, kept) in [(size, true), (size - 1, false)] {
            let cache = TruthCache::with_limit(limit);
            cache.tape(&truth, &mc, Share::WHOLE);
            let tape = cache.tape(&truth, &mc, Share::WHOLE);
            assert_eq!(tape.is_some(), kept, "limit {limit} of {size} bytes");
        }
    }
}
