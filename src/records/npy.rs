//! NumPy records: an `.npz` archive (`np.savez`) or `.npy` files, one array per quantity,
//! each named after it (`e`, `P`, `nu_radar`), with leading axes (N runs, T steps).

use std::io::Read;
use std::path::{Path, PathBuf};

use super::files::{Found, Keys, Row, fits, infer_layout, step_record};
use super::names::Quantity;
use super::{Layout, MAX_STEPS, StepSink};
use crate::input::FileError;

/// Largest array the reader accepts, in elements: 2³¹ doubles are 16 GiB.
const MAX_ELEMENTS: u64 = 1 << 31;
/// Most bytes reserved from an array's header before its data is read.
const PREALLOCATE: usize = 1 << 24;

/// One array, as doubles in C order.
struct Array {
    quantity: Quantity,
    /// A covariance without the runs axis, shape (1, T, n, n) here: the same in every run
    /// (a linear filter's P and S do not depend on the data).
    shared: bool,
    shape: Vec<usize>,
    data: Vec<f64>,
}

/// The arrays of one set of NumPy records.
pub(crate) struct Arrays {
    /// Where they were read from (for errors).
    file: PathBuf,
    arrays: Vec<Array>,
    /// N.
    pub runs: usize,
    /// T.
    pub steps: usize,
    /// Their own layout.
    pub layout: Layout,
    /// Per run, the step its filter diverged at (0: it did not).
    diverged: Vec<usize>,
}

fn read_array<R: Read>(
    file: &Path,
    name: &str,
    npy: npyz::NpyFile<R>,
) -> Result<(Vec<usize>, Vec<f64>), FileError> {
    let err = |m: String| FileError::new(file, format!("array {name}"), m);
    // npyz's own `len()` wraps on absurd shapes ((2³², 2³²) has "0" elements): count
    // them here, and trust no index into the data before the count is known to be small.
    let len = npy
        .shape()
        .iter()
        .try_fold(1u64, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= MAX_ELEMENTS)
        .ok_or_else(|| {
            err(format!(
                "shape {:?}: above the limit of {MAX_ELEMENTS} elements",
                npy.shape()
            ))
        })? as usize;
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    let order = npy.order();
    let dtype = npy.dtype().descr();
    // The common case, little-endian float64, in one read: element by element, the zip
    // reader's checksum and the buffering cost more than the numbers.
    if dtype == "'<f8'" || (dtype == "'=f8'" && cfg!(target_endian = "little")) {
        // The header's size is a claim: memory grows with the bytes actually there.
        let mut bytes = Vec::with_capacity((len * 8).min(PREALLOCATE));
        npy.into_inner()
            .take(len as u64 * 8)
            .read_to_end(&mut bytes)
            .map_err(|e| err(format!("cannot read: {}", one_line(&e))))?;
        if bytes.len() < len * 8 {
            return Err(err(format!(
                "truncated: {} bytes of data for {len} float64 numbers",
                bytes.len()
            )));
        }
        let data = bytes[..len * 8]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        return Ok((shape.clone(), c_order(&shape, order, data)));
    }
    macro_rules! try_types {
        ($npy:expr, $($t:ty),*) => {{
            let npy = $npy;
            $(
                let npy = match npy.try_data::<$t>() {
                    Ok(reader) => {
                        let mut out = Vec::with_capacity(len.min(PREALLOCATE / 8));
                        for v in reader {
                            out.push(v.map_err(|e| err(format!("cannot read: {}", one_line(&e))))? as f64);
                        }
                        return Ok((shape.clone(), c_order(&shape, order, out)));
                    }
                    Err(npy) => npy,
                };
            )*
            drop(npy);
        }};
    }
    try_types!(npy, f64, f32, i64, i32, i16, i8, u64, u32, u16, u8);
    Err(err(format!(
        "dtype {dtype} is not a real number type (use float64)"
    )))
}

/// An error of the NumPy or zip reader on one line: a header the Python-literal parser
/// refuses comes with a drawing of where (`--> 1:17`, the header, a caret, `= expected
/// value`), of which the position and the expectation are kept.
fn one_line(e: &impl std::fmt::Display) -> String {
    let text = e.to_string();
    let kept: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| {
            let drawing = l.starts_with('|')
                || l.split_once(" |")
                    .is_some_and(|(n, _)| n.parse::<u64>().is_ok());
            !l.is_empty() && !drawing
        })
        .map(|l| l.strip_prefix("= ").unwrap_or(l))
        .collect();
    kept.join(" ")
}

