//! The checks every problem-file field goes through, with errors naming the field.

use std::path::Path;

use nalgebra::{DMatrix, DVector};

use super::spec::MatrixSpec;
use crate::input::FileError;
use crate::linalg::{asymmetry, min_eigenvalue, psd_factor};

/// Validation context: the file errors name.
pub(super) struct Validator<'a> {
    pub(super) file: &'a Path,
}

/// A validation result.
pub(super) type VResult<T> = Result<T, FileError>;

impl Validator<'_> {
    pub(super) fn err<T>(
        &self,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> VResult<T> {
        Err(FileError::new(self.file, field, message))
    }

    pub(super) fn finite(&self, field: &str, v: f64) -> VResult<f64> {
        if v.is_finite() {
            Ok(v)
        } else {
            self.err(field, format!("{v} is not a finite number"))
        }
    }

    pub(super) fn matrix(
        &self,
        field: &str,
        m: &MatrixSpec,
        rows: Option<usize>,
        cols: Option<usize>,
    ) -> VResult<DMatrix<f64>> {
        if m.is_empty() {
            return self.err(field, "matrix has no rows");
        }
        if let Some(r) = rows
            && m.len() != r
        {
            return self.err(field, format!("has {} rows, expected {r}", m.len()));
        }
        let c = cols.unwrap_or(m[0].len());
        if c == 0 {
            return self.err(field, "matrix has no columns");
        }
        for (i, row) in m.iter().enumerate() {
            if row.len() != c {
                return self.err(
                    format!("{field}[{i}]"),
                    format!("row has {} entries, expected {c}", row.len()),
                );
            }
            for (j, &v) in row.iter().enumerate() {
                self.finite(&format!("{field}[{i}][{j}]"), v)?;
            }
        }
        Ok(DMatrix::from_fn(m.len(), c, |i, j| m[i][j]))
    }

    pub(super) fn vector(&self, field: &str, v: &[f64], len: usize) -> VResult<DVector<f64>> {
        if v.len() != len {
            return self.err(field, format!("has {} entries, expected {len}", v.len()));
        }
        for (i, &x) in v.iter().enumerate() {
            self.finite(&format!("{field}[{i}]"), x)?;
        }
        Ok(DVector::from_column_slice(v))
    }

    pub(super) fn symmetric_psd(
        &self,
        field: &str,
        m: &DMatrix<f64>,
        definite: bool,
    ) -> VResult<()> {
        if let Some((i, j)) = asymmetry(m) {
            return self.err(
                field,
                format!(
                    "not symmetric: entry [{i}][{j}] = {} but [{j}][{i}] = {}",
                    m[(i, j)],
                    m[(j, i)]
                ),
            );
        }
        if let Some(k) = m.iter().position(|v| !v.is_finite()) {
            let (i, j) = (k % m.nrows(), k / m.nrows());
            return self.err(
                field,
                format!("entry [{i}][{j}] is {} (overflow)", m[(i, j)]),
            );
        }
        // Judge the matrix scaled to unit size, so that huge entries cannot overflow the
        // eigenvalue computation.
        let scale = crate::linalg::max_abs(m).max(f64::MIN_POSITIVE);
        let unit = m / scale;
        let lmin = min_eigenvalue(&unit) * scale;
        if psd_factor(&unit).is_err() {
            return self.err(
                field,
                format!("not positive semidefinite (smallest eigenvalue {lmin:.3e})"),
            );
        }
        if definite && !crate::linalg::is_positive_definite(m) {
            // A positive smallest eigenvalue that is still refused is one too small next to
            // the largest to invert reliably: say so, rather than "not positive definite".
            let message = if lmin > 0.0 {
                let lmax = unit.symmetric_eigenvalues().max() * scale;
                format!(
                    "numerically singular: its smallest eigenvalue {lmin:.3e} is positive, but its condition number {:.3e} is too large to invert reliably",
                    lmax / lmin
                )
            } else {
                format!("not positive definite (smallest eigenvalue {lmin:.3e})")
            };
            return self.err(field, message);
        }
        Ok(())
    }

    pub(super) fn names(
        &self,
        field: &str,
        given: &Option<Vec<String>>,
        n: usize,
        prefix: &str,
    ) -> VResult<Vec<String>> {
        match given {
            Some(v) if v.len() != n => {
                self.err(field, format!("has {} names, expected {n}", v.len()))
            }
            Some(v) => Ok(v.clone()),
            None => Ok((0..n).map(|i| format!("{prefix}{i}")).collect()),
        }
    }
}
