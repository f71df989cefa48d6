//! Writing a command's output files: every location is checked before the work starts, the
//! files are written together after it (all of them or none), and no temporary file
//! outlives the process.
//!
//! A command collects its files in an [`Outputs`] and commits them at once: each is written
//! to a fresh temporary file beside its target (`.NAME.XXXXXXXX.tmp`, created exclusively
//! with a random name, so neither a file nor a symbolic link planted there is ever opened),
//! and only when every one was written and synced are they renamed into place. A failed
//! write removes the temporary files and the directories the commit created, and replaces
//! nothing.
//!
//! What may be replaced, checked before the work ([`check_output_file`],
//! [`check_report_dir`]) and again at the commit:
//! - never a file this process reads as an input (compared by identity, device and inode,
//!   after resolving links: [`crate::input::input_at`]), nor one another output of the same
//!   commit names;
//! - only a missing file or a regular file: a directory, symbolic link, FIFO, socket or
//!   device node at a target is refused (a rename would silently swap it for a regular
//!   file);
//! - an existing file only if autotune wrote it, by the mark every file it writes carries
//!   in its first kilobyte ([`is_marked`]: the header comment of a config, an XML or HTML
//!   comment, a JSON field), unless the command was given `--force`. Data files whose
//!   format has no room for a mark (a simulated record) are replaced only with `--force`.
//!
//! Temporary files are registered while they exist; [`remove_temporary_files`] deletes
//! them, for an interrupt handler to call before the process exits.

mod temporary;

pub use temporary::remove_temporary_files;
use temporary::{Temporary, made, split};

use std::io::Read;
use std::path::{Path, PathBuf};

/// An output file that could not be written, or may not be.
#[derive(Debug, thiserror::Error)]
#[error("{}{}: {source}", flag.as_deref().map(|f| format!("{f} ")).unwrap_or_else(|| "writing ".into()), path.display())]
pub struct WriteError {
    /// The file (or directory).
    pub path: PathBuf,
    /// The option that names it, where known (`--junit`).
    pub flag: Option<String>,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

impl WriteError {
    fn new(path: &Path, source: std::io::Error) -> Self {
        WriteError {
            path: path.to_path_buf(),
            flag: None,
            source,
        }
    }

    fn refused(path: &Path, message: String) -> Self {
        WriteError::new(path, std::io::Error::other(message))
    }

    /// The same error, naming the option that gave the path.
    pub fn of_flag(mut self, flag: &str) -> Self {
        self.flag = Some(flag.to_string());
        self
    }
}

/// The marks by which autotune recognises a file it wrote, one of which every file it
/// writes (but a data record) carries in its first [`MARK_WINDOW`] bytes: a config's header
/// comment (`# Tuned by autotune 0.1.0 …`), an XML, HTML or Markdown comment
/// (`<!-- written by autotune 0.1.0 -->`), a JSON report's field
/// (`"written_by": "autotune 0.1.0"`), a shard file's format.
pub const MARKS: [&str; 3] = [
    "by autotune ",
    "\"written_by\": \"autotune ",
    "\"format\": \"autotune-shard\"",
];

/// How far into a file its mark is looked for, in bytes.
pub const MARK_WINDOW: usize = 1024;

/// The comment line that marks an XML, HTML or Markdown file autotune wrote.
pub fn mark_comment() -> String {
    format!("<!-- written by autotune {} -->", env!("CARGO_PKG_VERSION"))
}

/// The value of the `written_by` field that marks a JSON file autotune wrote.
pub fn written_by() -> String {
    format!("autotune {}", env!("CARGO_PKG_VERSION"))
}

/// `value` as pretty-printed JSON whose first field is autotune's mark,
/// `"written_by": "autotune VERSION"`, followed by `value`'s own fields (an object).
pub fn marked_json<T: serde::Serialize>(value: &T) -> String {
    #[derive(serde::Serialize)]
    struct Marked<'a, T> {
        written_by: String,
        #[serde(flatten)]
        body: &'a T,
    }
    serde_json::to_string_pretty(&Marked {
        written_by: written_by(),
        body: value,
    })
    .expect("a report serializes")
}

