//! What every reader shares: the layout a file's quantities imply and one step's record
//! from whatever holds its numbers (a CSV row, NumPy arrays, a JSON object). The readers
//! call it; it calls no reader.

use super::error::{LayoutError, RecordError};
use super::names::Quantity;
use super::{
    Layout, MAX_COMPONENTS, SensorLayout, SensorRecord, StateLayout, StateRecord, StepRecord,
};

/// The quantities a file holds, each with its dimensions beyond (run, step): `[]` for a
/// scalar, `[n]` for a vector, `[n, n]` for a matrix.
pub(super) type Found = Vec<(Quantity, Vec<usize>)>;

/// The layout implied by the quantities a file holds; an error names what is missing,
/// contradictory or of mismatched size.
pub(super) fn infer_layout(found: &Found) -> Result<Layout, LayoutError> {
    // A quantity without entries (JSON `[]`, a NumPy axis of length 0) measures nothing,
    // and lets a NumPy file claim any number of runs without holding a byte of them.
    if let Some((q, d)) = found.iter().find(|(_, d)| d.contains(&0)) {
        return Err(LayoutError::Empty {
            quantity: q.name(),
            shape: d.clone(),
        });
    }
    // The sums, the per-component verdicts and the report grow with the components: a
    // list of millions (one JSON line can hold four million) took gigabytes and minutes.
    if let Some((q, d)) = found
        .iter()
        .find(|(_, d)| d.iter().any(|&n| n > MAX_COMPONENTS))
    {
        return Err(LayoutError::TooManyComponents {
            quantity: q.name(),
            shape: d.clone(),
        });
    }
    let held = Held(found);
    let state = held.state()?;
    let mut sensors: Vec<SensorLayout> = Vec::new();
    for (q, _) in found {
        let Some(name) = q.sensor() else { continue };
        if sensors.iter().any(|s| s.name == name) {
            continue;
        }
        sensors.push(held.sensor(name)?);
    }
    if state.is_none() && sensors.is_empty() {
        return Err(LayoutError::Nothing);
    }
    Ok(Layout { state, sensors })
}

/// The quantities a file holds, asked what they imply.
struct Held<'a>(&'a Found);