/// `data` in C order, given in `order`.
fn c_order(shape: &[usize], order: npyz::Order, data: Vec<f64>) -> Vec<f64> {
    if order == npyz::Order::C || shape.len() < 2 {
        return data;
    }
    let mut out = vec![0.0; data.len()];
    let mut idx = vec![0usize; shape.len()];
    for v in out.iter_mut() {
        // Fortran offset of the current C-order multi-index.
        let mut off = 0;
        let mut stride = 1;
        for (i, &d) in idx.iter().zip(shape) {
            off += i * stride;
            stride *= d;
        }
        *v = data[off];
        for a in (0..shape.len()).rev() {
            idx[a] += 1;
            if idx[a] < shape[a] {
                break;
            }
            idx[a] = 0;
        }
    }
    out
}

/// A NumPy array as read: its name, shape and data (f64, C order).
pub(crate) type RawArray = (String, Vec<usize>, Vec<f64>);

/// The arrays of an `.npz` archive or of a set of `.npy` files (each named after its file
/// stem), by name, with their shapes and their data as f64 in C order; nothing about what they
/// mean is checked here. `paths` is not empty.
pub(crate) fn read_raw(paths: &[PathBuf]) -> Result<Vec<RawArray>, FileError> {
    let file = paths[0].clone();
    let mut raw: Vec<RawArray> = Vec::new();
    let is_npz = paths.len() == 1
        && file
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("npz"));
    if is_npz {
        let mut archive = npyz::npz::NpzArchive::open(&file).map_err(|e| {
            FileError::new(&file, "", format!("not an .npz archive: {}", one_line(&e)))
        })?;
        let names: Vec<String> = archive.array_names().map(str::to_string).collect();
        for name in names {
            let npy = archive
                .by_name(&name)
                .map_err(|e| {
                    FileError::new(
                        &file,
                        format!("array {name}"),
                        format!("cannot read: {}", one_line(&e)),
                    )
                })?
                .ok_or_else(|| FileError::new(&file, format!("array {name}"), "missing"))?;
            let (shape, data) = read_array(&file, &name, npy)?;
            raw.push((name, shape, data));
        }
    } else {
        for p in paths {
            let name = p
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default()
                .to_string();
            let f = std::fs::File::open(p)
                .map_err(|e| FileError::new(p, "", format!("cannot read: {}", one_line(&e))))?;
            let npy = npyz::NpyFile::new(std::io::BufReader::new(f))
                .map_err(|e| FileError::new(p, "", format!("not a .npy file: {}", one_line(&e))))?;
            let (shape, data) = read_array(p, &name, npy)?;
            if raw.iter().any(|(n, _, _)| *n == name) {
                return Err(FileError::new(p, format!("array {name}"), "given twice"));
            }
            raw.push((name, shape, data));
        }
    }
    Ok(raw)
}

impl Arrays {
    /// Read an `.npz` archive, or a set of `.npy` files.
    pub(crate) fn read(paths: &[PathBuf]) -> Result<Arrays, FileError> {
        Self::validate(paths[0].clone(), read_raw(paths)?)
    }

