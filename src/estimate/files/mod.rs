//! Measurement records on disk (`docs/measurements.md`): CSV (`run,step,z_1,…,z_m`), JSON
//! Lines (`{"run": 0, "step": 1, "z": [..]}`) and NumPy (one array of shape (N, T, m) or
//! (T, m), in a `.npy` file or as `z` in an `.npz` archive). A missing component is an empty
//! cell, `NaN` or `null`; runs are sequences, each with steps 1, 2, … without gaps.

mod write;

pub use write::record_bytes;

use std::collections::HashSet;
use std::path::Path;

use serde_json::Value;

use super::{MeasurementRecord, Sequence};
use crate::input::FileError;

/// Most values (measurement components, all runs and steps together) a record may have:
/// the record is held in memory, 8 bytes a value, and a CSV of empty cells costs one byte
/// of file a value, so the cap bounds memory (docs/measurements.md, Limits).
pub const MAX_VALUES: usize = 20_000_000;

fn at(path: &Path, line: usize, field: &str, m: impl Into<String>) -> FileError {
    let mut e = FileError::new(path, field, m);
    e.line = Some(line);
    e
}

/// Builds sequences from rows that arrive in order.
struct Builder {
    /// What the values are called (`z`, `x`), for messages.
    prefix: &'static str,
    dim: Option<usize>,
    sequences: Vec<Sequence>,
    runs: Vec<usize>,
    seen: HashSet<usize>,
    values: usize,
}

impl Builder {
    fn new(prefix: &'static str) -> Self {
        Builder {
            prefix,
            dim: None,
            sequences: Vec::new(),
            runs: Vec::new(),
            seen: HashSet::new(),
            values: 0,
        }
    }

    /// Add run `run`, step `step` at `time` (s, where the record has times) with values `z`
    /// (NaN: missing); `Err((field, message))`.
    fn row(
        &mut self,
        run: usize,
        step: usize,
        time: Option<f64>,
        z: &[f64],
    ) -> Result<(), (String, String)> {
        let m = *self.dim.get_or_insert(z.len());
        if z.len() != m {
            return Err((
                self.prefix.into(),
                format!("{} components, earlier rows {m}", z.len()),
            ));
        }
        if let Some(j) = z.iter().position(|v| v.is_infinite()) {
            return Err((format!("{}_{}", self.prefix, j + 1), "not finite".into()));
        }
        self.values += m;
        if self.values > MAX_VALUES {
            return Err((self.prefix.into(), format!("more than {MAX_VALUES} values")));
        }
        if self.runs.last() != Some(&run) {
            if !self.seen.insert(run) {
                return Err((
                    "run".into(),
                    format!("run {run} appears twice (a run's rows must come together)"),
                ));
            }
            self.runs.push(run);
            self.sequences.push(Sequence {
                steps: 0,
                z: Vec::new(),
                time: Vec::new(),
            });
        }
        let s = self.sequences.last_mut().expect("pushed above");
        if step != s.steps + 1 {
            return Err((
                "step".into(),
                format!(
                    "run {run}: step {step} follows step {} (steps go 1, 2, … without gaps)",
                    s.steps
                ),
            ));
        }
        if let Some(t) = time {
            // Every row gives a time or none does; each after the last, the first after the
            // filter's initial state at 0.
            if s.time.len() != s.steps {
                return Err((
                    "time".into(),
                    format!("run {run}: some steps have a time and others not"),
                ));
            }
            let last = s.time.last().copied().unwrap_or(0.0);
            if !(t.is_finite() && t > last) {
                return Err((
                    "time".into(),
                    format!(
                        "run {run}, step {step}: {t} is not after {last} (times are seconds since the filter's initial state, increasing)"
                    ),
                ));
            }
            s.time.push(t);
        } else if !s.time.is_empty() {
            return Err((
                "time".into(),
                format!("run {run}: some steps have a time and others not"),
            ));
        }
        s.steps += 1;
        s.z.extend_from_slice(z);
        Ok(())
    }

    fn finish(self, path: &Path) -> Result<MeasurementRecord, FileError> {
        let dim = self
            .dim
            .filter(|_| !self.sequences.is_empty())
            .ok_or_else(|| FileError::new(path, "", "no measurements"))?;
        Ok(MeasurementRecord {
            dim,
            sequences: self.sequences,
        })
    }
}