impl Held<'_> {
    fn dims(&self, q: &Quantity) -> Option<Vec<usize>> {
        self.0.iter().find(|(f, _)| f == q).map(|(_, d)| d.clone())
    }

    fn has(&self, q: &Quantity) -> bool {
        self.dims(q).is_some()
    }

    fn vec_dim(&self, q: &Quantity) -> Option<usize> {
        self.dims(q).and_then(|d| d.first().copied())
    }

    /// The side of covariance `q` (called `name` in messages), if the file has it.
    fn square(&self, q: &Quantity, name: &str) -> Result<Option<usize>, LayoutError> {
        match self.dims(q) {
            Some(d) if d.len() == 2 && d[0] == d[1] => Ok(Some(d[0])),
            Some(d) => Err(LayoutError::NotSquare {
                quantity: name.to_string(),
                shape: d,
            }),
            None => Ok(None),
        }
    }

    /// The state side: raw (e and P, or x, xhat and P), normalized (nees), or none.
    fn state(&self) -> Result<Option<StateLayout>, LayoutError> {
        let without = |given: &str, missing: &str| LayoutError::Without {
            given: given.into(),
            missing: missing.into(),
        };
        let raw_state =
            self.has(&Quantity::E) || self.has(&Quantity::X) || self.has(&Quantity::Xhat);
        if raw_state || self.has(&Quantity::P) {
            if self.has(&Quantity::Nees) {
                return Err(LayoutError::StateBothWays);
            }
            let n = match (
                self.vec_dim(&Quantity::E),
                self.vec_dim(&Quantity::X),
                self.vec_dim(&Quantity::Xhat),
            ) {
                (Some(n), None, None) => n,
                (None, Some(a), Some(b)) if a == b => a,
                (None, Some(x), Some(xhat)) => return Err(LayoutError::StateSizes { x, xhat }),
                (None, _, _) => return Err(without("P", "e (or x and xhat)")),
                _ => return Err(LayoutError::ErrorBothWays),
            };
            match self.square(&Quantity::P, "P")? {
                Some(p) if p == n => {}
                Some(side) => {
                    return Err(LayoutError::CovarianceSize {
                        matrix: "P".into(),
                        side,
                        vector: "e".into(),
                        len: n,
                    });
                }
                None => return Err(without("e", "P")),
            }
            Ok(Some(StateLayout {
                dim: n,
                components: true,
            }))
        } else if self.has(&Quantity::Nees) {
            let n = self.vec_dim(&Quantity::E2p);
            if n.is_none() && !self.has(&Quantity::NeesDof) {
                return Err(LayoutError::UnknownDof {
                    given: "nees".into(),
                    missing: "nees_dof or e2p".into(),
                });
            }
            Ok(Some(StateLayout {
                dim: n.unwrap_or(0),
                components: n.is_some(),
            }))
        } else if self.has(&Quantity::E2p) || self.has(&Quantity::NeesDof) {
            Err(without("e2p or nees_dof", "nees"))
        } else {
            Ok(None)
        }
    }

    /// Sensor `name`: raw (its nu and S), or normalized (its nis, with nis_dof or u).
    fn sensor(&self, name: &str) -> Result<SensorLayout, LayoutError> {
        let label = |base: &str| {
            if name.is_empty() {
                base.to_string()
            } else {
                format!("{base}_{name}")
            }
        };
        let without = |given: &str, missing: &str| LayoutError::Without {
            given: label(given),
            missing: missing.into(),
        };
        let nu = self.vec_dim(&Quantity::Nu(name.into()));
        let s = self.square(&Quantity::S(name.into()), &label("S"))?;
        let nis = self.has(&Quantity::Nis(name.into()));
        let u = self.vec_dim(&Quantity::U(name.into()));
        let nis_dof = self.has(&Quantity::NisDof(name.into()));
        match (nu, s, nis) {
            (Some(_), _, true) | (None, Some(_), true) => Err(LayoutError::SensorBothWays {
                nu: label("nu"),
                s: label("S"),
                nis: label("nis"),
            }),
            (Some(m), Some(ms), false) if m == ms => Ok(SensorLayout {
                name: name.into(),
                dim: m,
                components: true,
            }),
            (Some(len), Some(side), false) => Err(LayoutError::CovarianceSize {
                matrix: label("S"),
                side,
                vector: label("nu"),
                len,
            }),
            (Some(_), None, false) => Err(without("nu", &label("S"))),
            (None, Some(_), false) => Err(without("S", &label("nu"))),
            (None, None, true) => {
                if u.is_none() && !nis_dof {
                    return Err(LayoutError::UnknownDof {
                        given: label("nis"),
                        missing: format!("{} or {}", label("nis_dof"), label("u")),
                    });
                }
                Ok(SensorLayout {
                    name: name.into(),
                    dim: u.unwrap_or(0),
                    components: u.is_some(),
                })
            }
            (None, None, false) => Err(LayoutError::Without {
                given: format!("{} or {}", label("u"), label("nis_dof")),
                missing: label("nis"),
            }),
        }
    }
}

/// A cell or key of a file as an error message quotes it: a quoted CSV cell may hold
/// newlines, and the message must stay on one line; a long one is cut.
pub(super) fn shown(text: &str) -> String {
    shown_up_to(text, 60)
}

/// `text` with control characters escaped, cut after `longest` characters (marked `…`):
/// how an error message quotes what a file or a worker wrote, on one line.
pub fn shown_up_to(text: &str, longest: usize) -> String {
    let mut out: String = text
        .chars()
        .take(longest)
        .flat_map(|c| {
            let esc: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            esc
        })
        .collect();
    if text.chars().nth(longest).is_some() {
        out.push('…');
    }
    out
}

/// Where one step's numbers come from.
pub(super) trait Row {
    /// The numbers of quantity `q` (row-major for a matrix; NaN where a cell is empty), or
    /// `None` where the source has no such quantity at this step.
    fn values(&mut self, q: &Quantity) -> Result<Option<Vec<f64>>, RecordError>;
    /// Why the run diverged at this step, if it is marked so.
    fn diverged(&mut self) -> Result<Option<String>, RecordError>;
}

/// The quantities of each sensor of a layout, named once rather than at every step.
pub(super) struct Keys {
    /// Per sensor: ν, S, NIS, its degrees of freedom, u.
    sensors: Vec<[Quantity; 5]>,
}

