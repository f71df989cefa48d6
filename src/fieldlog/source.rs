//! What a field log's reader is told ([`ReadOptions`]) and what it says of the file it read
//! ([`LogSource`]).

use std::path::Path;

use serde::Serialize;

use super::px4::Px4Info;

/// How the readers treat what they find.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReadOptions {
    /// Skip malformed rows of a CSV / JSON Lines log (and count them) instead of stopping at
    /// the first.
    pub skip_bad_rows: bool,
    /// PX4: keep only updates while `vehicle_land_detected` says the vehicle is in the air.
    pub in_air: bool,
    /// PX4: judge the data before the cut of a truncated or damaged log instead of refusing it.
    pub allow_truncated: bool,
}

/// A file read, and what its reader noted.
#[derive(Debug, Clone, Serialize)]
pub struct LogSource {
    /// The path as given.
    pub path: String,
    /// "csv", "jsonl", "px4-ulog" or "records".
    pub format: String,
    /// Rows (lines, ULog messages of the estimator topics, records) read.
    pub rows: usize,
    /// Malformed rows skipped (`--skip-bad-rows`).
    pub skipped_rows: usize,
    /// What the reader noted, one line each (pairing of PX4 topics, skipped lines, …).
    pub notes: Vec<String>,
    /// What a PX4 log says about its estimators (PX4 logs only).
    pub px4: Option<Px4Info>,
}

impl LogSource {
    pub(super) fn new(path: &Path, format: &str) -> Self {
        LogSource {
            path: path.display().to_string(),
            format: format.to_string(),
            rows: 0,
            skipped_rows: 0,
            notes: Vec::new(),
            px4: None,
        }
    }
}
