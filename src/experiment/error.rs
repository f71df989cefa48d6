//! Why an experiment could not produce its sums: the records it holds cannot give the runs
//! asked for, or the worker program behind it failed to start, broke the line protocol,
//! answered malformed records, or broke the seed contract.
//!
//! The worker's failures are named here, beside the seam's error that carries them, because
//! `external` (which runs the workers) sits above this module and the seam's error must be
//! able to hold them.

use std::ops::Range;
use std::path::PathBuf;

use crate::input::FileError;
use crate::records::RecordError;

/// An experiment that could not produce its sums at all: its worker failed, its records
/// were malformed. This is bad input or a broken setup (exit code 2), not a verdict on the
/// filter: a filter that diverged gives sums with its runs marked diverged instead.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExperimentError {
    /// Records read once cannot give the runs, steps or lags asked for.
    #[error("{source_label}: the records hold {} runs × {} steps ({} lags); they cannot give {} runs × {} steps ({} lags)", .held.0, .held.1, .held.2, .asked.0, .asked.1, .asked.2)]
    RecordsDiffer {
        /// Where the records come from, as reports name it.
        source_label: String,
        /// The records' runs, steps and lags.
        held: (usize, usize, usize),
        /// The runs, steps and lags asked for.
        asked: (usize, usize, usize),
    },
    /// A worker program could not be started.
    #[error("worker `{command}` (in {}){}: {why}", .dir.display(), if *.for_contract_check { ", a fresh worker for the seed-contract check" } else { "" })]
    WorkerStart {
        /// The command as one would type it.
        command: String,
        /// The directory it runs in.
        dir: PathBuf,
        /// Whether it was a fresh worker started for the seed-contract check.
        for_contract_check: bool,
        /// Why it did not start.
        why: StartFailure,
    },
    /// A worker broke the protocol or answered records that cannot be summed (boxed: it
    /// carries the request and the failure, and the error travels in every `Result`).
    #[error(transparent)]
    Worker(Box<WorkerError>),
    /// A worker whose runs do not depend on (seed, run) alone.
    #[error(
        "worker `{command}` breaks the seed contract: {violation} (run i's random numbers must depend on the seed and i alone; see docs/src/workers.md)"
    )]
    SeedContract {
        /// The command as one would type it.
        command: String,
        /// What showed it.
        violation: SeedContractViolation,
    },
    /// An evaluation asked for in shares (shards, MPI ranks) of an experiment that does not
    /// split into them: recorded sums, or an implementation that ignores the share.
    #[error(
        "{source_label}: its evaluations do not split into shares of their chunks (records and recorded measurements are judged in one process)"
    )]
    Unsplit {
        /// The experiment's source, as reports name it.
        source_label: String,
    },
    /// Another process of a distributed evaluation failed (an MPI rank: its worker, its
    /// input, a signal).
    #[error("rank {rank} of {ranks}: {message}")]
    Rank {
        /// The failed rank, 0-based.
        rank: usize,
        /// Ranks in the job.
        ranks: usize,
        /// What it said.
        message: String,
    },
}

/// A worker's failed request: which worker, the request, how it failed, and the end of
/// its stderr.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("worker `{command}` ({worker}), request {request}: {failure}; {stderr}")]
pub struct WorkerError {
    /// The command as one would type it.
    pub command: String,
    /// Which worker.
    pub worker: WorkerRole,
    /// The request it failed.
    pub request: RequestInfo,
    /// How it failed.
    pub failure: WorkerFailure,
    /// The last lines of its stderr, as a clause.
    pub stderr: String,
}

/// Why a worker program did not start.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StartFailure {
    /// Its scratch directory could not be made (the system's words).
    #[error("cannot create a scratch directory in {}: {why}", .temp.display())]
    Scratch {
        /// The temporary directory it was to be made in.
        temp: PathBuf,
        /// The system's words.
        why: String,
    },
    /// The program could not be run (the system's words).
    #[error("cannot start it: {0}")]
    Spawn(String),
}

/// Which worker of a pool.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum WorkerRole {
    /// Worker `index` (0-based) of `of`.
    #[error("worker {} of {of}", .index + 1)]
    Pool {
        /// 0-based.
        index: usize,
        /// Workers in the pool.
        of: usize,
    },
    /// A worker started only for the seed-contract check.
    #[error("a fresh worker started for the seed-contract check")]
    ContractCheck,
}

/// A request as error messages describe it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{id} (seed {seed}, runs {}..{}, {steps} steps)", .runs.start, .runs.end)]
pub struct RequestInfo {
    /// The request's id.
    pub id: u64,
    /// Its seed.
    pub seed: u64,
    /// The runs asked for.
    pub runs: Range<usize>,
    /// Steps per run.
    pub steps: usize,
}

