//! Tuned configs read back ([`TunedConfig`]): the values `autotune check --config` applies
//! on top of a problem file, checked against the problem's parameters (and the Q and R they
//! give). `crate::report::tuned` writes them.

use std::path::Path;

use indexmap::IndexMap;
use serde::{Deserialize, Serialize};

use crate::experiment::Experiment;
use crate::input::{FileError, parse_toml};
use crate::params::ParamSpace;
use crate::userfile::read_text;

/// A tuned config as stored on disk.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TunedConfig {
    /// Name of the problem it was tuned for.
    pub problem: String,
    /// Process noise covariance the parameters give, rows (informational).
    #[serde(default, rename = "Q", skip_serializing_if = "Option::is_none")]
    pub q: Option<Vec<Vec<f64>>>,
    /// Measurement noise covariance the parameters give, rows (informational).
    #[serde(default, rename = "R", skip_serializing_if = "Option::is_none")]
    pub r: Option<Vec<Vec<f64>>>,
    /// Parameter values by name: what `check --config` applies.
    pub params: IndexMap<String, f64>,
    /// Search bounds the tuning run widened, by parameter name: `[lower, upper]` in the
    /// parameter's units. Written only when a bound was widened, because the tuned value
    /// may then lie outside the problem file's bounds: these are the bounds it needs (copy
    /// them into the problem file to tune from it again). When given, each must name a
    /// parameter, satisfy 0 < lower < upper, and hold that parameter's value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bounds: Option<IndexMap<String, [f64; 2]>>,
    /// How the values were obtained (not read back).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub provenance: Option<toml::Table>,
}

impl TunedConfig {
    /// Read a tuned config for `experiment` and map its values onto the experiment's
    /// parameters: every parameter must be given, and nothing else; a `Q` or `R` the config
    /// carries must be what those values give (within 1e-9 of the matrix's largest entry),
    /// so that a config edited by hand, or tuned for another version of the problem, is
    /// not read as something it is not.
    pub fn load_values(path: &Path, experiment: &dyn Experiment) -> Result<Vec<f64>, FileError> {
        let text = read_text(path)?;
        let cfg: TunedConfig = parse_toml(&text, path)?;
        let values = cfg.values(path, &experiment.info().name, experiment.params())?;
        if cfg.q.is_some() || cfg.r.is_some() {
            let cov = experiment.covariances(&values);
            for (field, given, expected) in [
                ("Q", &cfg.q, cov.as_ref().map(|c| &c.Q)),
                ("R", &cfg.r, cov.as_ref().map(|c| &c.R)),
            ] {
                if let (Some(given), Some(expected)) = (given, expected) {
                    same_matrix(given, expected)
                        .map_err(|m| FileError::new(path, field, m.to_string()))?;
                }
            }
        }
        Ok(values)
    }

    /// The parameter values in `space`'s order, checked against it.
    fn values(
        &self,
        path: &Path,
        problem_name: &str,
        space: &ParamSpace,
    ) -> Result<Vec<f64>, FileError> {
        let err = |field: String, message: String| FileError::new(path, field, message);
        if self.problem != problem_name {
            return Err(err(
                "problem".into(),
                // Escaped: the name is whatever the file says, newlines included, and the
                // error must stay on one line.
                format!(
                    "this config was tuned for '{}', not '{problem_name}'",
                    self.problem.escape_debug()
                ),
            ));
        }
        let mut values = space.values();
        for (name, &v) in &self.params {
            let Some(i) = space.index(name) else {
                return Err(err(
                    format!("params.{name}"),
                    format!(
                        "the problem has no parameter '{name}' (it has: {})",
                        space.names().join(", ")
                    ),
                ));
            };
            if !(v.is_finite() && v > 0.0) {
                return Err(err(
                    format!("params.{name}"),
                    format!("{v} must be a finite number > 0"),
                ));
            }
            values[i] = v;
        }
        for p in &space.params {
            if !self.params.contains_key(&p.name) {
                return Err(err(format!("params.{}", p.name), "missing".into()));
            }
        }
        for (name, &[lower, upper]) in self.bounds.iter().flatten() {
            let field = format!("bounds.{name}");
            let Some(i) = space.index(name) else {
                return Err(err(
                    field,
                    format!(
                        "the problem has no parameter '{name}' (it has: {})",
                        space.names().join(", ")
                    ),
                ));
            };
            if !(lower.is_finite() && upper.is_finite() && 0.0 < lower && lower < upper) {
                return Err(err(
                    field,
                    format!("[{lower}, {upper}] must satisfy 0 < lower < upper"),
                ));
            }
            if !(lower..=upper).contains(&values[i]) {
                return Err(err(
                    field,
                    format!(
                        "[{lower}, {upper}] does not hold params.{name} = {}",
                        values[i]
                    ),
                ));
            }
        }
        Ok(values)
    }
}

/// How a config's stored matrix differs from what its parameters give.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum MatrixMismatch {
    /// Another shape than the parameters' matrix.
    #[error(
        "is not {rows}×{cols}, the shape this problem's parameters give (remove Q and R, or tune again)"
    )]
    Shape {
        /// The parameters' matrix's rows.
        rows: usize,
        /// Its columns.
        cols: usize,
    },
    /// An entry off by more than the tolerance.
    #[error(
        "[{row}][{col}] = {given:e}, but the parameters give {expected:e} (remove Q and R, or tune again)"
    )]
    Entry {
        /// Row index.
        row: usize,
        /// Column index.
        col: usize,
        /// The stored value.
        given: f64,
        /// The parameters' value.
        expected: f64,
    },
}

/// Whether the rows `given` hold `expected`, to 1e-9 of its largest entry; the error says
/// where they differ.
fn same_matrix(
    given: &[Vec<f64>],
    expected: &nalgebra::DMatrix<f64>,
) -> Result<(), MatrixMismatch> {
    let (rows, cols) = expected.shape();
    if given.len() != rows || given.iter().any(|r| r.len() != cols) {
        return Err(MatrixMismatch::Shape { rows, cols });
    }
    let tol = 1e-9 * expected.amax().max(f64::MIN_POSITIVE);
    for (i, row) in given.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            let e = expected[(i, j)];
            if (v - e).abs() > tol {
                return Err(MatrixMismatch::Entry {
                    row: i,
                    col: j,
                    given: v,
                    expected: e,
                });
            }
        }
    }
    Ok(())
}
