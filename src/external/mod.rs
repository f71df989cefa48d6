//! A filter and simulator in another program (Python, MATLAB/Octave, C++, …) as an
//! [`Experiment`]: autotune starts the program as long-lived workers and asks them, over the
//! line protocol of `docs/external.md`, for the records of the filter at parameter values θ,
//! seed s and runs [a, b). The records stream into the sums chunk by chunk.
//!
//! Reproducibility: runs are asked for in the engine's fixed chunks of
//! [`crate::montecarlo::CHUNK`] runs, whatever the number of workers, and the chunk sums
//! are merged in chunk order; a worker that honours the seed contract (run i's noise from
//! (seed, i) alone) therefore gives bit-identical statistics on any number of workers. The
//! contract is checked once, on the first evaluation: the first chunk's runs must not all
//! be the same run, and asked for again (as two halves, the second first, from another
//! worker or a fresh one) each run must come back bit for bit.
//!
//! Scratch directories and worker process groups are owned by one module (`scratch`):
//! made private and fresh, a worker's file answers contained in them, and everything
//! removed and stopped on every exit path, an interrupt included
//! ([`stop_workers_and_remove_scratch`]).

mod answer;
mod contract;
mod fingerprint;
mod replay;
mod scratch;
mod worker;

pub use answer::{ChunkError, WorkerChunk};
pub use replay::WorkerReplay;

pub use scratch::stop_workers_and_remove_scratch;

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use crate::experiment::{
    Definition, Experiment, ExperimentError, RequestInfo, RunOptions, StartFailure, WorkerError,
    WorkerFailure, WorkerRole,
};
use crate::montecarlo::{CHUNK, McConfig, Share};
use crate::params::Target;
use crate::records::{Layout, RecordSink, WireError};
use crate::stats::Accumulator;
use fingerprint::{Fingerprinting, Fingerprints};
use worker::{Request, Worker};

/// How to run the worker program.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerCommand {
    /// The program and its arguments.
    pub command: Vec<String>,
    /// The directory it runs in (a problem file's own).
    pub dir: PathBuf,
    /// Workers started in parallel (each answers whole chunks of runs).
    pub workers: usize,
    /// Longest wait for one answer, start-up included.
    pub timeout: Duration,
    /// Check the seed contract on the first evaluation.
    pub check_seed_contract: bool,
}

impl WorkerCommand {
    /// The command as one would type it.
    pub fn display(&self) -> String {
        self.command.join(" ")
    }
}

/// An experiment run by an external worker program.
pub struct ExternalExperiment {
    definition: Definition,
    layout: Layout,
    command: WorkerCommand,
    truth: Option<Vec<f64>>,
    /// What each parameter drives, where declared.
    targets: Vec<Option<Target>>,
    /// The running workers, started at the first evaluation.
    pool: Mutex<Vec<Worker>>,
    /// The first failure: the workers are gone, and every later evaluation gives it again.
    failed: Mutex<Option<ExperimentError>>,
    next_id: AtomicU64,
    contract_checked: AtomicBool,
    /// A worker said its runs are a recording it replays (`"replays": true`): the sums do
    /// not depend on the seed, so there is no seed contract to check and no fresh seed to
    /// confirm on.
    replays: AtomicBool,
}

impl std::fmt::Debug for ExternalExperiment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExternalExperiment")
            .field("definition", &self.definition)
            .field("command", &self.command)
            .finish_non_exhaustive()
    }
}

impl ExternalExperiment {
    /// An experiment whose records, of `layout`, come from `command`; `truth` is the
    /// parameter values equal to the simulated noise, where known.
    pub fn new(
        definition: Definition,
        layout: Layout,
        command: WorkerCommand,
        truth: Option<Vec<f64>>,
    ) -> Self {
        ExternalExperiment {
            definition,
            layout,
            command,
            truth,
            targets: Vec::new(),
            pool: Mutex::new(Vec::new()),
            failed: Mutex::new(None),
            next_id: AtomicU64::new(1),
            contract_checked: AtomicBool::new(false),
            replays: AtomicBool::new(false),
        }
    }

