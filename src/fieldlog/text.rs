//! The generic field log: one row per update, CSV or JSON Lines (`docs/fieldlog.md`).
//!
//! CSV: columns `time`, `sensor`, the innovation `nu_1 … nu_M` and its covariance as cells
//! `S_i_j` (all of them, one triangle, or the diagonal alone: a missing off-diagonal entry
//! is taken from the other triangle, else 0), or a precomputed `nis` with `dof`. A sensor of
//! dimension m fills `nu_1 … nu_m` and leaves the rest empty. JSON Lines: `time`, `sensor`,
//! `nu`, and `S` as a full matrix, its lower triangle (rows of 1, 2, … entries) or the list
//! of its diagonal; or `nis` and `dof`.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::Path;

use serde_json::Value;

use super::analysis::NisAnalyzer;
use super::ingest::{Ingest, MAX_DIM, Row, Skips};
use super::{LogSource, ReadOptions};
use crate::input::FileError;
use crate::records::{SensorRecord, shown_up_to};

/// Where the cells of a CSV log sit.
#[derive(Debug, Clone)]
pub(super) struct CsvColumns {
    time: usize,
    sensor: usize,
    nu: Vec<usize>,
    s: HashMap<(usize, usize), usize>,
    nis: Option<usize>,
    dof: Option<usize>,
}

fn err_json(path: &Path, line: usize, field: &str, m: impl Into<String>) -> FileError {
    let mut e = FileError::new(path, field, m);
    e.line = Some(line);
    e
}

/// Whether the CSV / JSON Lines file at `path` is in the records format (it has `run` and
/// `step` and no `sensor`) rather than a field log.
pub(super) fn is_records(path: &Path) -> Result<bool, FileError> {
    let file = crate::userfile::open_io(path)
        .map_err(|e| FileError::new(path, "", format!("cannot read: {e}")))?;
    let mut first = String::new();
    BufReader::new(file)
        .take_line(&mut first)
        .map_err(|e| FileError::new(path, "", format!("cannot read: {e}")))?;
    // A byte-order mark is not part of the first column's name (the CSV readers drop it).
    let first = first.trim_start_matches('\u{feff}').trim();
    if first.starts_with('{') {
        let Ok(Value::Object(o)) = serde_json::from_str::<Value>(first) else {
            return Ok(false);
        };
        return Ok(o.contains_key("run") && o.contains_key("step") && !o.contains_key("sensor"));
    }
    let cells: Vec<String> = first
        .split(',')
        .map(|c| c.trim().trim_matches('"').to_string())
        .collect();
    let has = |n: &str| cells.iter().any(|c| c == n);
    Ok(has("run") && has("step") && !has("sensor"))
}

/// Read at most one line, bounded, for the format sniff.
trait TakeLine {
    fn take_line(self, into: &mut String) -> std::io::Result<()>;
}

impl<R: BufRead> TakeLine for R {
    fn take_line(self, into: &mut String) -> std::io::Result<()> {
        let mut bytes = Vec::new();
        self.take(1 << 20).read_until(b'\n', &mut bytes)?;
        *into = String::from_utf8_lossy(&bytes).into_owned();
        Ok(())
    }
}

/// `nu_<j>` → j (1-based), `S_<i>_<j>` → (i, j).
fn index(name: &str, prefix: &str) -> Option<Vec<usize>> {
    let rest = name.strip_prefix(prefix)?;
    let idx: Option<Vec<usize>> = rest
        .split('_')
        .map(|p| {
            p.parse::<usize>()
                .ok()
                .filter(|&i| (1..=MAX_DIM).contains(&i))
        })
        .collect();
    idx
}

/// What is wrong with a CSV log's header.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(super) enum HeaderError {
    /// A column given twice.
    #[error("column {0} appears twice")]
    Twice(String),
    /// A column of no known name (as an error quotes it).
    #[error("unknown column '{0}' (expected time, sensor, nu_<j>, S_<i>_<j>, nis, dof)")]
    Unknown(String),
    /// A column every log needs.
    #[error("no '{0}' column")]
    Missing(&'static str),
    /// A gap in the innovation's columns.
    #[error("nu columns must be nu_1 … nu_{m} without gaps (nu_{j} is missing)")]
    NuGap { m: usize, j: usize },
    /// A covariance entry beyond the innovation's components.
    #[error("column S_{i}_{j} beyond the {m} nu columns")]
    SBeyond { i: usize, j: usize, m: usize },
    /// Neither innovations nor a NIS.
    #[error("neither nu_<j> nor nis columns: nothing to judge")]
    NothingToJudge,
    /// A NIS without its degrees of freedom, or the other way round.
    #[error("a 'nis' column needs a 'dof' column, and the other way round")]
    NisWithoutDof,
}

