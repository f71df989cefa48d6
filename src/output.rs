//! Writing a command's output files: every location is checked before the work starts, the
//! files are written together after it (all of them or none), and no temporary file
//! outlives the process.
//!
//! A command collects its files in an [`Outputs`] and commits them at once: each is written
//! to a temporary file `.NAME.tmp.PID` beside its target, and only when every one was
//! written and synced are they renamed into place. A failed write removes the temporary
//! files and the directories the commit created, and replaces nothing. Only a missing file
//! or a regular file is ever replaced: a directory, symbolic link, FIFO, socket or device
//! node at a target is refused (a rename would silently swap it for a regular file).
//!
//! Temporary files are registered while they exist; [`remove_temporary_files`] deletes
//! them, for an interrupt handler to call before the process exits.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// An output file that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("writing {}: {source}", path.display())]
pub struct WriteError {
    /// The file (or directory).
    pub path: PathBuf,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

impl WriteError {
    fn new(path: &Path, source: std::io::Error) -> Self {
        WriteError {
            path: path.to_path_buf(),
            source,
        }
    }

    fn refused(path: &Path, message: String) -> Self {
        WriteError::new(path, std::io::Error::other(message))
    }
}

/// What a commit in progress has made: its temporary files, and the directories it created
/// for its outputs (see [`remove_temporary_files`]).
#[derive(Debug)]
struct Made {
    files: Vec<PathBuf>,
    dirs: Vec<PathBuf>,
}

static MADE: Mutex<Made> = Mutex::new(Made {
    files: Vec::new(),
    dirs: Vec::new(),
});

fn made() -> MutexGuard<'static, Made> {
    MADE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Delete every temporary file this process is writing, and the directories a commit in
/// progress created (if still empty), for an interrupt handler: call it right before the
/// process exits. The registry stays locked afterwards, so a write in progress on another
/// thread cannot make a new temporary file (it waits for the exit).
pub fn remove_temporary_files() {
    let guard = made();
    for p in &guard.files {
        let _ = std::fs::remove_file(p);
    }
    for d in guard.dirs.iter().rev() {
        let _ = std::fs::remove_dir(d);
    }
    std::mem::forget(guard);
}

/// A temporary file, registered from before it is created until it is dropped (removed,
/// unless it was renamed into place).
struct Temporary {
    path: PathBuf,
    file: Option<std::fs::File>,
    /// Renamed into place: its path is no longer ours to remove.
    renamed: bool,
}

impl Temporary {
    /// Create `.NAME.tmp.PID` beside `target`. It is registered and created under the
    /// registry's lock, so an interrupt handler (which takes the lock and keeps it) either
    /// sees the file or stops it from being created: none slips in between its removal and
    /// the exit.
    fn create(target: &Path) -> std::io::Result<Temporary> {
        let (dir, name) = split(target);
        let path = dir.join(format!(".{name}.tmp.{}", std::process::id()));
        let mut made = made();
        made.files.push(path.clone());
        match std::fs::File::create(&path) {
            Ok(file) => Ok(Temporary {
                path,
                file: Some(file),
                renamed: false,
            }),
            Err(e) => {
                made.files.retain(|p| p != &path);
                Err(e)
            }
        }
    }

    fn write(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let mut f = self.file.take().expect("written once");
        f.write_all(bytes)?;
        f.sync_all()
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        if !self.renamed {
            let _ = std::fs::remove_file(&self.path);
            made().files.retain(|p| p != &self.path);
        }
    }
}

/// A target's directory (`.` for a bare file name) and file name.
fn split(path: &Path) -> (&Path, String) {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    (dir, name)
}

/// What is at `path`, if it is something a write must not replace.
fn not_a_regular_file(path: &Path) -> Option<&'static str> {
    use std::os::unix::fs::FileTypeExt;
    let t = std::fs::symlink_metadata(path).ok()?.file_type();
    if t.is_file() {
        None
    } else if t.is_dir() {
        Some("is a directory")
    } else if t.is_symlink() {
        Some("is a symbolic link")
    } else if t.is_fifo() {
        Some("is a FIFO")
    } else if t.is_socket() {
        Some("is a socket")
    } else {
        Some("is a device node")
    }
}

/// Refuse a target that exists and is not a regular file.
fn check_target(path: &Path) -> Result<(), WriteError> {
    match not_a_regular_file(path) {
        Some(what) => Err(WriteError::refused(
            path,
            format!("{what} (only regular files are replaced)"),
        )),
        None => Ok(()),
    }
}

