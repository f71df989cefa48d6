//! The checks every problem-file field goes through, with errors naming the field.

use std::path::Path;

use nalgebra::{DMatrix, DVector};

use super::spec::MatrixSpec;
use crate::input::FileError;
use crate::linalg::covariance_defect;

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
        match covariance_defect(m, definite) {
            Some(message) => self.err(field, message),
            None => Ok(()),
        }
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
