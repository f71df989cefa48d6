//! The temporary files a commit writes before renaming them into place, registered from
//! before each is created until it is dropped, so that an interrupt handler can remove them
//! (and the directories the commit created) before the process exits.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// What a commit in progress has made: its temporary files, and the directories it created
/// for its outputs (see [`remove_temporary_files`]).
#[derive(Debug)]
pub(super) struct Made {
    pub(super) files: Vec<PathBuf>,
    pub(super) dirs: Vec<PathBuf>,
}

static MADE: Mutex<Made> = Mutex::new(Made {
    files: Vec::new(),
    dirs: Vec::new(),
});

pub(super) fn made() -> MutexGuard<'static, Made> {
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
pub(super) struct Temporary {
    pub(super) path: PathBuf,
    file: Option<std::fs::File>,
    /// Renamed into place: its path is no longer ours to remove.
    pub(super) renamed: bool,
}

impl Temporary {
    /// Create a fresh `.NAME.XXXXXXXX.tmp` beside `target`: a random name, opened with
    /// `O_CREAT | O_EXCL` (so an existing file or a symbolic link planted at that name is
    /// never opened), mode 0666 less the umask as a plain create would give. It is
    /// registered under the registry's lock, so an interrupt handler (which takes the lock
    /// and keeps it) either sees the file or stops it from being created: none slips in
    /// between its removal and the exit.
    pub(super) fn create(target: &Path) -> std::io::Result<Temporary> {
        use std::os::unix::fs::PermissionsExt;
        let (dir, name) = split(target);
        let mut made = made();
        let (file, path) = tempfile::Builder::new()
            .prefix(&format!(".{name}."))
            .suffix(".tmp")
            .rand_bytes(8)
            .permissions(std::fs::Permissions::from_mode(0o666))
            .tempfile_in(dir)?
            .keep()
            .map_err(|e| e.error)?;
        made.files.push(path.clone());
        Ok(Temporary {
            path,
            file: Some(file),
            renamed: false,
        })
    }

    pub(super) fn write(&mut self, bytes: &[u8]) -> std::io::Result<()> {
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
pub(super) fn split(path: &Path) -> (&Path, String) {
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