/// How a worker went away.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Ended {
    /// It exited with a status.
    #[error("exited with status {0}")]
    Exited(i32),
    /// A signal ended it (the status as the system shows it).
    #[error("was killed ({0})")]
    Killed(String),
    /// It closed its stdin (and may still run).
    #[error("closed its stdin")]
    ClosedStdin,
    /// It closed its stdout (and may still run).
    #[error("closed its stdout")]
    ClosedStdout,
}

/// How a worker failed a request. Lines and messages it wrote are quoted, cut and with
/// control characters escaped, so that the error stays on one line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorkerFailure {
    /// It was gone before the request could be sent.
    #[error("{0} before it was asked")]
    GoneBeforeAsked(Ended),
    /// Its stdout could not be read (the reader's words).
    #[error("its stdout failed: {0}")]
    Stdout(String),
    /// It went away before answering.
    #[error("{0} before answering")]
    GoneBeforeAnswering(Ended),
    /// It did not answer in time, and was killed.
    #[error("no answer within the timeout of {seconds} s (killed)")]
    TimedOut {
        /// The timeout, s.
        seconds: f64,
    },
    /// It printed a line that is not a protocol line.
    #[error("printed {0} on stdout, which is not a protocol line (print diagnostics to stderr)")]
    NotProtocol(String),
    /// A record it answered inline is malformed.
    #[error("inline record: {0}")]
    InlineRecord(RecordError),
    /// It answered another request (its id as written), or without an id (the line).
    #[error("answered {} to request {request}", match .id { Some(id) => format!("id {id}"), None => format!("{line} without an id") })]
    WrongId {
        /// The id it answered, as written.
        id: Option<String>,
        /// Its line, quoted.
        line: String,
        /// The request's id.
        request: u64,
    },
    /// It reported an error (its message, quoted).
    #[error("reported an error: {0}")]
    Reported(String),
    /// Its answer's `file` is not a string.
    #[error("answered {0}: 'file' is not a path")]
    FileNotPath(String),
    /// It named a records file outside its scratch directory, or not a file.
    #[error("named the records file {file}, which {why}")]
    Uncontained {
        /// The path it named, quoted.
        file: String,
        /// Why it is refused.
        why: Uncontained,
    },
    /// The records file it named is malformed.
    #[error("its records file {0}")]
    RecordsFile(FileError),
    /// Its sums answer is malformed, or does not fit the request.
    #[error("its sums answer: {0}")]
    Sums(crate::records::WireError),
    /// An answer that is none of the protocol's.
    #[error("answered {0}: expected \"file\", \"sums\", \"done\" or \"error\"")]
    Unexpected(String),
    /// It answered a replay request without saying it replayed the record.
    #[error(
        "answered the request to replay the record without \"replays\": true on its closing line: a worker that replays answers with it, and one that cannot replay a record answers {{\"id\": …, \"error\": …}}"
    )]
    NotReplaying,
    /// Its records, together, cannot be summed (a run missing, steps out of order).
    #[error(transparent)]
    Records(#[from] RecordError),
}

/// Why a path a worker named is not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Uncontained {
    /// It cannot be resolved or examined (the system's words).
    #[error("cannot be opened ({0})")]
    CannotOpen(String),
    /// It resolves outside the worker's scratch directory.
    #[error("is not inside the worker's scratch directory {} (a worker writes its files there; autotune reads and deletes nothing else)", .0.display())]
    Outside(PathBuf),
    /// It is a directory, a FIFO, a device.
    #[error("is not a regular file")]
    NotRegular,
}

/// How a worker showed that its runs do not depend on (seed, run) alone.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SeedContractViolation {
    /// Every run of the first chunk gave the same records.
    #[error("the {} runs {}..{} all gave the same records, as if every run were seeded alike (e.g. with (seed, 0) instead of (seed, i))", .0.len(), .0.start, .0.end)]
    AllAlike(Range<usize>),
    /// A run asked for again came back different.
    #[error("run {run} asked for again (runs {}..{}, from {from}) gave other records than the first time (runs {}..{} from worker 1)", .again.start, .again.end, .first.start, .first.end)]
    NotRepeatable {
        /// The run.
        run: usize,
        /// The runs asked for again.
        again: Range<usize>,
        /// Who answered again ("worker 2", "a fresh worker").
        from: &'static str,
        /// The first chunk's runs.
        first: Range<usize>,
    },
}
