//! The ranks of an MPI job share every evaluation (the cargo feature `mpi`).
//!
//! Rank 0 runs the command (the check, the tuner's search) on a [`Ranked`] experiment: each
//! evaluation is sent to every rank, each rank computes its share of the chunks (chunk `c`
//! is rank `c mod K`'s) with its own engine and workers, and rank 0 merges all chunks in
//! chunk order, so every number is the one-process number, bit for bit. The other ranks
//! [`serve`] until rank 0 says [`stop`].
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
use std::time::Instant;

use mpi::topology::SimpleCommunicator;
use mpi::traits::{Communicator, Destination, Source};

use super::{SumsShape, empty_sums, share_sums};
use crate::experiment::{
    Block, Covariances, Definition, Experiment, ExperimentError, LinearExperiment, TruthReuse,
};
use crate::montecarlo::{Engine, McConfig, RunOptions, Share, TapeUsage};
use crate::params::Target;
use crate::stats::{Accumulator, GateMode};

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

/// Why a rank's answer does not decode (it is refused, with the rank named).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum AnswerError {
    #[error("it ends early")]
    EndsEarly,
    #[error("a count out of range")]
    CountOutOfRange,
    #[error("chunk {0} is beyond the evaluation's runs")]
    BeyondRuns(usize),
    #[error(transparent)]
    Wire(#[from] crate::records::WireError),
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
    /// Bytes sent in requests.
    pub request_bytes: usize,
    /// Bytes received in answers.
    pub answer_bytes: usize,
    /// Time rank 0 spent waiting for answers after its own share was done, s.
    pub waiting_s: f64,
}

/// An experiment whose evaluations rank 0 shares among the job's ranks; everything else is
/// the inner experiment's. Recorded sums ([`Sampling::splits`] false) and the altered
/// experiments of an explanation ([`Experiment::alter`]) are evaluated on rank 0 alone.
pub struct Ranked<'a> {
    inner: &'a dyn Experiment,
    world: &'a World,
    next_id: AtomicU64,
    stats: Mutex<CommStats>,
}