/// `dir`, or the nearest of its ancestors that exists, which must be a directory in which
/// a file can be created (tried with a probe file, so read-only file systems and missing
/// permissions are caught whoever runs it). `what` is the output named in errors.
fn check_directory(dir: &Path, what: &Path) -> Result<(), WriteError> {
    let mut existing = dir;
    while std::fs::symlink_metadata(existing).is_err() {
        match existing.parent() {
            Some(p) if !p.as_os_str().is_empty() => existing = p,
            _ => {
                existing = Path::new(".");
                break;
            }
        }
    }
    if !existing.is_dir() {
        return Err(WriteError::refused(
            what,
            format!("not a directory: {} is not a directory", existing.display()),
        ));
    }
    Temporary::create(&existing.join("autotune-probe"))
        .map(drop)
        .map_err(|e| {
            WriteError::refused(
                what,
                format!("cannot create files in {}: {e}", existing.display()),
            )
        })
}

/// Check, before any work, that `path` can be written as an output file: it is missing or
/// a regular file, and its directory exists or can be created, and takes new files.
pub fn check_output_file(path: &Path) -> Result<(), WriteError> {
    check_target(path)?;
    check_directory(split(path).0, path)
}

/// The files a report directory holds.
pub const REPORT_FILES: [&str; 3] = ["report.html", "report.md", "report.json"];

/// Check, before any work, that `dir` can take a report: it is a directory or can be
/// created as one, takes new files, and holds no [`REPORT_FILES`] entry that is not a
/// regular file.
pub fn check_report_dir(dir: &Path) -> Result<(), WriteError> {
    if std::fs::metadata(dir).is_ok_and(|m| !m.is_dir()) {
        return Err(WriteError::refused(dir, "not a directory".into()));
    }
    check_directory(dir, dir)?;
    REPORT_FILES
        .iter()
        .try_for_each(|f| check_target(&dir.join(f)))
}

/// A command's output files, written together by [`Outputs::commit`].
#[derive(Debug, Default)]
pub struct Outputs {
    files: Vec<(PathBuf, Vec<u8>)>,
    stale: Vec<PathBuf>,
}

impl Outputs {
    /// No files yet.
    pub fn new() -> Self {
        Outputs::default()
    }

    /// Write `bytes` to `path`.
    pub fn file(&mut self, path: &Path, bytes: impl Into<Vec<u8>>) {
        self.files.push((path.to_path_buf(), bytes.into()));
    }

    /// Write `report.html`, `report.md` and `report.json` into `dir` (created if missing).
    pub fn report_dir(&mut self, dir: &Path, html: &str, markdown: &str, json: &str) {
        for (name, text) in REPORT_FILES.iter().zip([html, markdown, json]) {
            self.file(&dir.join(name), text);
        }
    }

    /// Remove `path` (if it is a file) once the files are in place: an output of an
    /// earlier run that this one supersedes.
    pub fn remove_stale(&mut self, path: &Path) {
        self.stale.push(path.to_path_buf());
    }

    /// Write every file: all to temporary files first, then, when every write succeeded,
    /// rename them into place and remove the stale files. On an error nothing is replaced
    /// and the directories this commit created are removed again (a rename failing after
    /// the first one succeeded, which needs the file system to fail between two renames in
    /// directories just written to, is the one case that leaves part of the set). A handled
    /// signal (see [`remove_temporary_files`]) never splits the set: the renames hold the
    /// lock its handler needs.
    pub fn commit(self) -> Result<(), WriteError> {
        for (path, _) in &self.files {
            check_target(path)?;
        }
        let mut created = Vec::new();
        let result = self.write_and_rename(&mut created);
        if result.is_err() {
            // Deepest first; a directory something else wrote into stays.
            for d in created.iter().rev() {
                let _ = std::fs::remove_dir(d);
            }
        }
        made().dirs.retain(|d| !created.contains(d));
        result
    }

