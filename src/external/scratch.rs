//! Scratch space for workers, and everything the process must undo when it stops.
//!
//! One place owns it so that containment and cleanup are properties of the code, not of each
//! call site:
//! - a worker's scratch directory is made by [`ScratchDir::create`]: a fresh, unpredictable
//!   name made with `mkdir` (an existing directory or a planted symbolic link of that name
//!   is never reused), mode 0700, removed when the [`ScratchDir`] is dropped;
//! - a path a worker names is trusted only after [`ScratchDir::contain`] resolved it (every
//!   symbolic link followed) to a regular file inside that directory; only such a file,
//!   lying directly in it, is ever deleted;
//! - every live worker process group and scratch directory is registered here, so that an
//!   interrupt handler can stop the one and remove the other ([`stop_workers_and_remove_scratch`]),
//!   whatever the threads that own them are doing.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::experiment::Uncontained;

/// What is live now: the worker process groups (each worker leads its own) and the scratch
/// directories.
struct Live {
    groups: Vec<u32>,
    dirs: Vec<PathBuf>,
}

static LIVE: Mutex<Live> = Mutex::new(Live {
    groups: Vec::new(),
    dirs: Vec::new(),
});

fn live() -> MutexGuard<'static, Live> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// How long the workers of an interrupted run get between SIGTERM and SIGKILL.
const GRACE: Duration = Duration::from_secs(1);

/// Stop every worker process group (SIGTERM, then SIGKILL to what is left after a second)
/// and remove every scratch directory, for an interrupt handler: call it right before the
/// process exits. The registry stays locked afterwards, so that no thread starts a worker
/// or makes a directory between the cleanup and the exit (it waits for the exit instead).
pub fn stop_workers_and_remove_scratch() {
    let guard = live();
    #[cfg(unix)]
    stop_groups(&guard.groups);
    for d in &guard.dirs {
        // std's remove_dir_all does not follow symbolic links inside the tree.
        let _ = std::fs::remove_dir_all(d);
    }
    std::mem::forget(guard);
}

