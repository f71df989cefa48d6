#![allow(non_snake_case)]

//! Covariance terms (`Q = [...]`, `R = [...]`) and the model's dynamics: a problem file's
//! matrices become the bases of [`CovModel`]s.

use nalgebra::DMatrix;

use super::spec::{MatrixSpec, TermKind, TermSpec};
use super::validate::{VResult, Validator};
use crate::linalg::{expm, van_loan};
use crate::params::{Coef, CovModel, CovTerm, ParamSpace, cwna_block, dwna_block, embed};

/// Largest `‖A dt‖₁` accepted: beyond it e^{A dt} overflows anyway, and the matrix
/// exponential's scaling-and-squaring would take unbounded time.
const MAX_A_DT_NORM: f64 = 1e3;

/// A model's discrete transition F and, when given in continuous time, its A.
pub(super) type Dynamics = (DMatrix<f64>, Option<DMatrix<f64>>);

impl Validator<'_> {
    pub(super) fn dynamics(
        &self,
        section: &str,
        F: &Option<MatrixSpec>,
        A: &Option<MatrixSpec>,
        dt: f64,
        n: Option<usize>,
    ) -> VResult<Option<Dynamics>> {
        match (F, A) {
            (Some(_), Some(_)) => self.err(
                format!("{section}.A"),
                "give either F (discrete) or A (continuous), not both",
            ),
            (Some(f), None) => {
                let m = self.matrix(&format!("{section}.F"), f, n, n)?;
                if m.nrows() != m.ncols() {
                    return self.err(
                        format!("{section}.F"),
                        format!("must be square, is {}×{}", m.nrows(), m.ncols()),
                    );
                }
                Ok(Some((m, None)))
            }
            (None, Some(a)) => {
                let m = self.matrix(&format!("{section}.A"), a, n, n)?;
                if m.nrows() != m.ncols() {
                    return self.err(
                        format!("{section}.A"),
                        format!("must be square, is {}×{}", m.nrows(), m.ncols()),
                    );
                }
                let norm1 = (0..m.ncols())
                    .map(|j| m.column(j).iter().map(|v| v.abs()).sum::<f64>())
                    .fold(0.0, f64::max)
                    * dt;
                if norm1 > MAX_A_DT_NORM {
                    return self.err(
                        format!("{section}.A"),
                        format!("‖A·dt‖₁ = {norm1:.3e} is above {MAX_A_DT_NORM:e}: e^(A dt) overflows; is dt in seconds?"),
                    );
                }
                let f = expm(&(&m * dt));
                if f.iter().any(|v| !v.is_finite()) {
                    return self.err(format!("{section}.A"), "e^(A dt) overflows");
                }
                Ok(Some((f, Some(m))))
            }
            (None, None) => Ok(None),
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn cov_model(
        &self,
        field: &str,
        terms: &[TermSpec],
        dim: usize,
        is_q: bool,
        dt: f64,
        a: Option<&DMatrix<f64>>,
        params: Option<&ParamSpace>,
    ) -> VResult<CovModel> {
        if terms.is_empty() {
            return self.err(field, "needs at least one term");
        }
        let mut out = Vec::with_capacity(terms.len());
        for (t, term) in terms.iter().enumerate() {
            let tf = format!("{field}[{t}]");
            if !is_q
                && matches!(
                    term.kind,
                    TermKind::Dwna | TermKind::Cwna | TermKind::Continuous
                )
            {
                return self.err(
                    format!("{tf}.kind"),
                    format!(
                        "kind '{}' describes process noise; R takes diag or matrix",
                        kind_name(term.kind)
                    ),
                );
            }
            let basis = self.term_basis(&tf, term, dim, dt, a)?;
            if basis.iter().any(|v| !v.is_finite()) {
                return self.err(
                    tf.clone(),
                    format!("kind '{}' overflows with dt = {dt:e}", kind_name(term.kind)),
                );
            }
            let coef = self.term_coef(&tf, term, params)?;
            out.push(CovTerm { coef, basis });
        }
        Ok(CovModel { dim, terms: out })
    }

    /// The basis matrix of term `tf` of its kind, in a state or measurement of `dim`
    /// components.
    fn term_basis(
        &self,
        tf: &str,
        term: &TermSpec,
        dim: usize,
        dt: f64,
        a: Option<&DMatrix<f64>>,
    ) -> VResult<DMatrix<f64>> {
        let unused = |name: &str, present: bool| -> VResult<()> {
            if present {
                self.err(
                    format!("{tf}.{name}"),
                    format!("not used by kind '{}'", kind_name(term.kind)),
                )
            } else {
                Ok(())
            }
        };
        match term.kind {
            TermKind::Dwna | TermKind::Cwna => {
                unused("matrix", term.matrix.is_some())?;
                unused("input", term.input.is_some())?;
                let ix = self.term_indices(tf, term, dim, Some(2))?;
                let block = if term.kind == TermKind::Dwna {
                    dwna_block(dt)
                } else {
                    cwna_block(dt)
                };
                Ok(embed(dim, &ix, &block))
            }
            TermKind::Diag => {
                unused("matrix", term.matrix.is_some())?;
                unused("input", term.input.is_some())?;
                let ix = self.term_indices(tf, term, dim, None)?;
                let mut m = DMatrix::zeros(dim, dim);
                for i in ix {
                    m[(i, i)] = 1.0;
                }
                Ok(m)
            }
            TermKind::Matrix => {
                unused("indices", term.indices.is_some())?;
                unused("input", term.input.is_some())?;
                let Some(ms) = &term.matrix else {
                    return self.err(format!("{tf}.matrix"), "kind 'matrix' needs matrix");
                };
                let m = self.matrix(&format!("{tf}.matrix"), ms, Some(dim), Some(dim))?;
                self.symmetric_psd(&format!("{tf}.matrix"), &m, false)?;
                Ok(m)
            }
            TermKind::Continuous => {
                unused("indices", term.indices.is_some())?;
                unused("matrix", term.matrix.is_some())?;
                let Some(a) = a else {
                    return self.err(
                        format!("{tf}.kind"),
                        "kind 'continuous' needs the model's continuous-time A",
                    );
                };
                let Some(g) = &term.input else {
                    return self.err(
                        format!("{tf}.input"),
                        "kind 'continuous' needs input (the noise input vector g)",
                    );
                };
                let g = self.vector(&format!("{tf}.input"), g, dim)?;
                Ok(van_loan(a, &(&g * g.transpose()), dt))
            }
        }
    }

    /// Term `tf`'s indices into `dim` components: `needed` of them where its kind fixes
    /// the count, distinct and in range.
    fn term_indices(
        &self,
        tf: &str,
        term: &TermSpec,
        dim: usize,
        needed: Option<usize>,
    ) -> VResult<Vec<usize>> {
        let Some(ix) = &term.indices else {
            return self.err(
                format!("{tf}.indices"),
                format!("kind '{}' needs indices", kind_name(term.kind)),
            );
        };
        if let Some(k) = needed
            && ix.len() != k
        {
            return self.err(
                format!("{tf}.indices"),
                format!(
                    "needs exactly {k} indices (position, velocity), got {}",
                    ix.len()
                ),
            );
        }
        if ix.is_empty() {
            return self.err(format!("{tf}.indices"), "needs at least one index");
        }
        let mut v = Vec::with_capacity(ix.len());
        for &i in ix {
            if i < 0 || i as usize >= dim {
                return self.err(
                    format!("{tf}.indices"),
                    format!("index {i} out of range 0..{dim}"),
                );
            }
            if v.contains(&(i as usize)) {
                return self.err(format!("{tf}.indices"), format!("index {i} repeated"));
            }
            v.push(i as usize);
        }
        Ok(v)
    }

    /// Term `tf`'s coefficient: a fixed variance, or a parameter of `params` (none: the
    /// truth, which takes fixed values only).
    fn term_coef(&self, tf: &str, term: &TermSpec, params: Option<&ParamSpace>) -> VResult<Coef> {
        match (&term.param, term.value) {
            (Some(_), Some(_)) => self.err(
                format!("{tf}.value"),
                "give either param or value, not both",
            ),
            (None, None) => self.err(
                tf.to_string(),
                "needs param (a named parameter) or value (a fixed number)",
            ),
            (None, Some(v)) => {
                self.finite(&format!("{tf}.value"), v)?;
                if v < 0.0 {
                    return self.err(
                        format!("{tf}.value"),
                        format!("{v} is negative; a variance must be ≥ 0"),
                    );
                }
                Ok(Coef::Fixed(v))
            }
            (Some(name), None) => {
                let Some(ps) = params else {
                    return self.err(
                        format!("{tf}.param"),
                        "the truth takes fixed values: use value",
                    );
                };
                match ps.index(name) {
                    Some(i) => Ok(Coef::Param(i)),
                    None => {
                        let known = ps.names().join(", ");
                        self.err(
                            format!("{tf}.param"),
                            format!("unknown parameter '{name}' (defined in [params]: {known})"),
                        )
                    }
                }
            }
        }
    }
}

fn kind_name(k: TermKind) -> &'static str {
    match k {
        TermKind::Dwna => "dwna",
        TermKind::Cwna => "cwna",
        TermKind::Diag => "diag",
        TermKind::Matrix => "matrix",
        TermKind::Continuous => "continuous",
    }
}
