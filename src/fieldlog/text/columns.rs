//! The CSV field log's header ([`CsvColumns`]) and its rows read through it: which columns
//! hold the time, the sensor, ν and S, and the covariance assembled from whichever of its
//! triangles the row fills. Apart from the reader so that the column rules read together.

use std::collections::HashMap;

use super::check::{check_sensor, symmetric};
use crate::fieldlog::ingest::{MAX_DIM, Row};
use crate::records::{SensorRecord, shown_up_to};

/// Where the cells of a CSV log sit.
#[derive(Debug, Clone)]
pub(in crate::fieldlog) struct CsvColumns {
    time: usize,
    sensor: usize,
    nu: Vec<usize>,
    s: HashMap<(usize, usize), usize>,
    nis: Option<usize>,
    dof: Option<usize>,
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
pub(in crate::fieldlog) enum HeaderError {
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
    pub(in crate::fieldlog) fn new(header: &csv::StringRecord) -> Result<CsvColumns, HeaderError> {
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
    pub(in crate::fieldlog) fn row(
        &self,
        rec: &csv::StringRecord,
    ) -> Result<Row, (String, String)> {
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
