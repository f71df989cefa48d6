//! Named noise parameters and the map from a parameter vector to the filter's Q and R.
//!
//! Every supported way of writing a covariance is linear in its parameter, so a covariance
//! is `Q(θ) = Σ_i c_i B_i` where each term's coefficient `c_i` is either a named parameter
//! `θ_j` or a fixed number, and `B_i` is a constant positive-semidefinite basis matrix
//! built from the term's kind (a DWNA/CWNA block, a diagonal entry, a full matrix, or
//! continuous-time noise discretized by Van Loan's method). With nonnegative coefficients
//! the result is symmetric PSD by construction.

use nalgebra::DMatrix;
use serde::Serialize;

use crate::input::SettingError;

/// Whether a parameter sets process or measurement noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseKind {
    /// Process noise Q.
    Process,
    /// Measurement noise R.
    Measurement,
}

/// What a parameter drives: process noise of some state components, or measurement noise
/// of some measurement components (indices into the concatenated sensor components). Its
/// advice reads those components' statistics, and the Gauss–Newton search matches them
/// first.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Target {
    /// Process or measurement noise.
    pub kind: NoiseKind,
    /// The state (process) or measurement (measurement noise) components, 0-based.
    pub components: Vec<usize>,
}

impl Target {
    /// Process noise of these state components.
    pub fn process(components: &[usize]) -> Target {
        Target {
            kind: NoiseKind::Process,
            components: components.to_vec(),
        }
    }

    /// Measurement noise of these measurement components.
    pub fn measurement(components: &[usize]) -> Target {
        Target {
            kind: NoiseKind::Measurement,
            components: components.to_vec(),
        }
    }
}

/// One named parameter: a variance or spectral density that sets part of Q or R.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamDef {
    /// Name used in files and reports, e.g. `q_accel_x`.
    pub name: String,
    /// Value the filter uses as configured (the tuner's starting point).
    pub value: f64,
    /// Lower bound for the search (> 0: the search works in log space).
    pub lower: f64,
    /// Upper bound for the search.
    pub upper: f64,
    /// Held at `value` during tuning (e.g. R from a sensor datasheet).
    pub fixed: bool,
    /// Unit of the value, e.g. `(m/s²)²` or `m²/s³`.
    pub unit: String,
    /// What the parameter models, in the designer's words.
    pub about: String,
}

impl ParamDef {
    /// A free parameter `name` with configured value `value`, searched within
    /// `value/1e4 .. value·1e4`, no unit or description.
    pub fn new(name: &str, value: f64) -> ParamDef {
        ParamDef {
            name: name.to_string(),
            value,
            lower: value / 1e4,
            upper: value * 1e4,
            fixed: false,
            unit: String::new(),
            about: String::new(),
        }
    }

    /// Search bounds (0 < lower < upper, with the value inside).
    pub fn bounds(mut self, lower: f64, upper: f64) -> ParamDef {
        self.lower = lower;
        self.upper = upper;
        self
    }

    /// Hold at the configured value when tuning.
    pub fn fixed(mut self) -> ParamDef {
        self.fixed = true;
        self
    }

    /// Unit of the value, e.g. `(m/s²)²`.
    pub fn unit(mut self, unit: &str) -> ParamDef {
        self.unit = unit.to_string();
        self
    }

    /// What it models, one line.
    pub fn about(mut self, about: &str) -> ParamDef {
        self.about = about.to_string();
        self
    }

    /// Check the name (letters, digits, `_`), the value (finite, > 0: the search works in
    /// log space) and the bounds (finite, 0 < lower < upper, value inside). The error's
    /// setting is relative to the parameter: `` (the name), `value`, `lower` or `upper`.
    pub fn validate(&self) -> Result<(), SettingError> {
        let finite = |setting: &str, v: f64| {
            if v.is_finite() {
                Ok(v)
            } else {
                Err(SettingError::new(
                    setting,
                    format!("{v} is not a finite number"),
                ))
            }
        };
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_')
        {
            return Err(SettingError::new(
                "",
                "parameter names use letters, digits and _ only",
            ));
        }
        let value = finite("value", self.value)?;
        if value <= 0.0 {
            return Err(SettingError::new(
                "value",
                format!("{value} must be > 0 (variances are searched in log space)"),
            ));
        }
        let lower = finite("lower", self.lower)?;
        let upper = finite("upper", self.upper)?;
        if lower <= 0.0 {
            return Err(SettingError::new("lower", format!("{lower} must be > 0")));
        }
        if lower >= upper {
            return Err(SettingError::new(
                "lower",
                format!("lower bound {lower} is not below upper bound {upper}"),
            ));
        }
        if value < lower || value > upper {
            return Err(SettingError::new(
                "value",
                format!("{value} is outside [{lower}, {upper}]"),
            ));
        }
        Ok(())
    }
}

/// The ordered set of named parameters of a problem.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ParamSpace {
    /// Parameters in file order.
    pub params: Vec<ParamDef>,
}

impl ParamSpace {
    /// Index of the parameter called `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| p.name == name)
    }

    /// The configured values, in order.
    pub fn values(&self) -> Vec<f64> {
        self.params.iter().map(|p| p.value).collect()
    }

    /// Names in order.
    pub fn names(&self) -> Vec<&str> {
        self.params.iter().map(|p| p.name.as_str()).collect()
    }
}

