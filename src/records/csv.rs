//! CSV records: a header, then one row per run and step; each quantity flattened into
//! columns with 1-based indices (`e_1`, `P_1_2`, `nu_radar_1`). What MATLAB's
//! `writetable`, Octave's `csvwrite` after a header line, and pandas write.

use std::collections::{HashMap, HashSet};
use std::path::Path;

use super::error::RecordError;
use super::names::{Quantity, parse_column};
use super::rows::{Found, Keys, Row, fits, infer_layout, shown, step_record};
use super::{Layout, MAX_STEPS, StepSink};
use crate::input::FileError;
use crate::userfile::{self, LineCapped};

/// Where each quantity's numbers sit in a row.
struct Columns {
    run: usize,
    step: usize,
    /// Per quantity, the column of each entry (row-major), `None` for a matrix entry given
    /// only in the other triangle's column.
    quantities: HashMap<Quantity, Vec<Option<usize>>>,
    /// The quantity columns' sizes, for the layout.
    found: Found,
}

/// The file's reader: through `userfile`, so a FIFO or a device is refused and a row is
/// at most `userfile::MAX_LINE` bytes.
type Reader = csv::Reader<LineCapped<std::fs::File>>;

fn open(path: &Path) -> Result<Reader, FileError> {
    userfile::csv_reader(
        path,
        csv::ReaderBuilder::new()
            .has_headers(true)
            .trim(csv::Trim::All),
    )
}

fn csv_message(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::Io(io) => io.to_string(),
        csv::ErrorKind::Utf8 { .. } => "not UTF-8 text".into(),
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => format!("{len} fields where the header has {expected_len}"),
        _ => e.to_string(),
    }
}

fn line_error(
    path: &Path,
    line: Option<u64>,
    field: &str,
    message: impl Into<String>,
) -> FileError {
    let mut e = FileError::new(path, field, message);
    e.line = line.map(|l| l as usize);
    e
}

/// A quantity's column: its entry's indices (a matrix's (a, b), a vector's (j, 0)) and
/// where it is in the row.
type Cell = ([usize; 2], usize);

fn columns(path: &Path, rdr: &mut Reader) -> Result<Columns, FileError> {
    let header = rdr
        .headers()
        .map_err(|e| line_error(path, Some(1), "header", csv_message(&e)))?
        .clone();
    userfile::check_columns(path, header.len())?;
    let mut run = None;
    let mut step = None;
    // Per quantity, in the order of its first column: its (indices, column) pairs. A
    // matrix entry's indices are (a, b), a vector's (j, 0), a scalar's (0, 0).
    let mut ids: HashMap<Quantity, usize> = HashMap::new();
    let mut lists: Vec<(Quantity, Vec<Cell>)> = Vec::new();
    // Every (quantity, indices) seen: a duplicate is found by hashing, not by a scan of the
    // quantity's columns (which made a header of n columns cost n²).
    let mut seen: HashSet<(usize, [usize; 2])> = HashSet::new();
    for (c, name) in header.iter().enumerate() {
        // MATLAB's writetable may start the file with a byte-order mark.
        let name = name.trim_start_matches('\u{feff}');
        let (q, idx) = parse_column(name)
            .or_else(|| {
                Quantity::parse(name)
                    .filter(|q| q.rank() == 0)
                    .map(|q| (q, vec![]))
            })
            .ok_or_else(|| {
                line_error(
                    path,
                    Some(1),
                    "header",
                    format!(
                        "unknown column '{}' (see docs/src/records.md for the names)",
                        shown(name)
                    ),
                )
            })?;
        match q {
            Quantity::Run => run = Some(c),
            Quantity::Step => step = Some(c),
            q => {
                let id = *ids.entry(q).or_insert_with_key(|q| {
                    lists.push((q.clone(), Vec::new()));
                    lists.len() - 1
                });
                let at = [
                    idx.first().copied().unwrap_or(0),
                    idx.get(1).copied().unwrap_or(0),
                ];
                if !seen.insert((id, at)) {
                    return Err(line_error(path, Some(1), name, "column appears twice"));
                }
                lists[id].1.push((at, c));
            }
        }
    }
    let run = run.ok_or_else(|| line_error(path, Some(1), "header", "no 'run' column"))?;
    let step = step.ok_or_else(|| line_error(path, Some(1), "header", "no 'step' column"))?;
    let mut quantities = HashMap::new();
    let mut found = Found::new();
    for (q, list) in lists {
        let (dims, slots) = slots_of(path, &q, &list)?;
        found.push((q.clone(), dims));
        quantities.insert(q, slots);
    }
    Ok(Columns {
        run,
        step,
        quantities,
        found,
    })
}