/// Whether `head` (the start of a file) carries one of autotune's [`MARKS`] in its first
/// [`MARK_WINDOW`] bytes.
pub fn is_marked(head: &[u8]) -> bool {
    let head = &head[..head.len().min(MARK_WINDOW)];
    MARKS
        .iter()
        .any(|m| head.windows(m.len()).any(|w| w == m.as_bytes()))
}

/// Whether the regular file at `path` carries autotune's mark (read without following a
/// link and without blocking; at most [`MARK_WINDOW`] bytes).
fn file_is_marked(path: &Path) -> bool {
    use std::os::unix::fs::OpenOptionsExt;
    let Ok(file) = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)
    else {
        return false;
    };
    let mut head = Vec::with_capacity(MARK_WINDOW);
    if file
        .take(MARK_WINDOW as u64)
        .read_to_end(&mut head)
        .is_err()
    {
        return false;
    }
    is_marked(&head)
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

/// Refuse a target that exists and is not a regular file, that is one of this process's
/// inputs, or (unless `force`) that autotune did not write.
fn check_target(path: &Path, force: bool) -> Result<(), WriteError> {
    if let Some(what) = not_a_regular_file(path) {
        return Err(WriteError::refused(
            path,
            format!("{what} (only regular files are replaced)"),
        ));
    }
    if let Some(input) = crate::input::input_at(path) {
        let same = if input == path {
            String::new()
        } else {
            format!(" ({})", input.display())
        };
        return Err(WriteError::refused(
            path,
            format!("is an input of this command{same}: an output never replaces an input"),
        ));
    }
    if !force && std::fs::symlink_metadata(path).is_ok() && !file_is_marked(path) {
        return Err(WriteError::refused(
            path,
            "exists without autotune's mark (only files that carry it are replaced, and a record has no room for one): give --force to replace it, or another path".into(),
        ));
    }
    Ok(())
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
/// a regular file autotune wrote (any regular file with `force`) and none of this
/// process's inputs, and its directory exists or can be created, and takes new files.
pub fn check_output_file(path: &Path, force: bool) -> Result<(), WriteError> {
    check_target(path, force)?;
    check_directory(split(path).0, path)
}

/// The files a report directory holds.
pub const REPORT_FILES: [&str; 3] = ["report.html", "report.md", "report.json"];

/// Check, before any work, that `dir` can take a report: it is a directory or can be
/// created as one, takes new files, and each [`REPORT_FILES`] entry in it can be replaced
/// as [`check_output_file`] says.
pub fn check_report_dir(dir: &Path, force: bool) -> Result<(), WriteError> {
    if std::fs::metadata(dir).is_ok_and(|m| !m.is_dir()) {
        return Err(WriteError::refused(dir, "not a directory".into()));
    }
    check_directory(dir, dir)?;
    REPORT_FILES
        .iter()
        .try_for_each(|f| check_target(&dir.join(f), force))
}

/// Whether two output paths name the same file, however spelt (`x.csv`, `./x.csv`,
/// `d/../x.csv`, a symlinked directory, a hard link): the same device and inode where both
/// exist, else the canonical path where the file exists, or its directory's canonical path
/// and its name.
pub fn same_place(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    // The nearest existing ancestor, canonical, and the rest of the path normalized by
    // its words: what does not exist yet cannot be a link.
    fn resolve(p: &Path) -> PathBuf {
        use std::path::Component;
        let parts: Vec<Component> = p.components().collect();
        for cut in (0..=parts.len()).rev() {
            let head: PathBuf = parts[..cut].iter().collect();
            let head = if head.as_os_str().is_empty() {
                PathBuf::from(".")
            } else {
                head
            };
            if let Ok(mut out) = std::fs::canonicalize(&head) {
                for c in &parts[cut..] {
                    match c {
                        Component::ParentDir => {
                            out.pop();
                        }
                        Component::Normal(n) => out.push(n),
                        _ => {}
                    }
                }
                return out;
            }
        }
        p.to_path_buf()
    }
    if a == b {
        return true;
    }
    if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
        return x.dev() == y.dev() && x.ino() == y.ino();
    }
    resolve(a) == resolve(b)
}

/// A command's output files, written together by [`Outputs::commit`].
#[derive(Debug, Default)]
pub struct Outputs {
    files: Vec<(PathBuf, Vec<u8>)>,
    stale: Vec<PathBuf>,
    force: bool,
}