impl Keys {
    pub(super) fn new(layout: &Layout) -> Keys {
        Keys {
            sensors: layout
                .sensors
                .iter()
                .map(|s| {
                    let n = || s.name.clone();
                    [
                        Quantity::Nu(n()),
                        Quantity::S(n()),
                        Quantity::Nis(n()),
                        Quantity::NisDof(n()),
                        Quantity::U(n()),
                    ]
                })
                .collect(),
        }
    }
}

/// The record of run `run` at step `step` of `layout` (whose [`Keys`] are `keys`) from
/// `row`.
pub(super) fn step_record(
    layout: &Layout,
    keys: &Keys,
    run: usize,
    step: usize,
    row: &mut impl Row,
) -> Result<StepRecord, RecordError> {
    let mut r = StepRecord::new(run, step);
    if let Some(reason) = row.diverged()? {
        r.diverged = Some(reason);
        return Ok(r);
    }
    let scalar = |v: Option<Vec<f64>>| v.and_then(|v| v.first().copied());
    if let Some(state) = &layout.state {
        r.state = if let Some(nees) = scalar(row.values(&Quantity::Nees)?) {
            let dof = scalar(row.values(&Quantity::NeesDof)?).unwrap_or(state.dim as f64);
            Some(StateRecord::Normalized {
                nees,
                dof,
                e2p: row.values(&Quantity::E2p)?,
            })
        } else {
            let e = match row.values(&Quantity::E)? {
                Some(e) => Some(e),
                None => match (row.values(&Quantity::X)?, row.values(&Quantity::Xhat)?) {
                    (Some(x), Some(xh)) if x.len() == xh.len() => {
                        Some(x.iter().zip(&xh).map(|(a, b)| a - b).collect())
                    }
                    (Some(x), Some(xh)) => {
                        return Err(LayoutError::StateSizes {
                            x: x.len(),
                            xhat: xh.len(),
                        }
                        .into());
                    }
                    _ => None,
                },
            };
            match (e, row.values(&Quantity::P)?) {
                (Some(e), Some(p)) => Some(StateRecord::Raw { e, p }),
                _ => None,
            }
        };
    }
    for (idx, (s, [q_nu, q_s, q_nis, q_dof, q_u])) in
        layout.sensors.iter().zip(&keys.sensors).enumerate()
    {
        let measured =
            |v: &Option<Vec<f64>>| v.as_ref().is_some_and(|v| v.iter().any(|x| !x.is_nan()));
        let nu = row.values(q_nu)?;
        if measured(&nu) {
            let sm = row.values(q_s)?.unwrap_or_default();
            r.sensors.push((
                idx,
                SensorRecord::Raw {
                    nu: nu.unwrap_or_default(),
                    s: sm,
                },
            ));
            continue;
        }
        let nis = row.values(q_nis)?;
        if measured(&nis) {
            let dof = scalar(row.values(q_dof)?).unwrap_or(s.dim as f64);
            r.sensors.push((
                idx,
                SensorRecord::Normalized {
                    nis: scalar(nis).unwrap_or(f64::NAN),
                    dof,
                    u: row.values(q_u)?,
                },
            ));
        }
    }
    Ok(r)
}

/// Check that a file's own layout fits the experiment's: the same state dimension and
/// per-component data, and only sensors the experiment has, of their dimensions.
pub(super) fn fits(own: &Layout, expected: &Layout) -> Result<(), LayoutError> {
    match (own.state, expected.state) {
        (None, None) => {}
        (Some(_), None) => return Err(LayoutError::NoGroundTruth),
        (None, Some(_)) => return Err(LayoutError::NoState),
        (Some(a), Some(b)) => {
            if a.components != b.components || (a.components && a.dim != b.dim) {
                return Err(LayoutError::StateDimension {
                    dim: a.dim,
                    components: a.components,
                    expected: b.dim,
                    expected_components: b.components,
                });
            }
        }
    }
    for s in &own.sensors {
        let Some(e) = expected.sensors.iter().find(|e| e.name == s.name) else {
            return Err(LayoutError::UnknownSensor {
                sensor: s.name.clone(),
                known: expected.sensors.iter().map(|e| e.name.clone()).collect(),
            });
        };
        if s.components != e.components || (s.components && s.dim != e.dim) {
            return Err(LayoutError::SensorDimension {
                sensor: s.name.clone(),
                dim: s.dim,
                components: s.components,
                expected: e.dim,
            });
        }
    }
    Ok(())
}
