//! `mpirun -np K autotune check|tune PROBLEM …`: rank 0 runs the command on the problem
//! shared among the ranks ([`Ranked`]), the other ranks [`serve`] their shares of its
//! evaluations. Every rank parses the same arguments and loads the same problem (each node
//! starts its own workers). Commands that do not evaluate a problem's truth model (and
//! `check --shard`, records, recorded measurements) run on rank 0 alone.
//!
//! Every error line names its rank (`error: rank 1 of 3: …`). A rank whose evaluation
//! fails, and rank 0 on any error, exits 2 at once: Open MPI then ends the job (the ranks
//! waiting on it cannot hang), with that exit code.

use std::ffi::OsString;
use std::process::ExitCode;

use clap::Parser;

use super::error::AppError;
use super::print::finish;
use super::{Cli, Command, check, interrupt, run, tune_problem_over, usage_error};
use crate::cluster::mpi::{Mpi, Ranked, World, cpu_seconds, serve, stop};
use crate::problem::Problem;

/// The `autotune` binary under an MPI launcher.
pub(super) fn main(args: impl IntoIterator<Item = OsString>) -> ExitCode {
    let args: Vec<OsString> = args.into_iter().collect();
    let mpi = match Mpi::init() {
        Ok(m) => m,
        Err(why) => return finish(Err(AppError::Usage(format!("MPI: {why}")))),
    };
    // What the process took to start, MPI's initialization included: a job that only
    // starts and ends (the bench's `mpi_start`) takes it too, so the model of a job's time
    // counts it there, and the ranks' work from here on.
    let started = cpu_seconds();
    let world = mpi.world();
    let (rank, size) = (world.rank(), world.size());
    if size == 1 {
        let code = finish(run(args));
        if std::env::var_os("AUTOTUNE_MPI_STATS").is_some() {
            say(cpu_line(0, 1, started));
        }
        return code;
    }
    interrupt::set_rank(rank, size);
    let result = ranked(args, world, started);
    match result {
        Ok(code) => {
            drop(mpi);
            code
        }
        Err(Failure::Quiet(code)) => {
            drop(mpi);
            code
        }
        Err(Failure::Loud(e)) => {
            if let AppError::Io(io) = &e
                && io.kind() == std::io::ErrorKind::BrokenPipe
            {
                drop(mpi);
                return ExitCode::SUCCESS;
            }
            eprintln!("error: rank {rank} of {size}: {e}");
            // Ranks may be mid-evaluation, waiting for this one or sending to it: the job
            // ends here, not at MPI's finalize.
            crate::external::stop_workers_and_remove_scratch();
            crate::output::remove_temporary_files();
            std::process::exit(2);
        }
    }
}

/// How a rank's part of the job failed.
enum Failure {
    /// Said on rank 0 (a usage error): the others exit with its code, silently, after MPI's
    /// finalize.
    Quiet(ExitCode),
    /// Said by this rank, which then exits 2 at once.
    Loud(AppError),
}

impl From<AppError> for Failure {
    fn from(e: AppError) -> Self {
        Failure::Loud(e)
    }
}

/// This rank's part: the command on rank 0, the shares on the others.
fn ranked(args: Vec<OsString>, world: &World, started: f64) -> Result<ExitCode, Failure> {
    let rank = world.rank();
    let cli = match Cli::try_parse_from(&args) {
        Ok(c) => c,
        // Every rank parses the same arguments: rank 0 says what is wrong (or prints the
        // help), the others leave with its exit code.
        Err(e) if rank == 0 => return Ok(finish(usage_error(e, "autotune"))),
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            return Err(Failure::Quiet(ExitCode::from(code)));
        }
    };
    match cli.command {
        Command::Check(a)
            if a.records.is_empty() && a.measurements.is_none() && a.shard.is_none() =>
        {
            let Some(path) = &a.problem else {
                return Err(Failure::Quiet(ExitCode::from(2)));
            };
            let p = Problem::load(path).map_err(AppError::from)?;
            share(world, &p, started, |ranked| check(ranked, a.options))
        }
        Command::Tune(a) if a.measurements.is_none() => {
            let p = Problem::load(&a.problem).map_err(AppError::from)?;
            share(world, &p, started, |ranked| {
                tune_problem_over(a, &p, ranked)
            })
        }
        // Nothing to share: rank 0 runs it.
        _ if rank == 0 => Ok(run(args)?),
        _ => Ok(ExitCode::SUCCESS),
    }
}

/// `command` on rank 0 over `p` shared among the ranks; the others serve it.
fn share(
    world: &World,
    p: &Problem,
    started: f64,
    command: impl FnOnce(&Ranked<'_>) -> Result<ExitCode, AppError>,
) -> Result<ExitCode, Failure> {
    let stats = std::env::var_os("AUTOTUNE_MPI_STATS").is_some();
    let cpu = |rank: usize| {
        if stats {
            say(cpu_line(rank, world.size(), started));
        }
    };
    if world.rank() != 0 {
        serve(p, world).map_err(AppError::from)?;
        cpu(world.rank());
        return Ok(ExitCode::SUCCESS);
    }
    let ranked = Ranked::new(p, world);
    let code = command(&ranked)?;
    if stats {
        let s = ranked.stats();
        say(format!(
            "mpi: {} ranks, {} shared evaluations ({} by runs), {} request bytes, {} answer bytes, {:.3} s waiting for answers, {:.3} s merging them",
            world.size(),
            s.evaluations,
            s.by_runs,
            s.request_bytes,
            s.answer_bytes,
            s.waiting_s,
            s.merging_s
        ));
    }
    stop(world);
    cpu(0);
    Ok(code)
}

/// A rank's CPU time so far, and how much of it went before MPI's initialization returned
/// (`started`, s): `mpi: rank k of K: X s of CPU, Y s of it to start`.
fn cpu_line(rank: usize, size: usize, started: f64) -> String {
    format!(
        "mpi: rank {rank} of {size}: {:.3} s of CPU, {started:.3} s of it to start",
        cpu_seconds()
    )
}

/// `line` on stderr in one write: the ranks share mpirun's stderr, where a line written in
/// pieces would interleave with another rank's.
fn say(line: String) {
    use std::io::Write;
    let _ = std::io::stderr().write_all(format!("{line}\n").as_bytes());
}
