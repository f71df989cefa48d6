//! The ranks of an MPI job share every evaluation (the cargo feature `mpi`).
//!
//! Rank 0 runs the command (the check, the tuner's search) on a [`Ranked`] experiment: each
//! evaluation is sent to every rank, each rank computes its share with its own engine and
//! workers, and rank 0 merges all chunks in chunk order, so every number is the
//! one-process number, bit for bit. The other ranks [`serve`] until rank 0 says [`stop`].
//!
//! A share is dealt by chunks (chunk `c` is rank `c mod K`'s) or, for an evaluation of too
//! few chunks to keep every rank busy, by runs within every chunk ([`Share::runs`], where
//! the experiment [`Sampling::splits_runs`]): a tune's evaluations are one to four chunks
//! (a search's 60 runs are one), which ranks dealt chunks could not share. Which way is a
//! function of the evaluation's run count and K alone ([`deal_by_runs`]); a rank's truth
//! tape holds every run of a seed set it computed, whichever way they were dealt.
//!
//! A rank waiting for a request or an answer probes and sleeps rather than spinning in
//! MPI's receive, so that a waiting rank takes no CPU (ranks oversubscribing a machine, and
//! the CPU time per rank the scaling measurements report).
//!
//! MPI is initialized with `MPI_THREAD_MULTIPLE`: the tuner evaluates several candidates at
//! once (its confirmation seeds), each on its own thread; an evaluation's request carries
//! its own tag, and its answers are received by that tag from whichever rank answers first.
//!
//! A rank that cannot answer (its worker failed, its input is bad, a signal) prints one line
//! naming itself and exits 2; Open MPI then ends the job, whose exit code is that 2. A rank
//! killed by SIGKILL cannot say anything: Open MPI ends the job, naming the rank, with 137.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use mpi::topology::SimpleCommunicator;
use mpi::traits::{Communicator, Destination, Equivalence, Source};

mod wire;

use self::wire::{Request, decode_answer_into, encode_answer_into};
use super::{deal_by_runs, empty_sums, share_sums};
use crate::experiment::{
    Block, Covariances, Definition, Experiment, ExperimentError, LinearExperiment, TruthReuse,
};
use crate::montecarlo::{Engine, McConfig, RunMerge, RunOptions, Share, TapeUsage};
use crate::params::Target;
use crate::stats::Accumulator;

/// Requests from rank 0 travel with this tag; answers with the request's own.
const REQUEST: i32 = 1;
/// Answers' tags: `FIRST_ANSWER + id mod ANSWER_TAGS` (MPI guarantees tags up to 32767).
const FIRST_ANSWER: i32 = 2;
const ANSWER_TAGS: u64 = 30_000;

/// An initialized MPI job: this process's rank and the job's size. MPI is finalized when it
/// is dropped.
pub struct Mpi {
    world: World,
    _universe: mpi::environment::Universe,
}

/// The job's communicator, shared by the threads that evaluate at once.
pub struct World(SimpleCommunicator);

// SAFETY: MPI was initialized with MPI_THREAD_MULTIPLE (`Mpi::init` refuses anything less),
// under which any thread may call MPI on the communicator at any time.
unsafe impl Sync for World {}
// SAFETY: as above; the communicator is a handle that any thread may use.
unsafe impl Send for World {}

impl World {
    /// This process's rank, 0-based.
    pub fn rank(&self) -> usize {
        self.0.rank() as usize
    }

    /// Ranks in the job.
    pub fn size(&self) -> usize {
        self.0.size() as usize
    }
}

/// Whether this process was started by an MPI launcher (`mpirun`, `mpiexec`, `srun`): the
/// environment variables Open MPI, PMIx and MPICH's PMI give each rank.
pub fn launched() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_SIZE", "PMI_RANK"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

/// Why MPI could not be started for autotune ([`Mpi::init`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MpiError {
    /// This process initialized MPI before.
    #[error("MPI was initialized already")]
    Initialized,
    /// The MPI library gives less thread support than autotune's threads need.
    #[error("this MPI gives threads {0} support; autotune needs MPI_THREAD_MULTIPLE")]
    Threading(String),
}

