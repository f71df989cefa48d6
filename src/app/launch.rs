//! The `autotune` binary's entry: the interrupt handlers, then the command line in this
//! process or, under an MPI launcher, shared among the ranks.

use std::process::ExitCode;

use super::print::finish;
use super::{interrupt, run};

/// The `autotune` binary: parse the process's arguments, run, print any error on one line.
/// Ctrl-C (SIGINT), SIGTERM and SIGHUP stop any external workers, remove their scratch
/// directories and the temporary files of a write in progress, and exit 128 + the signal's
/// number (130, 143, 129).
pub fn main() -> ExitCode {
    interrupt::install();
    // Under an MPI launcher the ranks share the work (the cargo feature `mpi`).
    #[cfg(feature = "mpi")]
    if crate::cluster::mpi::launched() {
        return super::mpi::main(std::env::args_os());
    }
    // Without the feature every rank would run the whole command and print it.
    #[cfg(not(feature = "mpi"))]
    if let Some(ranks) = launcher_ranks() {
        return finish(Err(super::error::AppError::Usage(format!(
            "started as one of {ranks} MPI ranks, but this autotune was built without the `mpi` feature (cargo build --release --features mpi; docs/src/cluster.md)"
        ))));
    }
    finish(run(std::env::args_os()))
}

/// The job's size when an MPI launcher started this process as one of several ranks (Open
/// MPI's and MPICH's variables).
#[cfg(not(feature = "mpi"))]
fn launcher_ranks() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"]
        .iter()
        .filter_map(|v| std::env::var(v).ok()?.parse::<usize>().ok())
        .find(|&n| n > 1)
}