#[cfg(unix)]
fn stop_groups(groups: &[u32]) {
    let groups: Vec<libc::pid_t> = groups
        .iter()
        .filter_map(|&g| libc::pid_t::try_from(g).ok())
        .collect();
    // SAFETY: killpg and waitpid only send signals to, and reap, the worker groups this
    // process started (each worker leads its own group, so nothing of autotune's is in one).
    let signal = |sig| {
        for &g in &groups {
            unsafe {
                libc::killpg(g, sig);
            }
        }
    };
    let gone = || {
        groups.iter().all(|&g| unsafe {
            // Reap the leader if it exited (a zombie still counts as a member).
            libc::waitpid(g, std::ptr::null_mut(), libc::WNOHANG);
            libc::killpg(g, 0) != 0
        })
    };
    let wait = |until: Instant| {
        while !gone() && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    signal(libc::SIGTERM);
    wait(Instant::now() + GRACE);
    if !gone() {
        signal(libc::SIGKILL);
        wait(Instant::now() + Duration::from_millis(300));
    }
}

/// Start `cmd` (set up to lead its own process group) and register its group, both under
/// the registry's lock: an interrupt handler either sees the worker or stops it from
/// starting.
pub(super) fn spawn_registered(cmd: &mut Command) -> std::io::Result<Child> {
    let mut live = live();
    let child = cmd.spawn()?;
    live.groups.push(child.id());
    Ok(child)
}

/// Forget the group of worker `pid`, once it is stopped.
pub(super) fn unregister_group(pid: u32) {
    live().groups.retain(|&g| g != pid);
}

/// A worker's scratch directory: made fresh and private, removed on drop.
#[derive(Debug)]
pub(super) struct ScratchDir {
    /// Its canonical path (what containment compares with).
    path: PathBuf,
}

/// A file a worker named, resolved and inside its scratch directory.
#[derive(Debug)]
pub(super) struct Contained {
    /// The file's canonical path.
    pub path: PathBuf,
    /// Whether autotune may delete it once read: it lies directly in the scratch
    /// directory (a file deeper down goes with the directory, whose removal does not
    /// follow links, so that a subdirectory swapped for a link cannot redirect a delete).
    pub removable: bool,
}

impl ScratchDir {
    /// A fresh directory `autotune-<label>-<random>` in the system's temporary directory,
    /// mode 0700, registered for [`stop_workers_and_remove_scratch`].
    pub(super) fn create(label: &str) -> std::io::Result<ScratchDir> {
        let mut live = live();
        // tempfile's Builder makes the directory with mkdir (never reusing a name, never
        // following a link) under a random suffix; private from its creation on.
        let prefix = format!("autotune-{label}-");
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).rand_bytes(12);
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o700));
        let dir = builder.tempdir()?.keep();
        // Canonical, so that containment holds where TMPDIR itself is reached by a link.
        let path = match dir.canonicalize() {
            Ok(p) => p,
            Err(e) => {
                let _ = std::fs::remove_dir(&dir);
                return Err(e);
            }
        };
        live.dirs.push(path.clone());
        Ok(ScratchDir { path })
    }

    /// Its path.
    pub(super) fn path(&self) -> &Path {
        &self.path
    }

    /// The file a worker named as `answer` (relative paths are relative to the scratch
    /// directory), if it resolves to a regular file inside it; otherwise why not, as a
    /// clause ("is not inside …") that does not repeat the worker's text.
    pub(super) fn contain(&self, answer: &str) -> Result<Contained, Uncontained> {
        let named = Path::new(answer);
        let joined = self.path.join(named);
        let canonical = joined
            .canonicalize()
            .map_err(|e| Uncontained::CannotOpen(e.to_string()))?;
        if !canonical.starts_with(&self.path) || canonical == self.path {
            return Err(Uncontained::Outside(self.path.clone()));
        }
        let meta =
            std::fs::metadata(&canonical).map_err(|e| Uncontained::CannotOpen(e.to_string()))?;
        if !meta.is_file() {
            return Err(Uncontained::NotRegular);
        }
        let removable = canonical.parent() == Some(self.path.as_path());
        Ok(Contained {
            path: canonical,
            removable,
        })
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let mut live = live();
        let _ = std::fs::remove_dir_all(&self.path);
        live.dirs.retain(|d| d != &self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_outside_or_through_a_link_is_refused_and_a_file_inside_is_contained() {
        let outside = tempfile::tempdir().unwrap();
        let victim = outside.path().join("victim.csv");
        std::fs::write(&victim, "x").unwrap();
        let s = ScratchDir::create("test").unwrap();
        let up = format!(
            "{}/../{}/victim.csv",
            s.path().display(),
            outside.path().file_name().unwrap().to_string_lossy()
        );
        assert!(s.contain(&up).is_err(), "{up}");
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(&victim, s.path().join("link.csv")).unwrap();
            assert!(s.contain("link.csv").is_err());
        }
        std::fs::create_dir(s.path().join("sub")).unwrap();
        assert!(
            s.contain("sub").is_err(),
            "a directory is not a records file"
        );
        std::fs::write(s.path().join("sub/a.jsonl"), "").unwrap();
        let c = s.contain("sub/a.jsonl").unwrap();
        assert!(!c.removable);
        std::fs::write(s.path().join("b.jsonl"), "").unwrap();
        let c = s
            .contain(&s.path().join("b.jsonl").display().to_string())
            .unwrap();
        assert!(c.removable);
        let dir = s.path().to_path_buf();
        drop(s);
        assert!(!dir.exists());
        assert!(victim.exists());
    }

    #[cfg(unix)]
    #[test]
    fn a_scratch_directory_is_private() {
        use std::os::unix::fs::PermissionsExt;
        let s = ScratchDir::create("test").unwrap();
        let mode = std::fs::metadata(s.path()).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o700);
    }
}