impl Mpi {
    /// Initialize MPI with full thread support.
    pub fn init() -> Result<Mpi, MpiError> {
        let (universe, threading) = mpi::initialize_with_threading(mpi::Threading::Multiple)
            .ok_or(MpiError::Initialized)?;
        if threading != mpi::Threading::Multiple {
            return Err(MpiError::Threading(format!("{threading:?}")));
        }
        Ok(Mpi {
            world: World(universe.world()),
            _universe: universe,
        })
    }

    /// The job's communicator.
    pub fn world(&self) -> &World {
        &self.world
    }
}

/// What rank 0's evaluations cost in communication, for the scaling measurements.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CommStats {
    /// Evaluations shared among the ranks.
    pub evaluations: usize,
    /// Of them, those dealt by runs within every chunk ([`deal_by_runs`]).
    pub by_runs: usize,
    /// Bytes sent in requests.
    pub request_bytes: usize,
    /// Bytes received in answers.
    pub answer_bytes: usize,
    /// Time rank 0 spent waiting for answers after its own share was done, s.
    pub waiting_s: f64,
    /// Time rank 0 spent decoding the answers and merging every rank's sums, s: work no
    /// other rank shares.
    pub merging_s: f64,
}

/// An experiment whose evaluations rank 0 shares among the job's ranks; everything else is
/// the inner experiment's. Recorded sums ([`Sampling::splits`] false) and the altered
/// experiments of an explanation ([`Experiment::alter`]) are evaluated on rank 0 alone.
pub struct Ranked<'a> {
    inner: &'a dyn Experiment,
    world: &'a World,
    next_id: AtomicU64,
    stats: Mutex<CommStats>,
    /// What answers are received and read into, taken by one evaluation at a time.
    inbox: Mutex<Inbox>,
}

/// Rank 0's buffers for the ranks' answers, kept from one evaluation to the next: fresh ones
/// for each of a tune's thousands of runs would fault in and zero fresh pages.
#[derive(Default)]
struct Inbox {
    /// An answer's bytes.
    bytes: Vec<u8>,
    /// Its pieces' indices and sums (the first of them, as many as it has).
    pieces: Vec<(usize, Accumulator)>,
}

impl<'a> Ranked<'a> {
    /// `inner` shared among `world`'s ranks, from rank 0 (the others [`serve`] it).
    pub fn new(inner: &'a dyn Experiment, world: &'a World) -> Self {
        Ranked {
            inner,
            world,
            next_id: AtomicU64::new(0),
            stats: Mutex::new(CommStats::default()),
            inbox: Mutex::new(Inbox::default()),
        }
    }

