//! JSON Lines records: one object per run and step, keyed by quantity name, e.g.
//! `{"run": 0, "step": 1, "e": [..], "P": [[..], ..], "nu_radar": [..], "S_radar": [[..]]}`.
//! The same lines are what a worker may answer inline.

use std::io::BufRead;
use std::path::Path;

use serde_json::{Map, Value};

use super::error::RecordError;
use super::names::Quantity;
use super::rows::{Found, Keys, Row, infer_layout, shown, step_record};
use super::{Layout, MAX_STEPS, StepRecord, StepSink};
use crate::input::FileError;

/// A JSON number, or NaN for `null`.
fn number(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::Null => Some(f64::NAN),
        _ => None,
    }
}

/// A quantity's numbers and dimensions: a number, an array of numbers, or an array of
/// equal-length arrays (a matrix, row by row).
fn numbers(key: &str, v: &Value) -> Result<(Vec<f64>, Vec<usize>), RecordError> {
    let bad = || RecordError::NotNumbers(key.to_string());
    if let Some(x) = number(v) {
        return Ok((vec![x], vec![]));
    }
    let Value::Array(items) = v else {
        return Err(bad());
    };
    if items.iter().all(|i| number(i).is_some()) {
        return Ok((items.iter().filter_map(number).collect(), vec![items.len()]));
    }
    let mut out = Vec::new();
    let mut width = None;
    for row in items {
        let Value::Array(cells) = row else {
            return Err(bad());
        };
        if *width.get_or_insert(cells.len()) != cells.len() {
            return Err(RecordError::RaggedRows(key.to_string()));
        }
        for c in cells {
            out.push(number(c).ok_or_else(bad)?);
        }
    }
    Ok((out, vec![items.len(), width.unwrap_or(0)]))
}

/// The run and step of a record object.
fn run_step(obj: &Map<String, Value>) -> Result<(usize, usize), RecordError> {
    let index = |key: &'static str| -> Result<u64, RecordError> {
        let v = obj.get(key).ok_or(RecordError::NoIndex(key))?;
        v.as_u64()
            .or_else(|| {
                v.as_f64()
                    .filter(|x| *x >= 0.0 && x.fract() == 0.0 && *x < 9.0e15)
                    .map(|x| x as u64)
            })
            .ok_or_else(|| RecordError::BadIndex {
                key,
                value: v.to_string(),
            })
    };
    let run = index("run")? as usize;
    let step = index("step")? as usize;
    if step == 0 {
        return Err(RecordError::StepZero);
    }
    if step > MAX_STEPS {
        return Err(RecordError::StepAboveLimit(step));
    }
    Ok((run, step))
}

/// The quantities of one object, checked against the names.
fn found(obj: &Map<String, Value>) -> Result<Found, RecordError> {
    let mut f = Found::new();
    for (k, v) in obj {
        let q = Quantity::parse(k).ok_or_else(|| RecordError::UnknownKey(shown(k)))?;
        if matches!(q, Quantity::Run | Quantity::Step | Quantity::Diverged) {
            continue;
        }
        let (_, dims) = numbers(k, v)?;
        let dims = if q.rank() == 2 && dims.len() == 1 {
            // A matrix given flat, row-major.
            let n = (dims[0] as f64).sqrt().round() as usize;
            if n * n != dims[0] {
                return Err(RecordError::NotSquareCount {
                    key: k.clone(),
                    count: dims[0],
                });
            }
            vec![n, n]
        } else {
            dims
        };
        if dims.len() != q.rank() {
            return Err(RecordError::WrongRank {
                key: k.clone(),
                given: match dims.len() {
                    0 => "a number",
                    1 => "a list",
                    _ => "a matrix",
                },
                expected: ["number", "list", "matrix"][q.rank()],
            });
        }
        f.push((q, dims));
    }
    Ok(f)
}

struct JsonRow<'a>(&'a Map<String, Value>);

impl Row for JsonRow<'_> {
    fn values(&mut self, q: &Quantity) -> Result<Option<Vec<f64>>, RecordError> {
        let key = q.name();
        match self.0.get(&key) {
            None => Ok(None),
            Some(v) => numbers(&key, v).map(|(x, _)| Some(x)),
        }
    }

    fn diverged(&mut self) -> Result<Option<String>, RecordError> {
        Ok(match self.0.get("diverged") {
            None | Some(Value::Null) | Some(Value::Bool(false)) => None,
            Some(Value::String(s)) => Some(s.clone()),
            Some(Value::Number(n)) if n.as_f64() == Some(0.0) => None,
            Some(_) => Some("marked diverged in the records".to_string()),
        })
    }
}

