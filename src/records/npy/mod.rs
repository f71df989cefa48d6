//! NumPy records: an `.npz` archive (`np.savez`) or `.npy` files, one array per quantity,
//! each named after it (`e`, `P`, `nu_radar`), with leading axes (N runs, T steps).

use std::path::{Path, PathBuf};

mod array;

pub(crate) use array::{RawArray, read_raw};

use super::error::RecordError;
use super::names::Quantity;
use super::rows::{Found, Keys, Row, fits, infer_layout, step_record};
use super::{Layout, MAX_STEPS, StepSink};
use crate::input::FileError;

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

/// The arrays of a file by quantity, with their axes checked: (runs, steps) first and the
/// same in each, or a covariance shared by every run.
struct Shaped {
    arrays: Vec<Array>,
    /// N and T, from the first array with both axes (and its name).
    nt: Option<(usize, usize, String)>,
    /// Covariances without the runs axis, and their steps.
    shared_steps: Vec<(String, usize)>,
    /// The `diverged` array, as read.
    diverged: Option<RawArray>,
}

impl Shaped {
    fn of(file: &Path, raw: Vec<RawArray>) -> Result<Shaped, FileError> {
        let err = |name: &str, m: String| FileError::new(file, format!("array {name}"), m);
        let mut out = Shaped {
            arrays: Vec::new(),
            nt: None,
            shared_steps: Vec::new(),
            diverged: None,
        };
        for (name, shape, data) in raw {
            let q = Quantity::parse(&name).ok_or_else(|| {
                err(
                    &name,
                    "unknown name (see docs/src/records.md for the names)".into(),
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
                    out.diverged = Some((name, shape, data));
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
                out.shared_steps.push((name.clone(), shape[1]));
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
                match &out.nt {
                    None => out.nt = Some((shape[0], shape[1], name.clone())),
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
            out.arrays.push(Array {
                quantity: q,
                shared,
                shape,
                data,
            });
        }
        Ok(out)
    }
}

/// Arrays given in memory (`raw`, called `file` in errors) read as records of `layout`
/// into `sink`, run r of the arrays being run `first_run + r`: as from an `.npz` file.
pub(crate) fn read_numpy_records<E: std::error::Error>(
    file: &Path,
    raw: Vec<RawArray>,
    layout: &Layout,
    steps: usize,
    first_run: usize,
    sink: &mut dyn StepSink<Error = E>,
) -> Result<(), FileError> {
    Arrays::validate(file.to_path_buf(), raw)?.feed(layout, steps, first_run, sink)
}

impl Arrays {
    /// Read an `.npz` archive, or a set of `.npy` files.
    pub(crate) fn read(paths: &[PathBuf]) -> Result<Arrays, FileError> {
        Self::validate(paths[0].clone(), read_raw(paths)?)
    }

    /// The arrays `raw` of `file` as records: each named after a quantity, all of the same
    /// runs and steps, of a layout, with the step each run diverged at.
    fn validate(file: PathBuf, raw: Vec<RawArray>) -> Result<Arrays, FileError> {
        let err = |name: &str, m: String| FileError::new(&file, format!("array {name}"), m);
        let shaped = Shaped::of(&file, raw)?;
        let (runs, steps, _) = shaped.nt.ok_or_else(|| {
            FileError::new(
                &file,
                "",
                "no arrays of records (e, P, nu_<sensor>, …; see docs/src/records.md)",
            )
        })?;
        for (name, t) in &shaped.shared_steps {
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
        let arrays = shaped.arrays;
        let mut found = Found::new();
        for a in &arrays {
            let dims = if a.shape.len() >= 2 {
                a.shape[2..].to_vec()
            } else {
                vec![]
            };
            found.push((a.quantity.clone(), dims));
        }
        let layout = infer_layout(&found).map_err(|e| FileError::new(&file, "", e.to_string()))?;
        let diverged = match shaped.diverged {
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
    pub(crate) fn feed<E: std::error::Error>(
        &self,
        layout: &Layout,
        steps: usize,
        first_run: usize,
        sink: &mut dyn StepSink<Error = E>,
    ) -> Result<(), FileError> {
        fits(&self.layout, layout).map_err(|e| FileError::new(&self.file, "", e.to_string()))?;
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
                let at = |e: RecordError| {
                    FileError::new(&self.file, format!("run {r}, step {k}"), e.to_string())
                };
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
                    .map_err(|e| FileError::new(&self.file, "", e.to_string()))?;
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
    fn values(&mut self, q: &Quantity) -> Result<Option<Vec<f64>>, RecordError> {
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

    fn diverged(&mut self) -> Result<Option<String>, RecordError> {
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::records::{StateLayout, StateRecord, StepRecord};

    /// Collects the records it is fed.
    struct Collect(Vec<StepRecord>);

    impl StepSink for Collect {
        type Error = std::convert::Infallible;
        fn push(&mut self, r: StepRecord) -> Result<(), Self::Error> {
            self.0.push(r);
            Ok(())
        }
    }

    #[test]
    fn arrays_feed_each_run_and_step_as_a_record_numbered_from_the_first_run() {
        // e of 2 runs × 3 steps × 1 state, P shared by every run (3 steps × 1 × 1).
        let e: Vec<f64> = (0..6).map(f64::from).collect();
        let raw = vec![
            ("e".to_string(), vec![2, 3, 1], e),
            ("P".to_string(), vec![3, 1, 1], vec![4.0; 3]),
        ];
        let layout = Layout {
            state: Some(StateLayout {
                dim: 1,
                components: true,
            }),
            sensors: vec![],
        };
        let mut sink = Collect(Vec::new());
        read_numpy_records(Path::new("r.npz"), raw.clone(), &layout, 3, 10, &mut sink).unwrap();
        let got: Vec<(usize, usize, Vec<f64>)> = sink
            .0
            .iter()
            .map(|r| match &r.state {
                Some(StateRecord::Raw { e, p }) => {
                    assert_eq!(p, &[4.0]);
                    (r.run, r.step, e.clone())
                }
                other => panic!("{other:?}"),
            })
            .collect();
        let want: Vec<(usize, usize, Vec<f64>)> = (0..6)
            .map(|i| (10 + i / 3, i % 3 + 1, vec![i as f64]))
            .collect();
        assert_eq!(got, want);
        // Another step count than the experiment's is refused, naming the file.
        let mut sink = Collect(Vec::new());
        let err = read_numpy_records(Path::new("r.npz"), raw, &layout, 4, 0, &mut sink);
        assert!(
            err.unwrap_err()
                .to_string()
                .contains("3 steps per run, expected 4")
        );
        assert!(sink.0.is_empty());
    }
}