    fn validate(
        file: PathBuf,
        raw: Vec<(String, Vec<usize>, Vec<f64>)>,
    ) -> Result<Arrays, FileError> {
        let err = |name: &str, m: String| FileError::new(&file, format!("array {name}"), m);
        // N and T from the first array with both axes.
        let mut nt: Option<(usize, usize, String)> = None;
        // Covariances without the runs axis, and their steps.
        let mut shared_steps: Vec<(String, usize)> = Vec::new();
        let mut arrays = Vec::new();
        let mut diverged_raw: Option<(String, Vec<usize>, Vec<f64>)> = None;
        for (name, shape, data) in raw {
            let q = Quantity::parse(&name).ok_or_else(|| {
                err(
                    &name,
                    "unknown name (see docs/external.md for the names)".into(),
                )
            })?;
            match q {
                Quantity::Run | Quantity::Step => {
                    return Err(err(
                        &name,
                        "NumPy records number runs and steps by their axes".into(),
                    ));
                }
                Quantity::Diverged => {
                    diverged_raw = Some((name, shape, data));
                    continue;
                }
                _ => {}
            }
            let scalar_dof =
                matches!(q, Quantity::NeesDof | Quantity::NisDof(_)) && shape.is_empty();
            let shared = matches!(q, Quantity::P | Quantity::S(_)) && shape.len() == 3;
            let shape = if shared {
                [&[1], &shape[..]].concat()
            } else {
                shape
            };
            if shared {
                shared_steps.push((name.clone(), shape[1]));
            } else if !scalar_dof {
                let want = 2 + q.rank();
                if shape.len() != want {
                    return Err(err(
                        &name,
                        format!(
                            "shape {shape:?}: expected {want} axes (runs, steps{})",
                            match q.rank() {
                                0 => "",
                                1 => ", n",
                                _ => ", n, n",
                            }
                        ),
                    ));
                }
                match &nt {
                    None => nt = Some((shape[0], shape[1], name.clone())),
                    Some((n, t, first)) if (shape[0], shape[1]) != (*n, *t) => {
                        return Err(err(
                            &name,
                            format!(
                                "shape {shape:?}: its (runs, steps) differ from {first}'s ({n}, {t})"
                            ),
                        ));
                    }
                    Some(_) => {}
                }
            }
            arrays.push(Array {
                quantity: q,
                shared,
                shape,
                data,
            });
        }
        let (runs, steps, _) = nt.ok_or_else(|| {
            FileError::new(
                &file,
                "",
                "no arrays of records (e, P, nu_<sensor>, …; see docs/external.md)",
            )
        })?;
        for (name, t) in &shared_steps {
            if *t != steps {
                return Err(err(
                    name,
                    format!("{t} steps, but the other arrays have {steps}"),
                ));
            }
        }
        if runs == 0 || steps == 0 {
            return Err(FileError::new(
                &file,
                "",
                format!("{runs} runs of {steps} steps: no records"),
            ));
        }
        if steps > MAX_STEPS {
            return Err(FileError::new(
                &file,
                "",
                format!("{steps} steps per run, above the limit of {MAX_STEPS}"),
            ));
        }
        let mut found = Found::new();
        for a in &arrays {
            let dims = if a.shape.len() >= 2 {
                a.shape[2..].to_vec()
            } else {
                vec![]
            };
            found.push((a.quantity.clone(), dims));
        }
        let layout = infer_layout(&found).map_err(|m| FileError::new(&file, "", m))?;
        let diverged = match diverged_raw {
            None => vec![0; runs],
            Some((name, shape, data)) => {
                if shape != [runs] {
                    return Err(err(
                        &name,
                        format!("shape {shape:?}: expected ({runs},), a step per run"),
                    ));
                }
                data.iter()
                    .enumerate()
                    .map(|(i, &v)| {
                        if v.fract() == 0.0 && v >= 0.0 && v <= steps as f64 {
                            Ok(v as usize)
                        } else {
                            Err(err(
                                &name,
                                format!("run {i}: {v} is not a step in 0..={steps}"),
                            ))
                        }
                    })
                    .collect::<Result<Vec<usize>, FileError>>()?
            }
        };
        Ok(Arrays {
            file,
            arrays,
            runs,
            steps,
            layout,
            diverged,
        })
    }

    /// Stream the records into `sink` (an experiment of `layout`, `steps` steps), run r of
    /// the arrays being run `first_run + r`.
    pub(crate) fn feed(
        &self,
        layout: &Layout,
        steps: usize,
        first_run: usize,
        sink: &mut dyn StepSink,
    ) -> Result<(), FileError> {
        fits(&self.layout, layout).map_err(|m| FileError::new(&self.file, "", m))?;
        if self.steps != steps {
            return Err(FileError::new(
                &self.file,
                "",
                format!("{} steps per run, expected {steps}", self.steps),
            ));
        }
        let keys = Keys::new(layout);
        for r in 0..self.runs {
            for k in 1..=self.steps {
                let at = |m: String| FileError::new(&self.file, format!("run {r}, step {k}"), m);
                let mut row = NpyRow {
                    arrays: self,
                    r,
                    t: k - 1,
                };
                let mut rec = step_record(layout, &keys, first_run + r, k, &mut row).map_err(at)?;
                if self.diverged[r] == k {
                    rec = super::StepRecord::new(first_run + r, k);
                    rec.diverged = Some("marked diverged in the records".into());
                }
                let stop = rec.diverged.is_some();
                sink.push(rec)
                    .map_err(|m| FileError::new(&self.file, "", m))?;
                if stop {
                    break;
                }
            }
        }
        Ok(())
    }
}

struct NpyRow<'a> {
    arrays: &'a Arrays,
    r: usize,
    t: usize,
}

impl Row for NpyRow<'_> {
    fn values(&mut self, q: &Quantity) -> Result<Option<Vec<f64>>, String> {
        let Some(a) = self.arrays.arrays.iter().find(|a| a.quantity == *q) else {
            return Ok(None);
        };
        if a.shape.is_empty() {
            return Ok(Some(a.data.clone()));
        }
        let inner: usize = a.shape[2..].iter().product();
        let r = if a.shared { 0 } else { self.r };
        let at = (r * a.shape[1] + self.t) * inner;
        Ok(Some(a.data[at..at + inner].to_vec()))
    }

    fn diverged(&mut self) -> Result<Option<String>, String> {
        Ok(None)
    }
}