impl CsvColumns {
    /// The columns of a header, or what is wrong with it.
    pub(super) fn new(header: &csv::StringRecord) -> Result<CsvColumns, HeaderError> {
        let mut time = None;
        let mut sensor = None;
        let mut nu: HashMap<usize, usize> = HashMap::new();
        let mut s = HashMap::new();
        let (mut nis, mut dof) = (None, None);
        for (c, name) in header.iter().enumerate() {
            let slot = match name {
                "time" => &mut time,
                "sensor" => &mut sensor,
                "nis" => &mut nis,
                "dof" => &mut dof,
                _ => {
                    if let Some(i) = index(name, "nu_").filter(|v| v.len() == 1) {
                        if nu.insert(i[0], c).is_some() {
                            return Err(HeaderError::Twice(name.to_string()));
                        }
                    } else if let Some(ij) = index(name, "S_").filter(|v| v.len() == 2) {
                        if s.insert((ij[0], ij[1]), c).is_some() {
                            return Err(HeaderError::Twice(name.to_string()));
                        }
                    } else {
                        return Err(HeaderError::Unknown(shown_up_to(name, 40)));
                    }
                    continue;
                }
            };
            if slot.replace(c).is_some() {
                return Err(HeaderError::Twice(name.to_string()));
            }
        }
        let time = time.ok_or(HeaderError::Missing("time"))?;
        let sensor = sensor.ok_or(HeaderError::Missing("sensor"))?;
        let m = nu.len();
        let mut nu_cols = Vec::with_capacity(m);
        for j in 1..=m {
            nu_cols.push(*nu.get(&j).ok_or(HeaderError::NuGap { m, j })?);
        }
        if let Some((&(i, j), _)) = s.iter().find(|((i, j), _)| *i > m || *j > m) {
            return Err(HeaderError::SBeyond { i, j, m });
        }
        if m == 0 && nis.is_none() {
            return Err(HeaderError::NothingToJudge);
        }
        if nis.is_some() != dof.is_some() {
            return Err(HeaderError::NisWithoutDof);
        }
        Ok(CsvColumns {
            time,
            sensor,
            nu: nu_cols,
            s,
            nis,
            dof,
        })
    }

    /// Parse one data row; `Err((field, message))`.
    pub(super) fn row(&self, rec: &csv::StringRecord) -> Result<Row, (String, String)> {
        let num = |c: usize, field: &str| number(cell(rec, c), field);
        let time = num(self.time, "time")?
            .filter(|t| t.is_finite())
            .ok_or_else(|| ("time".to_string(), "missing or not finite".to_string()))?;
        let sensor = cell(rec, self.sensor).to_string();
        check_sensor(&sensor).map_err(|e| ("sensor".to_string(), e.to_string()))?;
        let mut nu = Vec::new();
        for (j, &c) in self.nu.iter().enumerate() {
            match num(c, &format!("nu_{}", j + 1))? {
                Some(v) if nu.len() == j => nu.push(v),
                Some(_) => {
                    return Err((
                        format!("nu_{}", j + 1),
                        format!("filled after an empty nu_{}", nu.len() + 1),
                    ));
                }
                None => {}
            }
        }
        if nu.is_empty() {
            let (Some(nc), Some(dc)) = (self.nis, self.dof) else {
                return Err(("nu_1".into(), "empty: no innovation in this row".into()));
            };
            let nis = num(nc, "nis")?
                .ok_or_else(|| ("nis".to_string(), "empty, and no nu either".to_string()))?;
            let dof = num(dc, "dof")?.ok_or_else(|| ("dof".to_string(), "empty".to_string()))?;
            return Ok(Row {
                time,
                sensor,
                record: SensorRecord::Normalized { nis, dof, u: None },
            });
        }
        let s = self.covariance(rec, nu.len())?;
        Ok(Row {
            time,
            sensor,
            record: SensorRecord::Raw { nu, s },
        })
    }

