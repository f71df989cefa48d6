//! A live monitor on a CSV / JSON Lines log that is still being written: each poll reads the
//! complete lines appended since the last, folds them into the sums, and the status gives
//! the running and windowed NIS against their chi-square intervals and the verdict so far.

use std::fmt;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::analysis::NisAnalyzer;
use super::ingest::{Ingest, Skips};
use super::report::NisReport;
use super::report::short;
use super::settings::NisSettings;
use super::text::{CsvColumns, csv_text, json_row};
use super::{LogSource, ReadOptions};
use crate::input::FileError;
use crate::stats::Verdict;

/// Longest line a log may have.
const MAX_LINE: usize = 1 << 20;
/// Bytes read at a time.
const CHUNK: usize = 1 << 20;

/// Follows one growing log.
pub struct Follower {
    path: PathBuf,
    jsonl: bool,
    options: ReadOptions,
    offset: u64,
    partial: Vec<u8>,
    line_no: usize,
    columns: Option<(CsvColumns, usize)>,
    ingest: Ingest,
    skips: Skips,
    rows: usize,
    analyzer: NisAnalyzer,
}

fn at_line(path: &Path, line: usize, field: &str, m: impl Into<String>) -> FileError {
    let mut e = FileError::new(path, field, m);
    e.line = Some(line);
    e
}

impl Follower {
    /// Follow the CSV or JSON Lines log at `path` (it may not exist yet, or be empty).
    pub fn new(
        path: &Path,
        settings: NisSettings,
        options: ReadOptions,
    ) -> Result<Follower, FileError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let jsonl = match ext.as_deref() {
            Some("csv") => false,
            Some("jsonl") | Some("ndjson") => true,
            _ => {
                return Err(FileError::new(
                    path,
                    "",
                    "--follow reads a CSV or JSON Lines log (.csv, .jsonl) as it is written",
                ));
            }
        };
        Ok(Follower {
            path: path.to_path_buf(),
            jsonl,
            options,
            offset: 0,
            partial: Vec::new(),
            line_no: 0,
            columns: None,
            ingest: Ingest::default(),
            skips: Skips::default(),
            rows: 0,
            analyzer: NisAnalyzer::new(settings),
        })
    }

    /// Read what was appended since the last poll; returns the number of complete lines
    /// read. A partial last line waits for its end.
    pub fn poll(&mut self) -> Result<usize, FileError> {
        let mut file = match crate::userfile::open_io(&self.path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
            Err(e) => return Err(FileError::new(&self.path, "", format!("cannot read: {e}"))),
        };
        // A log that appears after the start is an input from then on.
        crate::input::note_input(&self.path);
        let len = file
            .metadata()
            .map_err(|e| FileError::new(&self.path, "", format!("cannot read: {e}")))?
            .len();
        if len < self.offset {
            return Err(FileError::new(
                &self.path,
                "",
                format!(
                    "the file shrank from {} to {len} bytes while followed (replaced or truncated)",
                    self.offset
                ),
            ));
        }
        file.seek(SeekFrom::Start(self.offset))
            .map_err(|e| FileError::new(&self.path, "", format!("cannot read: {e}")))?;
        // In chunks: a log that is already large when followed is not read into memory
        // whole.
        let mut remaining = len - self.offset;
        let mut chunk = vec![0u8; remaining.min(CHUNK as u64) as usize];
        let mut count = 0;
        while remaining > 0 {
            let want = remaining.min(CHUNK as u64) as usize;
            let n = match file.read(&mut chunk[..want]) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(FileError::new(&self.path, "", format!("cannot read: {e}"))),
            };
            self.offset += n as u64;
            remaining -= n as u64;
            self.partial.extend_from_slice(&chunk[..n]);
            count += self.complete_lines()?;
        }
        Ok(count)
    }

    /// Take the complete lines out of `partial`; the number taken. A partial last line
    /// waits for its end, up to [`MAX_LINE`] bytes.
    fn complete_lines(&mut self) -> Result<usize, FileError> {
        let mut count = 0;
        if let Some(end) = self.partial.iter().rposition(|&b| b == b'\n') {
            let complete: Vec<u8> = self.partial.drain(..=end).collect();
            // `complete` ends with its newline: the lines are what lies between newlines.
            for raw in complete[..complete.len() - 1].split(|&b| b == b'\n') {
                self.line_no += 1;
                count += 1;
                self.line(raw)?;
            }
        }
        if self.partial.len() > MAX_LINE {
            return Err(at_line(
                &self.path,
                self.line_no + 1,
                "",
                format!("a line longer than {MAX_LINE} bytes"),
            ));
        }
        Ok(count)
    }

    /// Read what is left: a last line without its newline counts as a line once the
    /// follow ends.
    pub fn finish(&mut self) -> Result<(), FileError> {
        self.poll()?;
        if !self.partial.is_empty() {
            let raw = std::mem::take(&mut self.partial);
            self.line_no += 1;
            self.line(&raw)?;
        }
        Ok(())
    }

    fn line(&mut self, raw: &[u8]) -> Result<(), FileError> {
        let line_no = self.line_no;
        let Ok(text) = std::str::from_utf8(raw) else {
            return self.bad(at_line(&self.path, line_no, "", "not UTF-8 text"));
        };
        let text = text.trim_end_matches('\r');
        if text.trim().is_empty() {
            return Ok(());
        }
        let row = if self.jsonl {
            json_row(text)
        } else {
            let mut rdr = csv::ReaderBuilder::new()
                .has_headers(false)
                .flexible(true)
                .trim(csv::Trim::All)
                .from_reader(text.as_bytes());
            let mut rec = csv::StringRecord::new();
            if let Err(e) = rdr.read_record(&mut rec) {
                return self.bad(at_line(&self.path, line_no, "", csv_text(&e)));
            }
            match &self.columns {
                None => {
                    let cols = CsvColumns::new(&rec)
                        .map_err(|e| at_line(&self.path, line_no, "header", e.to_string()))?;
                    self.columns = Some((cols, rec.len()));
                    return Ok(());
                }
                Some((_, n)) if rec.len() != *n => {
                    let m = format!("{} cells where the header has {n}", rec.len());
                    return self.bad(at_line(&self.path, line_no, "", m));
                }
                Some((cols, _)) => cols.row(&rec),
            }
        };
        self.rows += 1;
        let res = row.and_then(|r| self.ingest.add(r, &mut self.analyzer));
        match res {
            Ok(()) => Ok(()),
            Err((field, m)) => self.bad(at_line(&self.path, line_no, &field, m)),
        }
    }

    fn bad(&mut self, e: FileError) -> Result<(), FileError> {
        if self.options.skip_bad_rows {
            self.skips.add(&e);
            Ok(())
        } else {
            Err(e)
        }
    }

    /// Bytes of the file read so far (its growth, for `--idle`).
    pub fn bytes_read(&self) -> u64 {
        self.offset
    }

    /// The full report of what was read so far.
    pub fn report(&self) -> NisReport {
        let mut r = self.analyzer.report();
        let mut source = LogSource::new(&self.path, if self.jsonl { "jsonl" } else { "csv" });
        source.rows = self.rows;
        source.skipped_rows = self.skips.count;
        source.notes.extend(self.skips.note());
        r.sources = vec![source];
        r
    }

    /// The status line's numbers.
    pub fn status(&self) -> Status {
        let r = self.analyzer.report();
        let time = r
            .sensors
            .iter()
            .map(|s| s.time_span.1)
            .fold(f64::NAN, f64::max);
        let windows = r
            .sensors
            .iter()
            .filter_map(|s| s.window.last.map(|w| (s.name.clone(), w.0, w.1, w.2)))
            .collect();
        Status {
            time,
            updates: r.overall.updates,
            outliers: r.overall.outliers,
            nis_per_dof: r.overall.nis_per_dof,
            interval: (r.overall.interval.lower, r.overall.interval.upper),
            windows,
            verdict: r.verdict,
            skipped: self.skips.count,
        }
    }
}

