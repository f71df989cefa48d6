//! Interrupts: Ctrl-C, SIGTERM and SIGHUP stop external workers, remove scratch directories
//! and the temporary files of a write in progress, and exit 128 + the signal's number; a
//! live follow ends on the first Ctrl-C with its summary instead.

/// Set while `nis --follow` runs: Ctrl-C then ends the follow (and prints its summary)
/// instead of the process.
pub(crate) static FOLLOWING: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);
/// Set by Ctrl-C during a follow.
pub(crate) static STOP_FOLLOWING: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

/// This process's rank and the job's size, in an MPI job of more than one rank.
static RANK: std::sync::OnceLock<(usize, usize)> = std::sync::OnceLock::new();

/// From now on a signal ends this rank of an MPI job with exit code 2 and a line naming it.
#[cfg(feature = "mpi")]
pub(super) fn set_rank(rank: usize, size: usize) {
    let _ = RANK.set((rank, size));
}

/// On SIGINT, SIGTERM or SIGHUP: stop the external workers (their whole process groups,
/// with a grace period) and remove their scratch directories, remove the temporary files of
/// any write in progress, so no `.NAME.tmp.PID` file outlives the process, and exit with
/// the signal's conventional code, 128 + its number (130 for Ctrl-C, 143 for SIGTERM, 129
/// for SIGHUP). Installed once per process, for each signal that has its default
/// disposition: a handler the program set before is left alone, and so is a signal the
/// process was started with ignored (`nohup`'s SIGHUP, a script's background job's
/// SIGINT): the user asked for it to be survived.
pub(super) fn install() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let signals: Vec<libc::c_int> = [libc::SIGINT, libc::SIGTERM, libc::SIGHUP]
            .into_iter()
            .filter(|&s| has_default_disposition(s))
            .collect();
        if signals.is_empty() {
            return;
        }
        // signal-hook's iterator hands the signal's number to an ordinary thread, where the
        // cleanup may take locks, wait and exit.
        let Ok(mut caught) = signal_hook::iterator::Signals::new(&signals) else {
            return;
        };
        std::thread::spawn(move || {
            use std::sync::atomic::Ordering;
            for signal in caught.forever() {
                // A follow ends on the first signal with its summary; a second one, or any
                // other command, stops at once.
                if FOLLOWING.load(Ordering::SeqCst) && !STOP_FOLLOWING.swap(true, Ordering::SeqCst)
                {
                    continue;
                }
                crate::external::stop_workers_and_remove_scratch();
                crate::output::remove_temporary_files();
                // A rank of an MPI job fails the job as a failed evaluation does, naming
                // itself: the job's exit code is the first rank's to fail.
                if let Some((rank, size)) = RANK.get() {
                    eprintln!("error: rank {rank} of {size}: stopped by signal {signal}");
                    std::process::exit(2);
                }
                std::process::exit(128 + signal);
            }
        });
    });
}

/// Whether `signal` has its default disposition (SIG_DFL) in this process: neither ignored
/// nor handled by a handler someone installed before.
fn has_default_disposition(signal: libc::c_int) -> bool {
    // SAFETY: a null new action only reads the current one into `old`, which is a plain
    // C struct for which all-zero bytes are a valid value.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(signal, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_DFL
    }
}