/// Quantity `q`'s dimensions and the column of each entry (row-major; `None` for a matrix
/// entry given only in the other triangle's column), from its columns `list`; an error
/// names the first entry missing.
fn slots_of(
    path: &Path,
    q: &Quantity,
    list: &[Cell],
) -> Result<(Vec<usize>, Vec<Option<usize>>), FileError> {
    let label = q.name();
    match q.rank() {
        0 => Ok((vec![], vec![Some(list[0].1)])),
        1 => {
            let n = list.iter().map(|(i, _)| i[0] + 1).max().unwrap_or(0);
            // The first gap is found among the columns there are, before anything the size
            // of an index (`e_99999999999`) is allocated.
            let given: HashSet<usize> = list.iter().map(|(i, _)| i[0]).collect();
            if let Some(j) = (0..n).find(|j| !given.contains(j)) {
                return Err(line_error(
                    path,
                    Some(1),
                    "header",
                    format!("column {label}_{} missing ({label} has {n} entries)", j + 1),
                ));
            }
            let mut slots = vec![None; n];
            for &(i, c) in list {
                slots[i[0]] = Some(c);
            }
            Ok((vec![n], slots))
        }
        _ => {
            let n = list
                .iter()
                .map(|(i, _)| i[0].max(i[1]) + 1)
                .max()
                .unwrap_or(0);
            // As for vectors: every (a, b) column present covers at most two entries, so a
            // gap turns up within 2·len + 1 entries, and the n × n slots are allocated only
            // for a matrix whose triangle is complete (n² ≤ 2·len + n).
            let given: HashSet<(usize, usize)> = list.iter().map(|(i, _)| (i[0], i[1])).collect();
            for a in 0..n {
                for b in 0..n {
                    if !given.contains(&(a, b)) && !given.contains(&(b, a)) {
                        return Err(line_error(
                            path,
                            Some(1),
                            "header",
                            format!(
                                "column {label}_{}_{} missing ({label} is {n}×{n}: give every entry of one triangle)",
                                a + 1,
                                b + 1
                            ),
                        ));
                    }
                }
            }
            let mut slots = vec![None; n * n];
            for &(i, c) in list {
                slots[i[0] * n + i[1]] = Some(c);
            }
            Ok((vec![n, n], slots))
        }
    }
}

/// An unsigned integer cell (`3`, or `3.0` as MATLAB may write it).
fn index_cell(cell: &str) -> Option<usize> {
    if let Ok(v) = cell.parse::<usize>() {
        return Some(v);
    }
    let v = cell.parse::<f64>().ok()?;
    (v >= 0.0 && v.fract() == 0.0 && v < 9.0e15).then_some(v as usize)
}

/// Read the next row into `rec`; `false` at the end. A row that cannot be read is an
/// error naming its line.
fn next_row(path: &Path, rdr: &mut Reader, rec: &mut csv::StringRecord) -> Result<bool, FileError> {
    rdr.read_record(rec).map_err(|e| {
        let line = e.position().map(|p| p.line());
        line_error(path, line, "", csv_message(&e))
    })
}