    /// The communication so far.
    pub fn stats(&self) -> CommStats {
        *self.stats.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn shared(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let size = self.world.size();
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let tag = FIRST_ANSWER + (id % ANSWER_TAGS) as i32;
        let by_runs = deal_by_runs(mc.runs(), size, self.inner.splits_runs());
        let request = Request {
            tag,
            theta: theta.to_vec(),
            mc: *mc,
            engine: options.engine,
            by_runs,
        }
        .encode();
        for r in 1..size {
            self.world
                .0
                .process_at_rank(r as i32)
                .send_with_tag(&request[..], REQUEST);
        }
        let own = request_share(0, size, by_runs).expect("rank 0 of a job of size >= 1");
        let mut mine = share_sums(self.inner, theta, mc, options, own)?;
        let refused = |rank: usize, message: String| ExperimentError::Rank {
            rank,
            ranks: size,
            message,
        };
        let merge_error =
            |e: crate::montecarlo::MergeError| refused(0, format!("the ranks' sums: {e}"));
        // Dealt by runs, every chunk's runs come rank by rank in rank order, each rank's
        // in run order: added into the chunks' sums as each answer comes, rank 0 holds the
        // chunks' sums and one answer. Dealt by chunks, it holds every chunk's sums.
        let mut by_run = by_runs.then(|| RunMerge::new(mc.runs(), || empty_sums(self.inner, mc)));
        let mut parts = Vec::new();
        let (mut waited, mut merging, mut answer_bytes) = (Duration::ZERO, Duration::ZERO, 0);
        // Its first `n` pieces: added where dealt by runs, kept where dealt by chunks.
        let mut take =
            |theirs: &mut Vec<(usize, Accumulator)>, n: usize| -> Result<(), ExperimentError> {
                match by_run.as_mut() {
                    Some(m) => theirs[..n]
                        .iter()
                        .try_for_each(|(r, sums)| m.add(*r, sums))
                        .map_err(merge_error),
                    None => {
                        parts.extend(theirs.drain(..n));
                        Ok(())
                    }
                }
            };
        let n = mine.len();
        take(&mut mine, n)?;
        // Evaluations side by side take turns with one inbox: the second finds it empty.
        let mut inbox = std::mem::take(&mut *self.inbox.lock().unwrap_or_else(|p| p.into_inner()));
        for rank in 1..size {
            let waiting = Instant::now();
            // By runs, in rank order; by chunks, whichever answers first.
            let from = receive(self.world, by_runs.then_some(rank), tag, &mut inbox.bytes);
            let decoding = Instant::now();
            waited += decoding - waiting;
            answer_bytes += inbox.bytes.len();
            let n = decode_answer_into(&inbox.bytes, mc, self.inner, by_runs, &mut inbox.pieces)
                .map_err(|why| refused(from, format!("its answer: {why}")))?;
            take(&mut inbox.pieces, n)?;
            merging += decoding.elapsed();
        }
        *self.inbox.lock().unwrap_or_else(|p| p.into_inner()) = inbox;
        let finishing = Instant::now();
        if let Some(m) = by_run {
            parts = m.finish().map_err(merge_error)?;
        }
        let merged =
            Share::merge(mc.runs(), empty_sums(self.inner, mc), parts).map_err(merge_error);
        merging += finishing.elapsed();
        let mut s = self.stats.lock().unwrap_or_else(|p| p.into_inner());
        s.evaluations += 1;
        s.by_runs += usize::from(by_runs);
        s.request_bytes += request.len() * (size - 1);
        s.answer_bytes += answer_bytes;
        s.waiting_s += waited.as_secs_f64();
        s.merging_s += merging.as_secs_f64();
        merged
    }
}

/// Rank `rank`'s share of `size`, dealt by runs or by chunks.
fn request_share(
    rank: usize,
    size: usize,
    by_runs: bool,
) -> Result<Share, crate::input::SettingError> {
    if by_runs {
        Share::runs(rank, size)
    } else {
        Share::new(rank, size)
    }
}

/// The longest a waiting rank sleeps between probes: a message waits at most this long to
/// be received, against evaluations of tens of milliseconds and more.
const MAX_NAP: Duration = Duration::from_micros(500);

/// The next message tagged `tag` (from rank `from`, or any) into `buf` (resized to it), and
/// its sender: probed for with naps that double from 10 µs to [`MAX_NAP`], so that waiting
/// takes no CPU (MPI's blocking receive spins). One buffer serves every answer rank 0
/// receives: a fresh one each time would fault in and zero fresh pages.
fn receive(world: &World, from: Option<usize>, tag: i32, buf: &mut Vec<u8>) -> usize {
    let mut nap = Duration::from_micros(10);
    loop {
        let found = match from {
            Some(r) => world
                .0
                .process_at_rank(r as i32)
                .immediate_matched_probe_with_tag(tag),
            None => world.0.any_process().immediate_matched_probe_with_tag(tag),
        };
        if let Some((message, status)) = found {
            let len = usize::try_from(status.count(u8::equivalent_datatype())).unwrap_or(0);
            buf.clear();
            buf.resize(len, 0);
            let status = message.matched_receive_into(&mut buf[..]);
            return status.source_rank() as usize;
        }
        std::thread::sleep(nap);
        nap = (nap * 2).min(MAX_NAP);
    }
}

/// This process's CPU time so far (every thread's, user and system), s.
pub fn cpu_seconds() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given; the clock id is a constant
    // every Linux has.
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) } == 0;
    if ok {
        t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
    } else {
        f64::NAN
    }
}

/// Tell every other rank that the job is over (rank 0, when its command is done, before it
/// prints and exits): they return from [`serve`].
pub fn stop(world: &World) {
    for r in 1..world.size() {
        world
            .0
            .process_at_rank(r as i32)
            .send_with_tag::<[u8]>(&[], REQUEST);
    }
}