    /// The row's S for an innovation of `m` components (row-major): all of it, one
    /// triangle, or its diagonal alone; symmetric, with no entry beyond `m`.
    fn covariance(&self, rec: &csv::StringRecord, m: usize) -> Result<Vec<f64>, (String, String)> {
        let cell_of = |i: usize, j: usize| -> Result<Option<f64>, (String, String)> {
            match self.s.get(&(i, j)) {
                Some(&c) => number(cell(rec, c), &format!("S_{i}_{j}")),
                None => Ok(None),
            }
        };
        // A diagonal S leaves every off-diagonal cell empty; any filled one means the row
        // gives a triangle or the full matrix, so every pair must then have an entry.
        let mut off_diagonal = false;
        for i in 1..=m {
            for j in 1..=m {
                if i != j && cell_of(i, j)?.is_some() {
                    off_diagonal = true;
                }
            }
        }
        let mut s = vec![0.0; m * m];
        for i in 1..=m {
            for j in 1..=m {
                let v = match (cell_of(i, j)?, i == j) {
                    (Some(v), _) => v,
                    (None, true) => {
                        return Err((
                            format!("S_{i}_{i}"),
                            format!("empty for a sensor of {m} components"),
                        ));
                    }
                    (None, false) => match cell_of(j, i)? {
                        Some(v) => v,
                        None if !off_diagonal => 0.0,
                        None => {
                            return Err((
                                format!("S_{i}_{j}"),
                                format!(
                                    "empty, and so is S_{j}_{i}: give all of S, one triangle, or its diagonal alone"
                                ),
                            ));
                        }
                    },
                };
                s[(i - 1) * m + (j - 1)] = v;
            }
        }
        for (&(i, j), &c) in &self.s {
            if (i > m || j > m) && !cell(rec, c).is_empty() {
                return Err((
                    format!("S_{i}_{j}"),
                    format!("filled for a sensor of {m} components"),
                ));
            }
        }
        symmetric(&s, m).map_err(|(i, j)| {
            (
                format!("S_{i}_{j}"),
                format!("differs from S_{j}_{i}: S must be symmetric"),
            )
        })?;
        Ok(s)
    }
}

/// Cell `c` of a row, trimmed (empty where the row is short).
fn cell(rec: &csv::StringRecord, c: usize) -> &str {
    rec.get(c).map(str::trim).unwrap_or("")
}

/// The number in cell text `t` (`None` when empty), or `(field, why not)`.
fn number(t: &str, field: &str) -> Result<Option<f64>, (String, String)> {
    if t.is_empty() {
        return Ok(None);
    }
    t.parse::<f64>().map(Some).map_err(|_| {
        (
            field.to_string(),
            format!("'{}' is not a number", shown_up_to(t, 24)),
        )
    })
}

/// Why a sensor name is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(super) enum SensorNameError {
    #[error("empty sensor name")]
    Empty,
    /// Too long or with control characters (the name, as an error quotes it).
    #[error("'{0}' is not a sensor name (at most 64 printable characters)")]
    Invalid(String),
}

pub(super) fn check_sensor(name: &str) -> Result<(), SensorNameError> {
    if name.is_empty() {
        return Err(SensorNameError::Empty);
    }
    if name.len() > 64 || name.chars().any(char::is_control) {
        return Err(SensorNameError::Invalid(shown_up_to(name, 24)));
    }
    Ok(())
}

/// `Err((i, j))` (1-based) where S is not symmetric to a relative 1e-9.
pub(super) fn symmetric(s: &[f64], m: usize) -> Result<(), (usize, usize)> {
    for i in 0..m {
        for j in 0..i {
            let (a, b) = (s[i * m + j], s[j * m + i]);
            if (a - b).abs() > 1e-9 * a.abs().max(b.abs()) {
                return Err((i + 1, j + 1));
            }
        }
    }
    Ok(())
}

/// Parse one JSON Lines row; `Err((field, message))`.
pub(super) fn json_row(line: &str) -> Result<Row, (String, String)> {
    let obj = crate::records::json_object(line).map_err(|e| (String::new(), e.to_string()))?;
    let f = |k: &str, m: &str| (k.to_string(), m.to_string());
    let time = obj
        .get("time")
        .and_then(Value::as_f64)
        .filter(|t| t.is_finite())
        .ok_or_else(|| f("time", "missing or not a finite number"))?;
    let sensor = obj
        .get("sensor")
        .and_then(Value::as_str)
        .ok_or_else(|| f("sensor", "missing or not a string"))?
        .to_string();
    check_sensor(&sensor).map_err(|e| ("sensor".to_string(), e.to_string()))?;
    let number = |v: &Value, k: &str| -> Result<f64, (String, String)> {
        v.as_f64().ok_or_else(|| f(k, "not a number"))
    };
    if let Some(nu) = obj.get("nu") {
        let nu: Vec<f64> = nu
            .as_array()
            .ok_or_else(|| f("nu", "not a list of numbers"))?
            .iter()
            .map(|v| number(v, "nu"))
            .collect::<Result<_, _>>()?;
        let m = nu.len();
        if m == 0 || m > MAX_DIM {
            return Err(f("nu", &format!("has {m} entries (1 to {MAX_DIM})")));
        }
        let sv = obj.get("S").and_then(Value::as_array).ok_or_else(|| {
            f(
                "S",
                "missing or not a list (full matrix, lower triangle, or diagonal)",
            )
        })?;
        let mut s = vec![0.0; m * m];
        if sv.iter().all(Value::is_number) {
            if sv.len() != m {
                return Err(f(
                    "S",
                    &format!("a diagonal of {} entries for {m} components", sv.len()),
                ));
            }
            for (j, v) in sv.iter().enumerate() {
                s[j * m + j] = number(v, "S")?;
            }
        } else {
            if sv.len() != m {
                return Err(f("S", &format!("{} rows for {m} components", sv.len())));
            }
            for (i, row) in sv.iter().enumerate() {
                let row = row.as_array().ok_or_else(|| f("S", "rows must be lists"))?;
                if row.len() != m && row.len() != i + 1 {
                    return Err(f(
                        "S",
                        &format!(
                            "row {} has {} entries: {m} (full) or {} (lower triangle)",
                            i + 1,
                            row.len(),
                            i + 1
                        ),
                    ));
                }
                for (j, v) in row.iter().enumerate() {
                    let x = number(v, "S")?;
                    s[i * m + j] = x;
                    if row.len() == i + 1 {
                        s[j * m + i] = x;
                    }
                }
            }
            symmetric(&s, m).map_err(|(i, j)| {
                f(
                    "S",
                    &format!("entry ({i}, {j}) differs from ({j}, {i}): S must be symmetric"),
                )
            })?;
        }
        return Ok(Row {
            time,
            sensor,
            record: SensorRecord::Raw { nu, s },
        });
    }
    let nis = obj
        .get("nis")
        .ok_or_else(|| f("nu", "missing (and no nis either)"))
        .and_then(|v| number(v, "nis"))?;
    let dof = obj
        .get("dof")
        .ok_or_else(|| f("dof", "missing (a nis needs its dof)"))
        .and_then(|v| number(v, "dof"))?;
    Ok(Row {
        time,
        sensor,
        record: SensorRecord::Normalized { nis, dof, u: None },
    })
}