    /// Declare what each parameter drives (by index; `None` where unknown): the advice
    /// names that evidence and the Gauss–Newton search matches it.
    pub fn with_targets(mut self, targets: Vec<Option<Target>>) -> Self {
        self.targets = targets;
        self
    }

    /// The worker command.
    pub fn command(&self) -> &WorkerCommand {
        &self.command
    }

    /// The records' layout.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The error of `worker`'s request `req`.
    fn error(&self, w: &Worker, req: &Request<'_>, failure: WorkerFailure) -> ExperimentError {
        let worker = if w.index < self.command.workers {
            WorkerRole::Pool {
                index: w.index,
                of: self.command.workers,
            }
        } else {
            WorkerRole::ContractCheck
        };
        ExperimentError::Worker(Box::new(WorkerError {
            command: self.command.display(),
            worker,
            request: RequestInfo {
                id: req.id,
                seed: req.seed,
                runs: req.runs.clone(),
                steps: req.steps,
            },
            failure,
            stderr: w.stderr_tail(),
        }))
    }

    /// The error of a worker that did not start (`for_contract_check`: a fresh one for the
    /// seed-contract check).
    fn start_error(&self, for_contract_check: bool, why: StartFailure) -> ExperimentError {
        ExperimentError::WorkerStart {
            command: self.command.display(),
            dir: self.command.dir.clone(),
            for_contract_check,
            why,
        }
    }

    /// θ as the request's JSON object, in parameter order.
    fn theta_json(&self, theta: &[f64]) -> String {
        let pairs: Vec<String> = self
            .definition
            .params
            .params
            .iter()
            .zip(theta)
            .map(|(p, v)| {
                format!(
                    "{}:{}",
                    serde_json::to_string(&p.name).expect("a string serializes"),
                    serde_json::to_string(v).expect("a number serializes")
                )
            })
            .collect();
        format!("{{{}}}", pairs.join(","))
    }

    fn sink(&self, mc: &McConfig, runs: std::ops::Range<usize>) -> RecordSink {
        RecordSink::new(&self.layout, mc.steps(), mc.lags()).expecting(runs)
    }

    /// Ask worker `w` for `runs` and sum them; with `prints`, also fingerprint each run's
    /// records into it.
    fn ask(
        &self,
        w: &mut Worker,
        theta: &str,
        mc: &McConfig,
        runs: std::ops::Range<usize>,
        prints: Option<&mut Fingerprints>,
    ) -> Result<Accumulator, ExperimentError> {
        let sums_fields = answer::request_fields(&self.layout, mc.lags());
        let req = Request {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            theta,
            seed: mc.seed(),
            runs: runs.clone(),
            steps: mc.steps(),
            lags: mc.lags(),
            sums_fields: &sums_fields,
            replay: None,
        };
        let mut sink = self.sink(mc, runs.clone());
        let mut prints = prints;
        let asked = match prints.as_deref_mut() {
            Some(prints) => {
                let mut tee = Fingerprinting {
                    sink: &mut sink,
                    prints,
                };
                w.request(&req, &self.layout, &mut tee, self.command.timeout)
            }
            None => w.request(&req, &self.layout, &mut sink, self.command.timeout),
        };
        if let Ok(reply) = &asked
            && reply.replays
        {
            self.replays.store(true, Ordering::Relaxed);
        }
        let summed = match asked.map(|reply| reply.sums) {
            Ok(None) => sink.finish().map_err(WorkerFailure::from),
            // Inline records and then sums would count runs twice.
            Ok(Some(_)) if sink.runs() > 0 => Err(WorkerFailure::Sums(WireError::AfterRecords)),
            Ok(Some(chunk)) => {
                if let Some(prints) = prints {
                    prints.0.extend(runs.zip(chunk.prints));
                }
                Ok(chunk.sums)
            }
            Err(e) => Err(e),
        };
        summed.map_err(|failure| self.error(w, &req, failure))
    }