impl Outputs {
    /// No files yet; existing files are replaced only where autotune wrote them.
    pub fn new() -> Self {
        Outputs::default()
    }

    /// No files yet; with `force` (a command's `--force`), any existing regular file that
    /// is not an input may be replaced.
    pub fn replacing(force: bool) -> Self {
        Outputs {
            force,
            ..Outputs::default()
        }
    }

    /// Write `bytes` to `path`: a file that carries autotune's mark ([`MARKS`]).
    pub fn file(&mut self, path: &Path, bytes: impl Into<Vec<u8>>) {
        self.files.push((path.to_path_buf(), bytes.into()));
    }

    /// Write `report.html`, `report.md` and `report.json` into `dir` (created if missing).
    pub fn report_dir(&mut self, dir: &Path, html: &str, markdown: &str, json: &str) {
        for (name, text) in REPORT_FILES.iter().zip([html, markdown, json]) {
            self.file(&dir.join(name), text);
        }
    }

    /// Remove `path` once the files are in place, if it is a regular file autotune wrote
    /// (by its mark, whatever `force` says): an output of an earlier run that this one
    /// supersedes. A file there without the mark is left alone.
    pub fn remove_stale(&mut self, path: &Path) {
        self.stale.push(path.to_path_buf());
    }

    /// Write every file: all to temporary files first, then, when every write succeeded,
    /// rename them into place and remove the stale files. On an error nothing is replaced
    /// and the directories this commit created are removed again (a rename failing after
    /// the first one succeeded, which needs the file system to fail between two renames in
    /// directories just written to, is the one case that leaves part of the set). A handled
    /// signal (see [`remove_temporary_files`]) never splits the set: the renames hold the
    /// lock its handler needs. Two outputs that name one file are refused, as is any target
    /// [`check_output_file`] refuses.
    pub fn commit(self) -> Result<(), WriteError> {
        for (i, (path, _)) in self.files.iter().enumerate() {
            check_target(path, self.force)?;
            if let Some((other, _)) = self.files[..i].iter().find(|(o, _)| same_place(o, path)) {
                return Err(WriteError::refused(
                    path,
                    format!(
                        "is also where {} goes: two outputs cannot be one file",
                        other.display()
                    ),
                ));
            }
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
            let ours = not_a_regular_file(path).is_none()
                && crate::input::input_at(path).is_none()
                && file_is_marked(path);
            if !ours {
                continue;
            }
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
/// that readers never see a half-written file (an [`Outputs`] of one file; `force` as in
/// [`Outputs::replacing`]).
pub fn write_file(path: &Path, bytes: &[u8], force: bool) -> Result<(), WriteError> {
    let mut o = Outputs::replacing(force);
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
            .filter(|n| n.ends_with(".tmp") || n.contains("probe"))
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_failing_file_leaves_every_other_target_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let first = dir.path().join("tuned.toml");
        std::fs::write(&first, "# Tuned by autotune 0.0.1 (old)").unwrap();
        let blocker = dir.path().join("blocker");
        std::fs::write(&blocker, "# Tuned by autotune 0.0.1, a file").unwrap();
        let mut o = Outputs::new();
        o.file(&first, "new");
        o.report_dir(&dir.path().join("new").join("report"), "h", "m", "j");
        o.file(&blocker.join("x.xml"), "under a file");
        o.remove_stale(&blocker);
        assert!(o.commit().is_err());
        assert_eq!(
            std::fs::read_to_string(&first).unwrap(),
            "# Tuned by autotune 0.0.1 (old)"
        );
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
        std::fs::write(&stale, "# Tuned by autotune 0.0.1").unwrap();
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
        let e = check_output_file(&link, true).unwrap_err().to_string();
        assert!(e.contains("is a symbolic link"), "{e}");
        assert!(write_file(&link, b"x", true).is_err());
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
        let e = check_output_file(dir.path(), true).unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        let e = check_output_file(Path::new("/dev/null"), true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a device node"), "{e}");
        assert!(check_output_file(&target, true).is_ok());
        assert!(check_output_file(&dir.path().join("new/deeper/file"), false).is_ok());
        let e = check_output_file(&target.join("under"), true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a directory"), "{e}");
        let e = check_report_dir(&target, true).unwrap_err().to_string();
        assert!(e.contains("not a directory"), "{e}");
        assert_eq!(leftovers(dir.path()), Vec::<String>::new());
    }

    #[test]
    fn a_file_autotune_did_not_write_is_replaced_only_with_force() {
        let dir = tempfile::tempdir().unwrap();
        let theirs = dir.path().join("notes.xml");
        std::fs::write(&theirs, "<notes>mine</notes>").unwrap();
        let e = check_output_file(&theirs, false).unwrap_err().to_string();
        assert!(e.contains("exists without autotune's mark"), "{e}");
        assert!(e.contains("--force"), "{e}");
        assert!(write_file(&theirs, b"<!-- written by autotune 9 -->", false).is_err());
        assert_eq!(
            std::fs::read_to_string(&theirs).unwrap(),
            "<notes>mine</notes>"
        );
        write_file(&theirs, mark_comment().as_bytes(), true).unwrap();
        // Now it is autotune's, and replaced without --force.
        write_file(
            &theirs,
            b"<?xml version=\"1.0\"?>\n<!-- written by autotune 1 -->",
            false,
        )
        .unwrap();
        // A stale file without the mark stays, even where the commit is forced.
        let stale = dir.path().join("x.rejected.toml");
        std::fs::write(&stale, "mine").unwrap();
        let mut o = Outputs::replacing(true);
        o.file(&dir.path().join("x.toml"), "# Tuned by autotune 1");
        o.remove_stale(&stale);
        o.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&stale).unwrap(), "mine");
        assert_eq!(leftovers(dir.path()), Vec::<String>::new());
    }

    #[test]
    fn marks_are_found_in_the_first_kilobyte_only() {
        assert!(is_marked(b"# Tuned by autotune 0.1.0 from p.toml"));
        assert!(is_marked(b"{\n  \"written_by\": \"autotune 0.1.0\",\n"));
        assert!(is_marked(b"{\n  \"format\": \"autotune-shard\",\n"));
        assert!(is_marked(mark_comment().as_bytes()));
        assert!(!is_marked(b"autotune"));
        assert!(!is_marked(b"# Tuned by hand"));
        let mut late = vec![b' '; MARK_WINDOW];
        late.extend_from_slice(b"# Tuned by autotune 1");
        assert!(!is_marked(&late));
    }

    #[test]
    fn an_input_is_never_an_output_however_it_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("problem.toml");
        std::fs::write(&input, "# Tuned by autotune 0 (even a marked input)").unwrap();
        crate::input::note_input(&input);
        let hard = dir.path().join("hard.toml");
        std::fs::hard_link(&input, &hard).unwrap();
        let sub = dir.path().join("sub");
        std::fs::create_dir(&sub).unwrap();
        let dotted = sub.join("..").join("problem.toml");
        for p in [&input, &hard, &dotted] {
            let e = check_output_file(p, true).unwrap_err().to_string();
            assert!(e.contains("is an input of this command"), "{e}");
            assert!(write_file(p, b"# Tuned by autotune 1", true).is_err());
        }
        assert_eq!(
            std::fs::read_to_string(&input).unwrap(),
            "# Tuned by autotune 0 (even a marked input)"
        );
    }

    #[test]
    fn two_outputs_that_name_one_file_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut o = Outputs::new();
        o.file(&dir.path().join("a.xml"), mark_comment());
        o.file(&dir.path().join("sub/../a.xml"), mark_comment());
        let e = o.commit().unwrap_err().to_string();
        assert!(e.contains("two outputs cannot be one file"), "{e}");
        assert!(!dir.path().join("a.xml").exists());
    }

    #[test]
    fn a_planted_temporary_name_is_never_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = dir.path().join("victim");
        std::fs::write(&victim, "keep").unwrap();
        let target = dir.path().join("out.xml");
        // The names the old scheme used, and a spread of others, all links to the victim.
        let pid = std::process::id();
        std::os::unix::fs::symlink(&victim, dir.path().join(format!(".out.xml.tmp.{pid}")))
            .unwrap();
        write_file(&target, mark_comment().as_bytes(), false).unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), mark_comment());
    }
}