/// A CSV reader's error on one line.
fn csv_message(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => format!("{len} cells where the header has {expected_len}"),
        csv::ErrorKind::Utf8 { .. } => "not UTF-8 text".into(),
        csv::ErrorKind::Io(io) => format!("cannot read: {io}"),
        _ => crate::records::shown_up_to(&e.to_string(), 120),
    }
}

fn index(text: &str, what: &str) -> Result<usize, (String, String)> {
    text.trim().parse::<usize>().map_err(|_| {
        (
            what.to_string(),
            format!(
                "'{}' is not a whole number ≥ 0",
                crate::records::shown_up_to(text, 24)
            ),
        )
    })
}

/// Read a measurement record (by extension: `.csv`, `.jsonl`, `.npy`, `.npz`).
pub fn read_measurements(path: &Path) -> Result<MeasurementRecord, FileError> {
    read_named(path, "z")
}

/// Read reference states recorded beside a measurement record, in the same layout with
/// `x` for `z` (columns `x_1 … x_n`, JSON key `x`, array `x`), as `simulate --truth` writes
/// them: `dim` is then the state's n.
pub fn read_states(path: &Path) -> Result<MeasurementRecord, FileError> {
    read_named(path, "x")
}

/// A record whose values are named `prefix` (`z`: measurements, `x`: states).
fn read_named(path: &Path, prefix: &'static str) -> Result<MeasurementRecord, FileError> {
    crate::input::note_input(path);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("csv") => read_csv(path, prefix),
        Some("jsonl") | Some("ndjson") => read_jsonl(path, prefix),
        Some("npy") | Some("npz") => read_numpy(path, prefix),
        _ => Err(FileError::new(
            path,
            "",
            "not a measurement record: expected .csv, .jsonl, .npy or .npz (docs/src/measurements.md)",
        )),
    }
}

fn read_csv(path: &Path, prefix: &'static str) -> Result<MeasurementRecord, FileError> {
    let column = format!("{prefix}_");
    let mut rdr = crate::userfile::csv_reader(
        path,
        csv::ReaderBuilder::new()
            .has_headers(true)
            .trim(csv::Trim::All),
    )?;
    let header = rdr
        .headers()
        .map_err(|e| at(path, 1, "header", csv_message(&e)))?
        .clone();
    crate::userfile::check_columns(path, header.len())?;
    let (mut run, mut step, mut time) = (None, None, None);
    let mut z: Vec<(usize, usize)> = Vec::new();
    for (c, name) in header.iter().enumerate() {
        match name {
            "run" => run = Some(c),
            "step" => step = Some(c),
            "time" => time = Some(c),
            _ => match name
                .strip_prefix(column.as_str())
                .and_then(|j| j.parse::<usize>().ok())
            {
                Some(j) if j >= 1 => z.push((j, c)),
                _ => {
                    return Err(at(
                        path,
                        1,
                        "header",
                        format!(
                            "unknown column '{}' (expected run, step, time, {prefix}_1 … {prefix}_m)",
                            crate::records::shown_up_to(name, 40)
                        ),
                    ));
                }
            },
        }
    }
    let step = step.ok_or_else(|| at(path, 1, "header", "no 'step' column"))?;
    z.sort_unstable();
    if z.is_empty() || z.iter().enumerate().any(|(i, (j, _))| *j != i + 1) {
        return Err(at(
            path,
            1,
            "header",
            format!("the {prefix} columns must be {prefix}_1 … {prefix}_m without gaps"),
        ));
    }
    let mut b = Builder::new(prefix);
    let mut rec = csv::StringRecord::new();
    let mut values = vec![0.0; z.len()];
    loop {
        let line = rdr.position().line() as usize;
        match rdr.read_record(&mut rec) {
            Ok(false) => break,
            Ok(true) => {}
            Err(e) => {
                let line = e.position().map_or(line, |p| p.line() as usize);
                return Err(at(path, line, "", csv_message(&e)));
            }
        }
        let line = rec.position().map_or(line, |p| p.line() as usize);
        let res = (|| {
            let r = match run {
                Some(c) => index(rec.get(c).unwrap_or(""), "run")?,
                None => 0,
            };
            let s = index(rec.get(step).unwrap_or(""), "step")?;
            let t = match time {
                Some(c) => {
                    let t = rec.get(c).unwrap_or("");
                    Some(t.parse::<f64>().map_err(|_| {
                        (
                            "time".to_string(),
                            format!("'{}' is not a number", crate::records::shown_up_to(t, 24)),
                        )
                    })?)
                }
                None => None,
            };
            for (k, (j, c)) in z.iter().enumerate() {
                let t = rec.get(*c).unwrap_or("");
                values[k] = if t.is_empty() {
                    f64::NAN
                } else {
                    t.parse::<f64>().map_err(|_| {
                        (
                            format!("{prefix}_{j}"),
                            format!("'{}' is not a number", crate::records::shown_up_to(t, 24)),
                        )
                    })?
                };
            }
            b.row(r, s, t, &values)
        })();
        res.map_err(|(field, m)| at(path, line, &field, m))?;
    }
    b.finish(path)
}