/// Read a CSV or JSON Lines field log into `an`.
pub(super) fn read(
    path: &Path,
    options: &ReadOptions,
    an: &mut NisAnalyzer,
) -> Result<LogSource, FileError> {
    let jsonl = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("jsonl") || e.eq_ignore_ascii_case("ndjson"));
    let mut source = LogSource::new(path, if jsonl { "jsonl" } else { "csv" });
    let mut ingest = Ingest::default();
    let mut skips = Skips::default();
    let handle = |res: Result<(), FileError>, skips: &mut Skips| -> Result<(), FileError> {
        match res {
            Err(e) if options.skip_bad_rows => {
                skips.add(&e);
                Ok(())
            }
            other => other,
        }
    };
    if jsonl {
        for (i, line) in crate::userfile::text_lines(path)?.lines().enumerate() {
            let line_no = i + 1;
            let line =
                line.map_err(|e| err_json(path, line_no, "", format!("cannot read: {e}")))?;
            if line.trim().is_empty() {
                continue;
            }
            source.rows += 1;
            let res = json_row(&line)
                .and_then(|row| ingest.add(row, an))
                .map_err(|(field, m)| err_json(path, line_no, &field, m));
            handle(res, &mut skips)?;
        }
    } else {
        let mut rdr = crate::userfile::csv_reader(
            path,
            csv::ReaderBuilder::new()
                .has_headers(true)
                .flexible(true)
                .trim(csv::Trim::All),
        )?;
        let header = rdr
            .headers()
            .map_err(|e| err_json(path, 1, "header", csv_text(&e)))?
            .clone();
        crate::userfile::check_columns(path, header.len())?;
        let cols =
            CsvColumns::new(&header).map_err(|e| err_json(path, 1, "header", e.to_string()))?;
        let mut rec = csv::StringRecord::new();
        loop {
            let line_no = rdr.position().line() as usize;
            match rdr.read_record(&mut rec) {
                Ok(false) => break,
                Ok(true) => {}
                Err(e) => {
                    let line = e.position().map_or(line_no, |p| p.line() as usize);
                    // Invalid UTF-8 or an I/O failure: the reader cannot go on past it.
                    return Err(err_json(path, line, "", csv_text(&e)));
                }
            }
            let line_no = rec.position().map_or(line_no, |p| p.line() as usize);
            source.rows += 1;
            let res = if rec.len() != header.len() {
                Err(err_json(
                    path,
                    line_no,
                    "",
                    format!("{} cells where the header has {}", rec.len(), header.len()),
                ))
            } else {
                cols.row(&rec)
                    .and_then(|row| ingest.add(row, an))
                    .map_err(|(field, m)| err_json(path, line_no, &field, m))
            };
            handle(res, &mut skips)?;
        }
    }
    source.skipped_rows = skips.count;
    source.notes.extend(skips.note());
    Ok(source)
}

pub(super) fn csv_text(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::Io(io) => format!("cannot read: {io}"),
        csv::ErrorKind::Utf8 { .. } => "not UTF-8 text".into(),
        _ => e.to_string().lines().next().unwrap_or("").to_string(),
    }
}