/// A term's coefficient: a named parameter or a fixed number.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum Coef {
    /// Index into the [`ParamSpace`].
    Param(usize),
    /// A fixed value (truth models, or terms the designer does not want tuned).
    Fixed(f64),
}

/// One term `c · B` of a covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct CovTerm {
    /// The coefficient.
    pub coef: Coef,
    /// Symmetric PSD basis matrix, dim × dim.
    pub basis: DMatrix<f64>,
}

/// A covariance matrix as a sum of parameterized terms.
#[derive(Debug, Clone, PartialEq)]
pub struct CovModel {
    /// Matrix dimension.
    pub dim: usize,
    /// The terms.
    pub terms: Vec<CovTerm>,
}

impl CovModel {
    /// The matrix at parameter values `theta` (indexed as the [`ParamSpace`]).
    pub fn build(&self, theta: &[f64]) -> DMatrix<f64> {
        let mut m = DMatrix::zeros(self.dim, self.dim);
        for t in &self.terms {
            let c = match t.coef {
                Coef::Param(i) => theta[i],
                Coef::Fixed(v) => v,
            };
            m += &t.basis * c;
        }
        m
    }

    /// Whether any term uses parameter `i`.
    pub fn uses(&self, i: usize) -> bool {
        self.terms.iter().any(|t| t.coef == Coef::Param(i))
    }

    /// The components (diagonal entries) that parameter `i`'s terms put variance on.
    pub fn touched(&self, i: usize) -> Vec<usize> {
        let mut out = Vec::new();
        for t in &self.terms {
            if t.coef == Coef::Param(i) {
                for j in 0..self.dim {
                    if t.basis[(j, j)] > 0.0 && !out.contains(&j) {
                        out.push(j);
                    }
                }
            }
        }
        out
    }
}

/// Basis of a discrete white-noise acceleration (DWNA) block for a (position, velocity)
/// pair with sample period `dt` (s); multiplied by the acceleration variance (units²/s⁴) it
/// gives `σ² [[dt⁴/4, dt³/2], [dt³/2, dt²]]` (Bar-Shalom et al. 2001, §6.3.3).
pub fn dwna_block(dt: f64) -> DMatrix<f64> {
    DMatrix::from_row_slice(
        2,
        2,
        &[
            dt.powi(4) / 4.0,
            dt.powi(3) / 2.0,
            dt.powi(3) / 2.0,
            dt.powi(2),
        ],
    )
}

/// Basis of a continuous white-noise acceleration (CWNA) block for a (position, velocity)
/// pair; multiplied by the spectral density q̃ (units²/s³) it gives
/// `q̃ [[dt³/3, dt²/2], [dt²/2, dt]]` (Bar-Shalom et al. 2001, §6.2.2). A tuned q̃ carries
/// across sample rates.
pub fn cwna_block(dt: f64) -> DMatrix<f64> {
    DMatrix::from_row_slice(
        2,
        2,
        &[dt.powi(3) / 3.0, dt.powi(2) / 2.0, dt.powi(2) / 2.0, dt],
    )
}

/// Place a k × k block into an n × n zero matrix at the given state indices.
pub fn embed(n: usize, indices: &[usize], block: &DMatrix<f64>) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(n, n);
    for (a, &i) in indices.iter().enumerate() {
        for (b, &j) in indices.iter().enumerate() {
            m[(i, j)] = block[(a, b)];
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::min_eigenvalue;
    use approx::assert_relative_eq;

    fn model() -> CovModel {
        CovModel {
            dim: 4,
            terms: vec![
                CovTerm {
                    coef: Coef::Param(0),
                    basis: embed(4, &[0, 1], &dwna_block(0.5)),
                },
                CovTerm {
                    coef: Coef::Param(1),
                    basis: embed(4, &[2, 3], &cwna_block(0.5)),
                },
                CovTerm {
                    coef: Coef::Fixed(0.25),
                    basis: embed(4, &[3], &DMatrix::from_element(1, 1, 1.0)),
                },
            ],
        }
    }

    #[test]
    fn build_is_linear_and_places_blocks() {
        let q = model().build(&[2.0, 3.0]);
        assert_relative_eq!(q[(0, 0)], 2.0 * 0.5_f64.powi(4) / 4.0);
        assert_relative_eq!(q[(0, 1)], 2.0 * 0.5_f64.powi(3) / 2.0);
        assert_relative_eq!(q[(2, 3)], 3.0 * 0.25 / 2.0);
        assert_relative_eq!(q[(3, 3)], 3.0 * 0.5 + 0.25);
        assert_relative_eq!(q[(0, 2)], 0.0);
    }

    #[test]
    fn nonnegative_parameters_give_symmetric_psd() {
        // A grid over five decades per parameter stands in for a property test: the sum of
        // PSD bases with nonnegative weights must stay PSD and symmetric.
        let m = model();
        for a in [-3, -1, 0, 1, 2] {
            for b in [-3, -1, 0, 1, 2] {
                let q = m.build(&[10f64.powi(a), 10f64.powi(b)]);
                assert!(crate::linalg::asymmetry(&q).is_none());
                assert!(min_eigenvalue(&q) >= -1e-12 * crate::linalg::max_abs(&q));
            }
        }
    }

    #[test]
    fn uses_reports_parameter_membership() {
        let m = model();
        assert!(m.uses(0) && m.uses(1) && !m.uses(2));
    }
}