fn read_jsonl(path: &Path, prefix: &'static str) -> Result<MeasurementRecord, FileError> {
    use std::io::BufRead;
    let mut b = Builder::new(prefix);
    for (i, line) in crate::userfile::text_lines(path)?.lines().enumerate() {
        let n = i + 1;
        let line = line.map_err(|e| at(path, n, "", format!("cannot read: {e}")))?;
        if line.trim().is_empty() {
            continue;
        }
        let res = (|| {
            let obj =
                crate::records::json_object(&line).map_err(|e| (String::new(), e.to_string()))?;
            let int = |k: &str, default: Option<usize>| match obj.get(k) {
                None => default.ok_or_else(|| (k.to_string(), "missing".to_string())),
                Some(v) => v
                    .as_u64()
                    .and_then(|v| usize::try_from(v).ok())
                    .ok_or_else(|| (k.to_string(), "not a whole number ≥ 0".to_string())),
            };
            let r = int("run", Some(0))?;
            let s = int("step", None)?;
            let t = match obj.get("time") {
                None => None,
                Some(v) => Some(
                    v.as_f64()
                        .ok_or_else(|| ("time".to_string(), "not a number".to_string()))?,
                ),
            };
            let z: Vec<f64> = obj
                .get(prefix)
                .and_then(Value::as_array)
                .ok_or_else(|| (prefix.to_string(), "missing or not a list".to_string()))?
                .iter()
                .map(|v| match v {
                    Value::Null => Ok(f64::NAN),
                    v => v
                        .as_f64()
                        .ok_or_else(|| (prefix.to_string(), "not a number or null".to_string())),
                })
                .collect::<Result<_, _>>()?;
            b.row(r, s, t, &z)
        })();
        res.map_err(|(field, m)| at(path, n, &field, m))?;
    }
    b.finish(path)
}

fn read_numpy(path: &Path, prefix: &str) -> Result<MeasurementRecord, FileError> {
    let raw = crate::records::read_numpy_arrays(&[path.to_path_buf()])?;
    let single = raw.len() == 1;
    let (name, shape, data) = raw
        .into_iter()
        .find(|(n, _, _)| single || n == prefix)
        .ok_or_else(|| {
            FileError::new(
                path,
                format!("array {prefix}"),
                format!("missing (the values are the array named {prefix})"),
            )
        })?;
    let field = format!("array {name}");
    let (runs, steps, m) = match shape[..] {
        [t, m] => (1, t, m),
        [n, t, m] => (n, t, m),
        _ => {
            return Err(FileError::new(
                path,
                &field,
                format!("shape {shape:?}: expected (N, T, m) or (T, m)"),
            ));
        }
    };
    if runs == 0 || steps == 0 || m == 0 {
        return Err(FileError::new(
            path,
            &field,
            format!("shape {shape:?} holds no measurements"),
        ));
    }
    if data.len() > MAX_VALUES {
        return Err(FileError::new(
            path,
            &field,
            format!("shape {shape:?}: more than {MAX_VALUES} values"),
        ));
    }
    if let Some(i) = data.iter().position(|v| v.is_infinite()) {
        return Err(FileError::new(
            path,
            &field,
            format!("element {i} is not finite"),
        ));
    }
    // One run keeps the numbers read; several are cut from them.
    let sequences = if runs == 1 {
        vec![Sequence {
            steps,
            z: data,
            time: Vec::new(),
        }]
    } else {
        data.chunks(steps * m)
            .map(|c| Sequence {
                steps,
                z: c.to_vec(),
                time: Vec::new(),
            })
            .collect()
    };
    Ok(MeasurementRecord { dim: m, sequences })
}
