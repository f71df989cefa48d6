//! Output: the human summary, JSON, JUnit XML, and tuned configs; every file is written
//! atomically.

pub mod advice;
pub mod html;
mod junit;
pub mod plots;
mod summary;
pub mod tune;
pub mod tuned;

pub use junit::junit_xml;
pub use summary::{fmt_g, gate_text, run_spread_note, summary_text};

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::stats::ConsistencyReport;

/// What a `check` run reports, for machines.
#[derive(Debug, Clone, Serialize)]
pub struct CheckOutput<'a> {
    /// Problem name.
    pub problem: &'a str,
    /// Problem file.
    pub file: String,
    /// SHA-256 of the problem file (`null` for a model defined in Rust).
    pub problem_hash: Option<&'a str>,
    /// Base seed.
    pub seed: u64,
    /// Parameter values the filter was run with.
    pub params: Vec<(String, f64)>,
    /// The statistics.
    pub report: &'a ConsistencyReport,
    /// autotune version.
    pub version: &'static str,
}

/// Write `bytes` to `path` through a temporary file in the same directory and a rename, so
/// that readers never see a half-written file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp.{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// An output file that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("writing {}: {source}", path.display())]
pub struct WriteError {
    /// The file.
    pub path: PathBuf,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

/// [`write_atomic`], with the path in the error.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_atomic(path, bytes).map_err(|source| WriteError {
        path: path.to_path_buf(),
        source,
    })
}

/// Write `report.html`, `report.md` and `report.json` into `dir` (created if missing), each
/// atomically.
pub fn write_report_dir(
    dir: &Path,
    html: &str,
    markdown: &str,
    json: &str,
) -> Result<(), WriteError> {
    for (name, text) in [
        ("report.html", html),
        ("report.md", markdown),
        ("report.json", json),
    ] {
        write_file(&dir.join(name), text.as_bytes())?;
    }
    Ok(())
}