/// A rank other than 0: compute this rank's share of each evaluation rank 0 asks for, until
/// it says [`stop`]. `Err` (the rank's evaluation failed, or a request was not one) is for
/// the caller to print, naming the rank, and exit 2 on: rank 0 is waiting for the answer.
pub fn serve(experiment: &dyn Experiment, world: &World) -> Result<(), ExperimentError> {
    let (rank, size) = (world.rank(), world.size());
    let refused = |message: String| ExperimentError::Rank {
        rank,
        ranks: size,
        message,
    };
    // Kept from one evaluation to the next, as rank 0 keeps its inbox.
    let (mut bytes, mut answer) = (Vec::new(), Vec::new());
    loop {
        receive(world, Some(0), REQUEST, &mut bytes);
        if bytes.is_empty() {
            return Ok(());
        }
        let req = Request::decode(&bytes).ok_or_else(|| {
            refused("a request from rank 0 that is not one (another autotune's?)".into())
        })?;
        let share = request_share(rank, size, req.by_runs).map_err(|e| refused(e.to_string()))?;
        let options = RunOptions {
            engine: req.engine,
            ..RunOptions::default()
        };
        let parts = share_sums(experiment, &req.theta, &req.mc, options, share)?;
        encode_answer_into(&mut answer, &parts, &req.mc, experiment, req.by_runs);
        send(world, &answer, req.tag);
    }
}

/// `bytes` to rank 0 tagged `tag`, waiting for the send to complete with naps as
/// [`receive`] does: an answer larger than MPI's eager limit waits for rank 0 to receive
/// it, which a blocking send would spin through.
fn send(world: &World, bytes: &[u8], tag: i32) {
    mpi::request::scope(|scope| {
        let mut pending = world
            .0
            .process_at_rank(0)
            .immediate_send_with_tag(scope, bytes, tag);
        let mut nap = Duration::from_micros(10);
        loop {
            match pending.test() {
                Ok(_) => return,
                Err(still) => pending = still,
            }
            std::thread::sleep(nap);
            nap = (nap * 2).min(MAX_NAP);
        }
    });
}

impl Experiment for Ranked<'_> {
    fn definition(&self) -> &Definition {
        self.inner.definition()
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        // A share asked of this experiment (a shard of a shard) and unsplittable sums stay
        // in this process.
        if self.world.size() == 1 || options.share.is_some() || !self.inner.splits() {
            return self.inner.monte_carlo_with(theta, mc, options);
        }
        self.shared(theta, mc, options)
    }
}

impl crate::experiment::Structure for Ranked<'_> {
    fn supports(&self, engine: Engine) -> bool {
        self.inner.supports(engine)
    }

    fn expected(&self, theta: &[f64], mc: &McConfig) -> Option<Accumulator> {
        self.inner.expected(theta, mc)
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.inner.target(i)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.inner.covariances(theta)
    }

    fn blocks(&self) -> Option<Vec<Block>> {
        self.inner.blocks()
    }

    fn truth_values(&self) -> Option<Vec<f64>> {
        self.inner.truth_values()
    }

    fn linear(&self) -> Option<&LinearExperiment> {
        self.inner.linear()
    }
}

impl crate::experiment::HeldAsCode for Ranked<'_> {
    // A hypothesis trial's corrected readings run in this process, whole: the same sums as
    // one process gives, so a tune's explanations do not depend on the rank count.
    fn monte_carlo_corrected(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
        correction: &crate::filter::Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        self.inner
            .monte_carlo_corrected(theta, mc, options, correction)
    }

    fn innovation_scales(&self, theta: &[f64], mc: &McConfig) -> Option<Vec<f64>> {
        self.inner.innovation_scales(theta, mc)
    }
}

impl crate::experiment::Sampling for Ranked<'_> {
    fn seed_free(&self) -> bool {
        self.inner.seed_free()
    }

    fn splits(&self) -> bool {
        self.inner.splits()
    }

    fn splits_runs(&self) -> bool {
        self.inner.splits_runs()
    }

    fn truth_reuse(&self, since: TapeUsage) -> TruthReuse {
        self.inner.truth_reuse(since)
    }

    fn tape_usage(&self) -> TapeUsage {
        self.inner.tape_usage()
    }
}