/// The layout and the number of steps (the largest step) of a CSV records file.
pub(super) fn scan(path: &Path) -> Result<(Layout, usize), FileError> {
    let mut rdr = open(path)?;
    let cols = columns(path, &mut rdr)?;
    let layout = infer_layout(&cols.found)
        .map_err(|e| line_error(path, Some(1), "header", e.to_string()))?;
    let mut steps = 0;
    let mut rec = csv::StringRecord::new();
    while next_row(path, &mut rdr, &mut rec)? {
        let line = rec.position().map(|p| p.line());
        let k = index_cell(&rec[cols.step])
            .filter(|&k| k >= 1)
            .ok_or_else(|| {
                line_error(
                    path,
                    line,
                    "step",
                    format!("'{}' is not a step (1, 2, …)", shown(&rec[cols.step])),
                )
            })?;
        if k > MAX_STEPS {
            return Err(line_error(
                path,
                line,
                "step",
                format!("{k} is above the limit of {MAX_STEPS} steps per run"),
            ));
        }
        steps = steps.max(k);
    }
    if steps == 0 {
        return Err(FileError::new(path, "", "no rows"));
    }
    Ok((layout, steps))
}

/// One CSV row as a [`Row`].
struct CsvRow<'a> {
    rec: &'a csv::StringRecord,
    cols: &'a Columns,
    headers: &'a csv::StringRecord,
}

impl CsvRow<'_> {
    fn number(&self, c: usize) -> Result<f64, RecordError> {
        let cell = &self.rec[c];
        if cell.is_empty() {
            return Ok(f64::NAN);
        }
        cell.parse::<f64>().map_err(|_| RecordError::NotANumber {
            column: self.headers[c].to_string(),
            cell: shown(cell),
        })
    }
}

impl Row for CsvRow<'_> {
    fn values(&mut self, q: &Quantity) -> Result<Option<Vec<f64>>, RecordError> {
        let Some(slots) = self.cols.quantities.get(q) else {
            return Ok(None);
        };
        let n = if q.rank() == 2 {
            (slots.len() as f64).sqrt() as usize
        } else {
            0
        };
        let mut out = Vec::with_capacity(slots.len());
        for (k, slot) in slots.iter().enumerate() {
            let c = match slot {
                Some(c) => *c,
                // The other triangle's column.
                None => slots[(k % n) * n + k / n].expect("one triangle is complete"),
            };
            out.push(self.number(c)?);
        }
        Ok(Some(out))
    }

    fn diverged(&mut self) -> Result<Option<String>, RecordError> {
        let Some(slots) = self.cols.quantities.get(&Quantity::Diverged) else {
            return Ok(None);
        };
        let c = slots[0].expect("a scalar column");
        let v = self.number(c)?;
        Ok((v.is_finite() && v != 0.0).then(|| "marked diverged in the records".to_string()))
    }
}

/// Stream a CSV records file into `sink`, which expects `layout`.
pub(super) fn feed<E: std::error::Error>(
    path: &Path,
    layout: &Layout,
    sink: &mut dyn StepSink<Error = E>,
) -> Result<(), FileError> {
    let mut rdr = open(path)?;
    let cols = columns(path, &mut rdr)?;
    let header_error =
        |e: super::error::LayoutError| line_error(path, Some(1), "header", e.to_string());
    let own = infer_layout(&cols.found).map_err(header_error)?;
    fits(&own, layout).map_err(header_error)?;
    let headers = rdr
        .headers()
        .map_err(|e| line_error(path, Some(1), "header", csv_message(&e)))?
        .clone();
    let keys = Keys::new(layout);
    let mut rec = csv::StringRecord::new();
    while next_row(path, &mut rdr, &mut rec)? {
        let line = rec.position().map(|p| p.line());
        let run = index_cell(&rec[cols.run]).ok_or_else(|| {
            line_error(
                path,
                line,
                "run",
                format!("'{}' is not a run index (0, 1, …)", shown(&rec[cols.run])),
            )
        })?;
        let step = index_cell(&rec[cols.step])
            .filter(|&k| k >= 1)
            .ok_or_else(|| {
                line_error(
                    path,
                    line,
                    "step",
                    format!("'{}' is not a step (1, 2, …)", shown(&rec[cols.step])),
                )
            })?;
        let mut row = CsvRow {
            rec: &rec,
            cols: &cols,
            headers: &headers,
        };
        let r = step_record(layout, &keys, run, step, &mut row)
            .map_err(|e| line_error(path, line, "", e.to_string()))?;
        sink.push(r)
            .map_err(|e| line_error(path, line, "", e.to_string()))?;
    }
    Ok(())
}