    fn run(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let mut pool = self.pool.lock().unwrap_or_else(|p| p.into_inner());
        self.fill(&mut pool)?;
        let theta_json = self.theta_json(theta);
        let runs = mc.runs();
        // This process's chunks, in order: all of them, or a share's (a shard, an MPI rank).
        let share = options.share.map_or(Share::WHOLE, |s| s.share);
        // Taken a wave at a time: nothing is sized by N (up to 10¹² runs), only by a wave.
        let mut own = share.chunks(runs.div_ceil(CHUNK)).peekable();
        let mut total =
            Accumulator::new(mc.steps(), self.layout.n_x(), self.layout.n_z(), mc.lags());
        // The first chunk's runs, fingerprinted for the seed-contract check.
        let checking = self.command.check_seed_contract
            && !self.contract_checked.load(Ordering::Relaxed)
            && runs > 0
            && share.owns_chunk(0);
        let first_prints: Mutex<Option<Fingerprints>> =
            Mutex::new(checking.then(Fingerprints::new));
        // Waves of a few chunks per worker, merged in chunk order as they complete: memory
        // holds one wave's sums whatever N.
        let wave = 4 * pool.len();
        let mut done = 0;
        while own.peek().is_some() {
            let wave_chunks: &[usize] = &own.by_ref().take(wave).collect::<Vec<_>>();
            let asked = Asked {
                theta: &theta_json,
                mc,
                stride: share.count(),
                first_prints: &first_prints,
            };
            let parts = self.ask_wave(&mut pool, wave_chunks, &asked)?;
            for (part, &c) in parts.into_iter().zip(wave_chunks) {
                done += part.runs;
                match options.share {
                    Some(to) => (to.sink)(c, part),
                    None => total.merge(&part),
                }
            }
            if let Some(report) = options.progress {
                report(done);
            }
        }
        // A worker that replays a recording gives the same runs whatever the seed.
        if !self.contract_checked.swap(true, Ordering::Relaxed)
            && !self.replays.load(Ordering::Relaxed)
            && let Some(first) = first_prints.into_inner().unwrap_or_else(|p| p.into_inner())
        {
            self.check_contract(&mut pool, &theta_json, mc, &first)?;
        }
        Ok(total)
    }

    /// The sums of `chunks` (one wave), in their order, each asked of its worker: the
    /// workers answer side by side, and the first failure stops the wave.
    fn ask_wave(
        &self,
        pool: &mut [Worker],
        chunks: &[usize],
        asked: &Asked<'_>,
    ) -> Result<Vec<Accumulator>, ExperimentError> {
        let (mc, n_workers) = (asked.mc, pool.len());
        let range = |c: usize| c * CHUNK..(c * CHUNK + CHUNK).min(mc.runs());
        let slots: Vec<Mutex<Option<Accumulator>>> =
            chunks.iter().map(|_| Mutex::new(None)).collect();
        let failure: Mutex<Option<ExperimentError>> = Mutex::new(None);
        std::thread::scope(|scope| {
            // Chunk c always goes to worker c mod W: a worker that caches its truth per run
            // (it does not depend on θ) then finds it at every evaluation. A share's chunks
            // are every n-th (c = i + n j): worker j mod W, or with n a multiple of W every
            // chunk would go to one worker.
            for (k, w) in pool.iter_mut().enumerate() {
                let (slots, failure) = (&slots, &failure);
                scope.spawn(move || {
                    let mine = chunks.iter().enumerate();
                    for (slot, &c) in mine.filter(|(_, c)| (*c / asked.stride) % n_workers == k) {
                        if failure.lock().unwrap_or_else(|p| p.into_inner()).is_some() {
                            return;
                        }
                        let answer = if c == 0 {
                            // Only chunk 0's worker takes this lock.
                            let mut prints =
                                asked.first_prints.lock().unwrap_or_else(|p| p.into_inner());
                            self.ask(w, asked.theta, mc, range(c), prints.as_mut())
                        } else {
                            self.ask(w, asked.theta, mc, range(c), None)
                        };
                        match answer {
                            Ok(acc) => {
                                *slots[slot].lock().unwrap_or_else(|p| p.into_inner()) = Some(acc);
                            }
                            Err(e) => {
                                failure
                                    .lock()
                                    .unwrap_or_else(|p| p.into_inner())
                                    .get_or_insert(e);
                                return;
                            }
                        }
                    }
                });
            }
        });
        if let Some(e) = failure.into_inner().unwrap_or_else(|p| p.into_inner()) {
            return Err(e);
        }
        Ok(slots
            .into_iter()
            .map(|s| {
                let part = s.into_inner().unwrap_or_else(|p| p.into_inner());
                part.expect("every chunk of the wave answered")
            })
            .collect())
    }

