//! Field logs: a filter's recorded innovations from a real drive or flight, judged without
//! ground truth (`autotune nis`).
//!
//! Without truth the NIS is what a designer has. Over a single run, a consistent filter's
//! innovations are white and `ν_k' S_k⁻¹ ν_k ~ χ²(m_k)` independently, so the sum of K
//! updates' NIS is `χ²(Σ m_k)` and its time average has the single-run interval
//! `χ²(K m)/K` (Bar-Shalom, Li, Kirubarajan 2001, §5.4.2). Each sensor is tested on its own
//! update sequence: its gated average, its outliers beyond a stated gate (counted, and tested
//! against the binomial tail the gate allows, instead of being averaged in), each component's
//! `ν_j²/S_jj`, and each component's whiteness (the normalized autocorrelation at lags 1..L and
//! its portmanteau), at a family-wise level α.
//!
//! Readers ([`read_logs`]): a generic CSV / JSON Lines log (one row per update: time, sensor,
//! innovation and S, or a precomputed NIS), PX4 ULog (`estimator_innovations` with
//! `estimator_innovation_variances`, or the older `ekf2_innovations`), and the records format
//! of `docs/external.md` read without truth. The format is in `docs/fieldlog.md`.

mod advice;
mod analysis;
mod follow;
mod ingest;
mod monitor;
mod px4;
mod records;
mod report;
mod settings;
mod source;
mod text;
mod ulog_walk;

use std::path::{Path, PathBuf};

pub use analysis::{
    AnalyzerError, Dropped, MAX_SENSORS, NisAnalyzer, SensorInfo, SeriesPoint, Update,
};
pub use follow::{Follower, Status};
pub use monitor::{MonitorError, MonitorStatus, NisMonitor, SensorStatus, WindowStatus};
pub use px4::{EventKind, NotJudged, ParamAdvice, Px4Channel, Px4Event, Px4Info, Px4Instance};
pub use report::{
    CentredWhiteness, Histogram, MeanTest, NisAverage, NisReport, NotFused, Overall, SensorPlot,
    SensorReport, WindowSummary,
};
pub use settings::{NisSettings, Window};
pub use source::{LogSource, ReadOptions};

use crate::input::FileError;

/// The kinds of files `autotune nis` reads, by extension (and for CSV / JSON Lines, by
/// their columns: a `run` and `step` without `sensor` is a records file).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Ulog,
    Text,
    Records,
}

fn kind_of(path: &Path) -> Result<Kind, FileError> {
    // Every reader goes through `userfile`, which refuses a FIFO or a device; refusing it
    // here too gives that error before the format sniff. A missing file is left to the
    // reader's error.
    match crate::userfile::open_io(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(crate::userfile::cannot_read(path, &e)),
        Ok(_) => {}
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("ulg") | Some("ulog") => Ok(Kind::Ulog),
        Some("npz") | Some("npy") => Ok(Kind::Records),
        Some("csv") | Some("jsonl") | Some("ndjson") => {
            if text::is_records(path)? {
                Ok(Kind::Records)
            } else {
                Ok(Kind::Text)
            }
        }
        _ => Err(FileError::new(
            path,
            "",
            "not a field log: expected .ulg (PX4), .csv or .jsonl (docs/src/field-logs.md), or a records file (.npz, .npy)",
        )),
    }
}

/// Read the logs `paths` into `analyzer`, file by file (each file starts new sequences).
/// An error names the file, and the line or field.
pub fn read_logs(
    paths: &[PathBuf],
    options: &ReadOptions,
    analyzer: &mut NisAnalyzer,
) -> Result<Vec<LogSource>, FileError> {
    if paths.is_empty() {
        return Err(FileError::new(Path::new("LOG"), "", "no log files given"));
    }
    paths.iter().for_each(|p| crate::input::note_input(p));
    let mut sources = Vec::new();
    let mut npy: Vec<PathBuf> = Vec::new();
    for p in paths {
        let kind = kind_of(p)?;
        analyzer.break_sequences();
        match kind {
            Kind::Ulog => sources.push(px4::read(p, options, analyzer)?),
            Kind::Text => sources.push(text::read(p, options, analyzer)?),
            Kind::Records if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("npy")) => {
                npy.push(p.clone());
            }
            Kind::Records => sources.push(records::read(std::slice::from_ref(p), analyzer)?),
        }
    }
    if !npy.is_empty() {
        analyzer.break_sequences();
        sources.push(records::read(&npy, analyzer)?);
    }
    Ok(sources)
}

/// Read and judge the logs `paths` with `settings`.
pub fn analyze(
    paths: &[PathBuf],
    options: &ReadOptions,
    settings: NisSettings,
) -> Result<NisReport, FileError> {
    let mut analyzer = NisAnalyzer::new(settings);
    let sources = read_logs(paths, options, &mut analyzer)?;
    let mut report = analyzer.report();
    report.sources = sources;
    px4::annotate(&mut report);
    Ok(report)
}