pub(crate) fn object(line: &str) -> Result<Map<String, Value>, RecordError> {
    // A file written with a byte-order mark (Windows tools do) starts its first line with
    // one: JSON has none.
    let line = line.strip_prefix('\u{feff}').unwrap_or(line);
    let parsed = serde_json::from_str::<Value>(line).or_else(|e| {
        // Python's json module writes NaN and Infinity, which JSON has not: read them as
        // the null (NaN) they stand for, so a diverged filter reads as diverged.
        if line.contains("NaN") || line.contains("Infinity") {
            let fixed = line
                .replace("-Infinity", "null")
                .replace("Infinity", "null")
                .replace("NaN", "null");
            serde_json::from_str::<Value>(&fixed).map_err(|_| e)
        } else {
            Err(e)
        }
    });
    match parsed {
        Ok(Value::Object(m)) => Ok(m),
        Ok(_) => Err(RecordError::NotObject),
        Err(e) => Err(RecordError::NotJson(e.to_string())),
    }
}

/// One record line of an experiment of `layout`: a JSON object with `run`, `step` and
/// quantities by name.
pub fn parse_record_line(line: &str, layout: &Layout) -> Result<StepRecord, RecordError> {
    let obj = object(line)?;
    let (run, step) = run_step(&obj)?;
    for (q, _) in found(&obj)? {
        if let Some(s) = q.sensor()
            && layout.sensor(s).is_none()
        {
            return Err(RecordError::UnknownSensor {
                quantity: q.name(),
                sensor: s.to_string(),
                known: layout.sensors.iter().map(|e| e.name.clone()).collect(),
            });
        }
        if q.sensor().is_none() && layout.state.is_none() {
            return Err(RecordError::NoGroundTruth(q.name()));
        }
    }
    step_record(layout, &Keys::new(layout), run, step, &mut JsonRow(&obj))
}

/// The layout and the number of steps of a JSON Lines records file.
pub(super) fn scan(path: &Path) -> Result<(Layout, usize), FileError> {
    let mut all = Found::new();
    let mut steps = 0;
    for (i, line) in crate::userfile::text_lines(path)?.lines().enumerate() {
        let at = |m: String| {
            let mut e = FileError::new(path, "", m);
            e.line = Some(i + 1);
            e
        };
        let line = line.map_err(|e| at(format!("cannot read: {e}")))?;
        if line.trim().is_empty() {
            continue;
        }
        let obj = object(&line).map_err(|e| at(e.to_string()))?;
        let (_, step) = run_step(&obj).map_err(|e| at(e.to_string()))?;
        steps = steps.max(step);
        for (q, dims) in found(&obj).map_err(|e| at(e.to_string()))? {
            match all.iter().find(|(f, _)| *f == q) {
                Some((_, d)) if *d != dims => {
                    return Err(at(format!(
                        "{}: dimensions {dims:?}, but {d:?} on an earlier line",
                        q.name()
                    )));
                }
                Some(_) => {}
                None => all.push((q, dims)),
            }
        }
    }
    if steps == 0 {
        return Err(FileError::new(path, "", "no records"));
    }
    let layout = infer_layout(&all).map_err(|e| FileError::new(path, "", e.to_string()))?;
    Ok((layout, steps))
}

/// Stream a JSON Lines records file into `sink`, which expects `layout`.
pub(super) fn feed<E: std::error::Error>(
    path: &Path,
    layout: &Layout,
    sink: &mut dyn StepSink<Error = E>,
) -> Result<(), FileError> {
    for (i, line) in crate::userfile::text_lines(path)?.lines().enumerate() {
        let at = |m: String| {
            let mut e = FileError::new(path, "", m);
            e.line = Some(i + 1);
            e
        };
        let line = line.map_err(|e| at(format!("cannot read: {e}")))?;
        if line.trim().is_empty() {
            continue;
        }
        let r = parse_record_line(&line, layout).map_err(|e| at(e.to_string()))?;
        sink.push(r).map_err(|e| at(e.to_string()))?;
    }
    Ok(())
}