/// What the live status line shows.
#[derive(Debug, Clone)]
pub struct Status {
    /// Time of the latest update, seconds.
    pub time: f64,
    /// Updates so far.
    pub updates: usize,
    /// Outliers so far.
    pub outliers: usize,
    /// Running NIS per degree of freedom, all sensors.
    pub nis_per_dof: f64,
    /// Its interval at the test level.
    pub interval: (f64, f64),
    /// Per sensor, its latest window average and interval.
    pub windows: Vec<(String, f64, f64, f64)>,
    /// The verdict so far.
    pub verdict: Verdict,
    /// Malformed rows skipped so far.
    pub skipped: usize,
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.updates == 0 {
            return write!(f, "waiting for updates…");
        }
        write!(
            f,
            "t {} s | {} updates | NIS/dof {} in [{}, {}]",
            short(self.time),
            self.updates,
            short(self.nis_per_dof),
            short(self.interval.0),
            short(self.interval.1)
        )?;
        if !self.windows.is_empty() {
            write!(f, " | window")?;
            for (name, v, lo, hi) in &self.windows {
                let mark = if v < lo || v > hi { " ✗" } else { "" };
                write!(
                    f,
                    " {name} {} [{}, {}]{mark}",
                    short(*v),
                    short(*lo),
                    short(*hi)
                )?;
            }
        }
        if self.outliers > 0 {
            write!(f, " | {} outliers", self.outliers)?;
        }
        if self.skipped > 0 {
            write!(f, " | {} rows skipped", self.skipped)?;
        }
        write!(f, " | {}", self.verdict.label())
    }
}