    /// Start the pool's workers, where it has none yet (they start at the first request).
    fn fill(&self, pool: &mut Vec<Worker>) -> Result<(), ExperimentError> {
        if pool.is_empty() {
            for k in 0..self.command.workers {
                let w = Worker::start(&self.command.command, &self.command.dir, k)
                    .map_err(|why| self.start_error(false, why))?;
                pool.push(w);
            }
        }
        Ok(())
    }

    /// The failure that stopped the workers, if one has: every later evaluation gives it.
    pub fn failure(&self) -> Option<ExperimentError> {
        self.failed
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }
}

/// What every request of an evaluation's wave shares.
struct Asked<'a> {
    /// θ as the requests carry it.
    theta: &'a str,
    /// The evaluation's settings.
    mc: &'a McConfig,
    /// The share's chunk stride: 1, or the number of shares.
    stride: usize,
    /// Chunk 0's runs' fingerprints, when the seed contract is being checked.
    first_prints: &'a Mutex<Option<Fingerprints>>,
}

/// Stop every worker of `pool`, together.
fn shut_down(pool: &mut Vec<Worker>) {
    for w in pool.iter_mut() {
        w.close();
    }
    pool.clear();
}

impl Drop for ExternalExperiment {
    fn drop(&mut self) {
        shut_down(self.pool.get_mut().unwrap_or_else(|p| p.into_inner()));
    }
}

impl Experiment for ExternalExperiment {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        if let Some(e) = self.failure() {
            return Err(e);
        }
        let result = self.run(theta, mc, options);
        if let Err(e) = &result {
            // The workers may be mid-answer or gone: stop them all.
            shut_down(&mut self.pool.lock().unwrap_or_else(|p| p.into_inner()));
            *self.failed.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.clone());
        }
        result
    }
}

impl crate::experiment::Structure for ExternalExperiment {
    fn truth_values(&self) -> Option<Vec<f64>> {
        self.truth.clone()
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.targets.get(i).cloned().flatten()
    }
}

impl crate::experiment::HeldAsCode for ExternalExperiment {}

impl crate::experiment::Sampling for ExternalExperiment {
    fn truth_reuse(&self, _since: crate::montecarlo::TapeUsage) -> crate::experiment::TruthReuse {
        if self.replays.load(Ordering::Relaxed) {
            return crate::experiment::TruthReuse::Recorded;
        }
        crate::experiment::TruthReuse::Simulated {
            why: "the worker simulates its own truth, and autotune cannot tell whether the parameters it is sent enter it".to_string(),
        }
    }

    /// Known once the first answer is in: a worker that replays a recording says so.
    fn seed_free(&self) -> bool {
        self.replays.load(Ordering::Relaxed)
    }
}