impl<'a> Ranked<'a> {
    /// `inner` shared among `world`'s ranks, from rank 0 (the others [`serve`] it).
    pub fn new(inner: &'a dyn Experiment, world: &'a World) -> Self {
        Ranked {
            inner,
            world,
            next_id: AtomicU64::new(0),
            stats: Mutex::new(CommStats::default()),
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
        let request = Request {
            tag,
            theta: theta.to_vec(),
            mc: *mc,
            engine: options.engine,
        }
        .encode();
        for r in 1..size {
            self.world
                .0
                .process_at_rank(r as i32)
                .send_with_tag(&request[..], REQUEST);
        }
        let own = Share::new(0, size).expect("rank 0 of a job of size >= 1");
        let mut parts = share_sums(self.inner, theta, mc, options, own)?;
        let waiting = Instant::now();
        let mut answer_bytes = 0;
        for _ in 1..size {
            let (bytes, status) = self.world.0.any_process().receive_vec_with_tag::<u8>(tag);
            let rank = status.source_rank() as usize;
            answer_bytes += bytes.len();
            let theirs =
                decode_answer(&bytes, mc, self.inner).map_err(|why| ExperimentError::Rank {
                    rank,
                    ranks: size,
                    message: format!("its answer: {why}"),
                })?;
            parts.extend(theirs);
        }
        let waited = waiting.elapsed();
        {
            let mut s = self.stats.lock().unwrap_or_else(|p| p.into_inner());
            s.evaluations += 1;
            s.request_bytes += request.len() * (size - 1);
            s.answer_bytes += answer_bytes;
            s.waiting_s += waited.as_secs_f64();
        }
        Share::merge(mc.runs(), empty_sums(self.inner, mc), parts).map_err(|e| {
            ExperimentError::Rank {
                rank: 0,
                ranks: size,
                message: format!("the ranks' chunks: {e}"),
            }
        })
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
    let share = Share::new(rank, size).map_err(|e| ExperimentError::Rank {
        rank,
        ranks: size,
        message: e.to_string(),
    })?;
    loop {
        let (bytes, _) = world
            .0
            .process_at_rank(0)
            .receive_vec_with_tag::<u8>(REQUEST);
        if bytes.is_empty() {
            return Ok(());
        }
        let req = Request::decode(&bytes).ok_or_else(|| ExperimentError::Rank {
            rank,
            ranks: size,
            message: "a request from rank 0 that is not one (another autotune's?)".into(),
        })?;
        let options = RunOptions {
            engine: req.engine,
            ..RunOptions::default()
        };
        let parts = share_sums(experiment, &req.theta, &req.mc, options, share)?;
        let answer = encode_answer(&parts, &req.mc, experiment);
        world
            .0
            .process_at_rank(0)
            .send_with_tag(&answer[..], req.tag);
    }
}

/// An evaluation as rank 0 asks for it.
struct Request {
    tag: i32,
    theta: Vec<f64>,
    mc: McConfig,
    engine: Engine,
}

impl Request {
    fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut u = |x: u64| out.extend_from_slice(&x.to_le_bytes());
        u(self.tag as u64);
        u(self.theta.len() as u64);
        for t in &self.theta {
            u(t.to_bits());
        }
        let mc = &self.mc;
        for x in [mc.runs(), mc.steps(), mc.lags()] {
            u(x as u64);
        }
        u(mc.seed());
        u(mc.alpha().to_bits());
        u(match mc.gate() {
            GateMode::Full => 0,
            GateMode::Mean => 1,
        });
        u(match self.engine {
            Engine::Auto => 0,
            Engine::Linear => 1,
            Engine::Generic => 2,
        });
        out
    }

    fn decode(bytes: &[u8]) -> Option<Request> {
        let mut words = bytes
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")));
        let mut next = || words.next();
        let tag = i32::try_from(next()?).ok()?;
        let n = usize::try_from(next()?).ok()?;
        let theta = (0..n)
            .map(|_| next().map(f64::from_bits))
            .collect::<Option<Vec<f64>>>()?;
        let (runs, steps, lags) = (next()?, next()?, next()?);
        let (seed, alpha) = (next()?, f64::from_bits(next()?));
        let gate = [GateMode::Full, GateMode::Mean]
            .get(next()? as usize)
            .copied()?;
        let engine = [Engine::Auto, Engine::Linear, Engine::Generic]
            .get(next()? as usize)
            .copied()?;
        let mc = McConfig::new(runs, steps)
            .and_then(|m| m.with_alpha(alpha))
            .and_then(|m| m.with_lags(lags))
            .ok()?
            .with_seed(seed)
            .with_gate(gate);
        Some(Request {
            tag,
            theta,
            mc,
            engine,
        })
    }
}

/// A rank's chunk sums: the count, then each chunk's index, length and sums format bytes.
fn encode_answer(parts: &[(usize, Accumulator)], mc: &McConfig, e: &dyn Experiment) -> Vec<u8> {
    let shape = SumsShape::of(e, mc);
    let mut out = (parts.len() as u64).to_le_bytes().to_vec();
    for (c, sums) in parts {
        let bytes = shape.encode(*c, sums);
        out.extend_from_slice(&(*c as u64).to_le_bytes());
        out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
        out.extend_from_slice(&bytes);
    }
    out
}

fn decode_answer(
    bytes: &[u8],
    mc: &McConfig,
    e: &dyn Experiment,
) -> Result<Vec<(usize, Accumulator)>, AnswerError> {
    let mut at = 0;
    fn word(bytes: &[u8], at: &mut usize) -> Result<usize, AnswerError> {
        let b = bytes.get(*at..*at + 8).ok_or(AnswerError::EndsEarly)?;
        *at += 8;
        usize::try_from(u64::from_le_bytes(b.try_into().expect("8 bytes")))
            .map_err(|_| AnswerError::CountOutOfRange)
    }
    let shape = SumsShape::of(e, mc);
    let n = word(bytes, &mut at)?;
    let mut parts = Vec::with_capacity(n.min(1 << 16));
    for _ in 0..n {
        let c = word(bytes, &mut at)?;
        let len = word(bytes, &mut at)?;
        let body = bytes
            .get(at..at.saturating_add(len))
            .ok_or(AnswerError::EndsEarly)?;
        at += len;
        if c >= shape.chunks() {
            return Err(AnswerError::BeyondRuns(c));
        }
        parts.push((c, shape.decode(c, body)?));
    }
    Ok(parts)
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

    fn truth_reuse(&self, since: TapeUsage) -> TruthReuse {
        self.inner.truth_reuse(since)
    }

    fn tape_usage(&self) -> TapeUsage {
        self.inner.tape_usage()
    }
}