    fn write_and_rename(&self, created: &mut Vec<PathBuf>) -> Result<(), WriteError> {
        let mut written = Vec::with_capacity(self.files.len());
        for (path, bytes) in &self.files {
            create_dirs(split(path).0, created).map_err(|e| WriteError::new(path, e))?;
            let mut tmp = Temporary::create(path).map_err(|e| WriteError::new(path, e))?;
            tmp.write(bytes).map_err(|e| WriteError::new(path, e))?;
            written.push((tmp, path));
        }
        hold_for_tests();
        // The renames run under the registry's lock. An interrupt handler takes that lock
        // before it removes the temporary files and exits, so it finds the set either
        // before the first rename (and removes every temporary file: nothing replaced) or
        // after the last (everything replaced), never a mix of this run's files and an
        // earlier run's. Declared after `written`, the guard is released before any
        // `Temporary` is dropped (their drop takes the lock too).
        let mut registry = made();
        for (tmp, path) in written.iter_mut() {
            let path: &Path = path;
            std::fs::rename(&tmp.path, path).map_err(|e| WriteError::new(path, e))?;
            tmp.renamed = true;
            registry.files.retain(|p| p != &tmp.path);
        }
        drop(registry);
        for path in &self.stale {
            match std::fs::remove_file(path) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(WriteError::new(path, e));
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// Create `dir` and its missing ancestors, recording each one created in `created`.
fn create_dirs(dir: &Path, created: &mut Vec<PathBuf>) -> std::io::Result<()> {
    let mut missing = Vec::new();
    let mut d = dir;
    while std::fs::symlink_metadata(d).is_err() {
        missing.push(d.to_path_buf());
        match d.parent() {
            Some(p) if !p.as_os_str().is_empty() => d = p,
            _ => break,
        }
    }
    for m in missing.into_iter().rev() {
        made().dirs.push(m.clone());
        match std::fs::create_dir(&m) {
            Ok(()) => created.push(m),
            Err(e) => {
                made().dirs.retain(|d| d != &m);
                if !(e.kind() == std::io::ErrorKind::AlreadyExists && m.is_dir()) {
                    return Err(e);
                }
            }
        }
    }
    Ok(())
}

/// A test hook: with `AUTOTUNE_TEST_HOLD_TEMPORARY_MS` set, a commit waits that long with
/// its temporary files written and not yet renamed, so that a test can interrupt it there
/// (`tests/interrupt.rs`).
fn hold_for_tests() {
    if let Some(ms) = std::env::var("AUTOTUNE_TEST_HOLD_TEMPORARY_MS")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    {
        std::thread::sleep(std::time::Duration::from_millis(ms.min(600_000)));
    }
}

/// Write `bytes` to `path` through a temporary file in the same directory and a rename, so
/// that readers never see a half-written file (an [`Outputs`] of one file).
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let mut o = Outputs::new();
    o.file(path, bytes);
    o.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leftovers(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains(".tmp.") || n.contains("probe"))
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_failing_file_leaves_every_other_target_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let first = dir.path().join("tuned.toml");
        std::fs::write(&first, "old").unwrap();
        let blocker = dir.path().join("blocker");
        std::fs::write(&blocker, "a file").unwrap();
        let mut o = Outputs::new();
        o.file(&first, "new");
        o.report_dir(&dir.path().join("new").join("report"), "h", "m", "j");
        o.file(&blocker.join("x.xml"), "under a file");
        o.remove_stale(&blocker);
        assert!(o.commit().is_err());
        assert_eq!(std::fs::read_to_string(&first).unwrap(), "old");
        assert!(
            blocker.is_file(),
            "the stale file stays when the commit fails"
        );
        assert!(
            !dir.path().join("new").exists(),
            "directories the commit made are removed"
        );
        assert_eq!(leftovers(dir.path()), Vec::<String>::new());
        let made = made();
        assert!(!made.files.iter().any(|p| p.starts_with(dir.path())));
        assert!(!made.dirs.iter().any(|p| p.starts_with(dir.path())));
    }

    #[test]
    fn a_commit_writes_every_file_and_removes_the_stale_one() {
        let dir = tempfile::tempdir().unwrap();
        let stale = dir.path().join("x.rejected.toml");
        std::fs::write(&stale, "old").unwrap();
        let mut o = Outputs::new();
        o.file(&dir.path().join("x.toml"), "cfg");
        o.report_dir(&dir.path().join("a/b"), "h", "m", "j");
        o.remove_stale(&stale);
        o.commit().unwrap();
        assert!(!stale.exists());
        assert_eq!(
            std::fs::read_to_string(dir.path().join("a/b/report.md")).unwrap(),
            "m"
        );
        assert_eq!(leftovers(dir.path()), Vec::<String>::new());
    }

    #[test]
    fn only_regular_files_are_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("real");
        std::fs::write(&target, "keep").unwrap();
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let e = check_output_file(&link).unwrap_err().to_string();
        assert!(e.contains("is a symbolic link"), "{e}");
        assert!(write_file(&link, b"x").is_err());
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
        let e = check_output_file(dir.path()).unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        let e = check_output_file(Path::new("/dev/null"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a device node"), "{e}");
        assert!(check_output_file(&target).is_ok());
        assert!(check_output_file(&dir.path().join("new/deeper/file")).is_ok());
        let e = check_output_file(&target.join("under"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a directory"), "{e}");
        let e = check_report_dir(&target).unwrap_err().to_string();
        assert!(e.contains("not a directory"), "{e}");
        assert_eq!(leftovers(dir.path()), Vec::<String>::new());
    }
}
