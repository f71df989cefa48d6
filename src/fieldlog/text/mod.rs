//! The generic field log: one row per update, CSV or JSON Lines (`docs/fieldlog.md`).
//!
//! CSV: columns `time`, `sensor`, the innovation `nu_1 … nu_M` and its covariance as cells
//! `S_i_j` (all of them, one triangle, or the diagonal alone: a missing off-diagonal entry
//! is taken from the other triangle, else 0), or a precomputed `nis` with `dof`. A sensor of
//! dimension m fills `nu_1 … nu_m` and leaves the rest empty. JSON Lines: `time`, `sensor`,
//! `nu`, and `S` as a full matrix, its lower triangle (rows of 1, 2, … entries) or the list
//! of its diagonal; or `nis` and `dof`.

use std::io::{BufRead, BufReader};
use std::path::Path;

use serde_json::Value;

use super::analysis::NisAnalyzer;
use super::ingest::{Ingest, MAX_DIM, Row, Skips};
use super::{LogSource, ReadOptions};
use crate::input::FileError;
use crate::records::SensorRecord;

mod check;
mod columns;

pub(super) use check::{check_sensor, symmetric};
pub(super) use columns::CsvColumns;

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
