//! Problem files: the TOML schema, validation with errors that name the file and field,
//! and construction of the truth model, the filter and the parameter space.

#![allow(non_snake_case)]

pub mod spec;

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::{DMatrix, DVector};
use sha2::{Digest, Sha256};

use crate::filter::KalmanFilter;
use crate::linalg::{asymmetry, expm, min_eigenvalue, psd_factor, van_loan};
use crate::model::LinearGaussianModel;
use crate::model::catalog::{self, CatalogEntry, CatalogModel, ModelContext, NoiseKind};
use crate::montecarlo::Settings;
use crate::params::{Coef, CovModel, CovTerm, ParamDef, ParamSpace, cwna_block, dwna_block, embed};
pub use spec::ProblemSpec;
use spec::{MatrixSpec, TermKind, TermSpec};

/// Largest number of steps per run: per-step sums and the linear engine's per-step gains
/// take memory proportional to T (about 0.5 kB per step for four states).
pub const MAX_STEPS: usize = 1_000_000;

/// Largest `‖A dt‖₁` accepted: beyond it e^{A dt} overflows anyway, and the matrix
/// exponential's scaling-and-squaring would take unbounded time.
const MAX_A_DT_NORM: f64 = 1e3;

/// A bad problem file (or bad option value): which file, which field, what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct ProblemError {
    /// The file.
    pub file: PathBuf,
    /// Dotted path of the field, e.g. `truth.Q[1].indices` (empty if the whole file).
    pub field: String,
    /// Line in the file, where known.
    pub line: Option<usize>,
    /// What is wrong, on one line.
    pub message: String,
}

impl fmt::Display for ProblemError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if !self.field.is_empty() {
            write!(f, ": {}", self.field)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for ProblemError {}

/// Monte Carlo and test settings from `[montecarlo]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct McConfig {
    /// Runs N.
    pub runs: usize,
    /// Steps T.
    pub steps: usize,
    /// Base seed.
    pub seed: u64,
    /// Significance level α.
    pub alpha: f64,
    /// Largest autocorrelation lag.
    pub lags: usize,
}

impl McConfig {
    /// The engine's settings.
    pub fn engine(&self) -> Settings {
        Settings {
            runs: self.runs,
            steps: self.steps,
            seed: self.seed,
            lags: self.lags,
        }
    }
}

/// The filter's model with Q and R as functions of the parameters.
#[derive(Debug, Clone)]
pub struct FilterModel {
    /// State transition, n × n.
    pub F: DMatrix<f64>,
    /// Measurement matrix, m × n.
    pub H: DMatrix<f64>,
    /// Initial estimate.
    pub x0: DVector<f64>,
    /// Initial covariance (positive definite).
    pub P0: DMatrix<f64>,
    /// Process noise as a function of the parameters.
    pub q: CovModel,
    /// Measurement noise as a function of the parameters.
    pub r: CovModel,
}

/// A linear-Gaussian problem: the truth and the Kalman filter's model.
#[derive(Debug, Clone)]
pub struct LinearProblem {
    /// The truth.
    pub truth: LinearGaussianModel,
    /// The filter's model.
    pub filter: FilterModel,
}

impl LinearProblem {
    /// The Kalman filter with parameters `theta` (one value per parameter, in order).
    pub fn filter_at(&self, theta: &[f64]) -> KalmanFilter {
        KalmanFilter {
            F: self.filter.F.clone(),
            H: self.filter.H.clone(),
            Q: self.filter.q.build(theta),
            R: self.filter.r.build(theta),
            x0: self.filter.x0.clone(),
            P0: self.filter.P0.clone(),
        }
    }
}

/// What a problem simulates and filters.
#[derive(Debug, Clone)]
pub enum System {
    /// `[truth]` and `[filter]`: a linear-Gaussian truth and a Kalman filter.
    Linear(Box<LinearProblem>),
    /// `[model]`: a named model of the catalog ([`crate::model::catalog`]).
    Catalog {
        /// The catalog entry (name, parameters).
        entry: CatalogEntry,
        /// The model built from the file's `[model]` table.
        model: Arc<dyn CatalogModel>,
    },
}

/// A validated problem: everything the engine needs.
#[derive(Debug, Clone)]
pub struct Problem {
    /// Name (from the file, or its stem).
    pub name: String,
    /// One-line description.
    pub description: String,
    /// The file it was read from.
    pub path: PathBuf,
    /// SHA-256 of the file's bytes, hex.
    pub hash: String,
    /// Sample period, s.
    pub dt: f64,
    /// State component names, n.
    pub state_names: Vec<String>,
    /// Measurement component names, m.
    pub measurement_names: Vec<String>,
    /// Monte Carlo settings.
    pub mc: McConfig,
    /// The truth and the filter family.
    pub system: System,
    /// Named parameters.
    pub params: ParamSpace,
    /// The file's `[tune]` section, as written (the tuner validates it).
    pub tune: spec::TuneSpec,
}

impl Problem {
    /// Read and validate a problem file.
    pub fn load(path: &Path) -> Result<Problem, ProblemError> {
        let bytes = std::fs::read(path).map_err(|e| ProblemError {
            file: path.to_path_buf(),
            field: String::new(),
            line: None,
            message: format!("cannot read: {e}"),
        })?;
        let text = String::from_utf8(bytes).map_err(|_| ProblemError {
            file: path.to_path_buf(),
            field: String::new(),
            line: None,
            message: "not UTF-8 text".into(),
        })?;
        Problem::from_toml(&text, path)
    }

    /// Validate problem-file text; `path` names it in errors.
    pub fn from_toml(text: &str, path: &Path) -> Result<Problem, ProblemError> {
        let spec = parse_toml::<ProblemSpec>(text, path)?;
        let mut p = Validator { file: path }.problem(spec)?;
        p.hash = sha256_hex(text.as_bytes());
        Ok(p)
    }

    /// The linear truth and filter model, if the problem is linear.
    pub fn linear(&self) -> Option<&LinearProblem> {
        match &self.system {
            System::Linear(l) => Some(l.as_ref()),
            System::Catalog { .. } => None,
        }
    }

    /// Mutable access to the linear truth and filter model, if the problem is linear.
    pub fn linear_mut(&mut self) -> Option<&mut LinearProblem> {
        match &mut self.system {
            System::Linear(l) => Some(l.as_mut()),
            System::Catalog { .. } => None,
        }
    }

    /// The catalog model, if the problem names one.
    pub fn catalog(&self) -> Option<&dyn CatalogModel> {
        match &self.system {
            System::Linear(_) => None,
            System::Catalog { model, .. } => Some(model.as_ref()),
        }
    }

    /// State dimension (of the filter's error state).
    pub fn n_x(&self) -> usize {
        self.state_names.len()
    }

    /// Measurement dimension (all sensors' components).
    pub fn n_z(&self) -> usize {
        self.measurement_names.len()
    }

    /// Whether parameter `i` sets process noise, and the state (process) or measurement
    /// components it acts on.
    pub fn param_target(&self, i: usize) -> (NoiseKind, Vec<usize>) {
        match &self.system {
            System::Linear(l) => {
                if l.filter.q.uses(i) {
                    (NoiseKind::Process, l.filter.q.touched(i))
                } else {
                    (NoiseKind::Measurement, l.filter.r.touched(i))
                }
            }
            System::Catalog { entry, .. } => entry
                .params
                .get(i)
                .map(|p| (p.noise, p.components.to_vec()))
                .unwrap_or((NoiseKind::Measurement, Vec::new())),
        }
    }

    /// The parameter values equal to the truth's noise, where the problem knows them (catalog
    /// models; a linear problem's truth is written as matrices, not parameters).
    pub fn truth_values(&self) -> Option<Vec<f64>> {
        self.catalog().map(|m| m.truth_values())
    }
}

/// SHA-256 of bytes as lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Deserialize TOML into `T`, turning syntax and schema errors into a [`ProblemError`]
/// with the field path and line.
pub fn parse_toml<T: serde::de::DeserializeOwned>(
    text: &str,
    path: &Path,
) -> Result<T, ProblemError> {
    let line_of = |span: Option<std::ops::Range<usize>>| {
        span.map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
    };
    let one_line = |m: &str| m.trim().replace('\n', "; ");
    let de = toml::de::Deserializer::parse(text).map_err(|e| ProblemError {
        file: path.to_path_buf(),
        field: String::new(),
        line: line_of(e.span()),
        message: format!("malformed TOML: {}", one_line(e.message())),
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        ProblemError {
            file: path.to_path_buf(),
            field: if field == "." { String::new() } else { field },
            line: line_of(inner.span()),
            message: one_line(inner.message()),
        }
    })
}

struct Validator<'a> {
    file: &'a Path,
}

type VResult<T> = Result<T, ProblemError>;

/// A model's discrete transition F and, when given in continuous time, its A.
type Dynamics = (DMatrix<f64>, Option<DMatrix<f64>>);

impl Validator<'_> {
    fn err<T>(&self, field: impl Into<String>, message: impl Into<String>) -> VResult<T> {
        Err(ProblemError {
            file: self.file.to_path_buf(),
            field: field.into(),
            line: None,
            message: message.into(),
        })
    }

    fn finite(&self, field: &str, v: f64) -> VResult<f64> {
        if v.is_finite() {
            Ok(v)
        } else {
            self.err(field, format!("{v} is not a finite number"))
        }
    }

    fn matrix(
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

    fn vector(&self, field: &str, v: &[f64], len: usize) -> VResult<DVector<f64>> {
        if v.len() != len {
            return self.err(field, format!("has {} entries, expected {len}", v.len()));
        }
        for (i, &x) in v.iter().enumerate() {
            self.finite(&format!("{field}[{i}]"), x)?;
        }
        Ok(DVector::from_column_slice(v))
    }

    fn symmetric_psd(&self, field: &str, m: &DMatrix<f64>, definite: bool) -> VResult<()> {
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
            return self.err(
                field,
                format!("not positive definite (smallest eigenvalue {lmin:.3e})"),
            );
        }
        Ok(())
    }

    fn dynamics(
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
    fn cov_model(
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
            let indices = |needed: Option<usize>| -> VResult<Vec<usize>> {
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
            };
            let unexpected = |name: &str, present: bool| -> VResult<()> {
                if present {
                    self.err(
                        format!("{tf}.{name}"),
                        format!("not used by kind '{}'", kind_name(term.kind)),
                    )
                } else {
                    Ok(())
                }
            };
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
            let basis = match term.kind {
                TermKind::Dwna | TermKind::Cwna => {
                    unexpected("matrix", term.matrix.is_some())?;
                    unexpected("input", term.input.is_some())?;
                    let ix = indices(Some(2))?;
                    let block = if term.kind == TermKind::Dwna {
                        dwna_block(dt)
                    } else {
                        cwna_block(dt)
                    };
                    embed(dim, &ix, &block)
                }
                TermKind::Diag => {
                    unexpected("matrix", term.matrix.is_some())?;
                    unexpected("input", term.input.is_some())?;
                    let ix = indices(None)?;
                    let mut m = DMatrix::zeros(dim, dim);
                    for i in ix {
                        m[(i, i)] = 1.0;
                    }
                    m
                }
                TermKind::Matrix => {
                    unexpected("indices", term.indices.is_some())?;
                    unexpected("input", term.input.is_some())?;
                    let Some(ms) = &term.matrix else {
                        return self.err(format!("{tf}.matrix"), "kind 'matrix' needs matrix");
                    };
                    let m = self.matrix(&format!("{tf}.matrix"), ms, Some(dim), Some(dim))?;
                    self.symmetric_psd(&format!("{tf}.matrix"), &m, false)?;
                    m
                }
                TermKind::Continuous => {
                    unexpected("indices", term.indices.is_some())?;
                    unexpected("matrix", term.matrix.is_some())?;
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
                    van_loan(a, &(&g * g.transpose()), dt)
                }
            };
            if basis.iter().any(|v| !v.is_finite()) {
                return self.err(
                    tf.clone(),
                    format!("kind '{}' overflows with dt = {dt:e}", kind_name(term.kind)),
                );
            }
            let coef = match (&term.param, term.value) {
                (Some(_), Some(_)) => {
                    return self.err(
                        format!("{tf}.value"),
                        "give either param or value, not both",
                    );
                }
                (None, None) => {
                    return self.err(
                        tf.clone(),
                        "needs param (a named parameter) or value (a fixed number)",
                    );
                }
                (None, Some(v)) => {
                    self.finite(&format!("{tf}.value"), v)?;
                    if v < 0.0 {
                        return self.err(
                            format!("{tf}.value"),
                            format!("{v} is negative; a variance must be ≥ 0"),
                        );
                    }
                    Coef::Fixed(v)
                }
                (Some(name), None) => {
                    let Some(ps) = params else {
                        return self.err(
                            format!("{tf}.param"),
                            "the truth takes fixed values: use value",
                        );
                    };
                    match ps.index(name) {
                        Some(i) => Coef::Param(i),
                        None => {
                            let known = ps.names().join(", ");
                            return self.err(
                                format!("{tf}.param"),
                                format!(
                                    "unknown parameter '{name}' (defined in [params]: {known})"
                                ),
                            );
                        }
                    }
                }
            };
            out.push(CovTerm { coef, basis });
        }
        Ok(CovModel { dim, terms: out })
    }

    fn params(&self, spec: &indexmap::IndexMap<String, spec::ParamSpec>) -> VResult<ParamSpace> {
        let mut params = Vec::with_capacity(spec.len());
        for (name, p) in spec {
            let f = format!("params.{name}");
            if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                return self.err(f, "parameter names use letters, digits and _ only");
            }
            let value = self.finite(&format!("{f}.value"), p.value)?;
            if value <= 0.0 {
                return self.err(
                    format!("{f}.value"),
                    format!("{value} must be > 0 (variances are searched in log space)"),
                );
            }
            let lower = self.finite(&format!("{f}.lower"), p.lower.unwrap_or(value / 1e4))?;
            let upper = self.finite(&format!("{f}.upper"), p.upper.unwrap_or(value * 1e4))?;
            if lower <= 0.0 {
                return self.err(format!("{f}.lower"), format!("{lower} must be > 0"));
            }
            if lower >= upper {
                return self.err(
                    format!("{f}.lower"),
                    format!("lower bound {lower} is not below upper bound {upper}"),
                );
            }
            if value < lower || value > upper {
                return self.err(
                    format!("{f}.value"),
                    format!("{value} is outside [{lower}, {upper}]"),
                );
            }
            params.push(ParamDef {
                name: name.clone(),
                value,
                lower,
                upper,
                fixed: p.fixed,
                unit: p.unit.clone(),
                about: p.about.clone(),
            });
        }
        Ok(ParamSpace { params })
    }

    fn names(
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

    fn problem(&self, s: ProblemSpec) -> VResult<Problem> {
        let dt = self.finite("dt", s.dt)?;
        if dt <= 0.0 {
            return self.err("dt", format!("{dt} must be > 0 (seconds per step)"));
        }
        let mc = &s.montecarlo;
        if mc.runs < 1 {
            return self.err("montecarlo.runs", format!("{} must be ≥ 1", mc.runs));
        }
        if mc.steps < 1 || mc.steps > MAX_STEPS as i64 {
            return self.err(
                "montecarlo.steps",
                format!("{} must be in 1..={MAX_STEPS}", mc.steps),
            );
        }
        if !(mc.alpha > 0.0 && mc.alpha < 1.0) {
            return self.err(
                "montecarlo.alpha",
                format!("{} must be in (0, 1)", mc.alpha),
            );
        }
        let lags = match mc.lags {
            Some(l) if l < 0 => return self.err("montecarlo.lags", format!("{l} must be ≥ 0")),
            Some(l) if l >= mc.steps => {
                return self.err(
                    "montecarlo.lags",
                    format!("{l} must be below steps ({})", mc.steps),
                );
            }
            Some(l) => l,
            None => 5.min(mc.steps - 1),
        };
        let mc = McConfig {
            runs: mc.runs as usize,
            steps: mc.steps as usize,
            seed: mc.seed,
            alpha: mc.alpha,
            lags: lags as usize,
        };

        let (system, params, state_names, measurement_names) = match (&s.truth, &s.filter, &s.model)
        {
            (None, None, Some(model)) => self.catalog_problem(&s, model, dt, &mc)?,
            (t, _, Some(_)) => {
                let which = if t.is_some() { "truth" } else { "filter" };
                return self.err(
                    which,
                    "give either [model] (a named model) or [truth] and [filter], not both",
                );
            }
            (Some(t), Some(f), None) => self.linear_problem(&s, t, f, dt)?,
            (None, _, None) => {
                return self.err(
                    "truth",
                    "missing: give [truth] and [filter], or [model] with a catalog name",
                );
            }
            (Some(_), None, None) => return self.err("filter", "missing"),
        };
        let name = s.name.clone().unwrap_or_else(|| {
            self.file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "problem".into())
        });
        // The name becomes part of output paths (tuned/<name>.toml).
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            let field = if s.name.is_some() {
                "name"
            } else {
                "name (from the file name)"
            };
            return self.err(
                field,
                format!("'{name}' must be letters, digits, _ and - only"),
            );
        }
        Ok(Problem {
            name,
            description: s.description.clone().unwrap_or_default(),
            path: self.file.to_path_buf(),
            hash: String::new(),
            dt,
            state_names,
            measurement_names,
            mc,
            system,
            params,
            tune: s.tune.clone(),
        })
    }

    fn linear_problem(
        &self,
        s: &ProblemSpec,
        t: &spec::TruthSpec,
        f: &spec::FilterSpec,
        dt: f64,
    ) -> VResult<(System, ParamSpace, Vec<String>, Vec<String>)> {
        let Some((tF, tA)) = self.dynamics("truth", &t.F, &t.A, dt, None)? else {
            return self.err("truth.F", "missing: give F (discrete) or A (continuous)");
        };
        let n = tF.nrows();
        let tH = self.matrix("truth.H", &t.H, None, Some(n))?;
        let m = tH.nrows();
        let tx0 = self.vector("truth.x0", &t.x0, n)?;
        let tP0 = self.matrix("truth.P0", &t.P0, Some(n), Some(n))?;
        self.symmetric_psd("truth.P0", &tP0, false)?;
        let tQ = self
            .cov_model("truth.Q", &t.Q, n, true, dt, tA.as_ref(), None)?
            .build(&[]);
        let tR = self
            .cov_model("truth.R", &t.R, m, false, dt, None, None)?
            .build(&[]);
        self.symmetric_psd("truth.Q", &tQ, false)?;
        self.symmetric_psd("truth.R", &tR, false)?;

        let params = self.params(&s.params)?;
        let (fF, fA) = match self.dynamics("filter", &f.F, &f.A, dt, Some(n))? {
            Some(d) => d,
            None => (tF.clone(), tA.clone()),
        };
        let fH = match &f.H {
            Some(h) => self.matrix("filter.H", h, Some(m), Some(n))?,
            None => tH.clone(),
        };
        let fx0 = match &f.x0 {
            Some(x) => self.vector("filter.x0", x, n)?,
            None => tx0.clone(),
        };
        let (fP0, p0_field) = match &f.P0 {
            Some(p) => (self.matrix("filter.P0", p, Some(n), Some(n))?, "filter.P0"),
            None => (tP0.clone(), "truth.P0 (used as filter.P0)"),
        };
        self.symmetric_psd(p0_field, &fP0, true)?;
        let q = self.cov_model("filter.Q", &f.Q, n, true, dt, fA.as_ref(), Some(&params))?;
        let r = self.cov_model("filter.R", &f.R, m, false, dt, None, Some(&params))?;
        for (i, p) in params.params.iter().enumerate() {
            if !q.uses(i) && !r.uses(i) {
                return self.err(
                    format!("params.{}", p.name),
                    "not used by any filter.Q or filter.R term",
                );
            }
        }
        let truth =
            LinearGaussianModel::new(tF, tH, tQ, tR, tx0, tP0).map_err(|e| ProblemError {
                file: self.file.to_path_buf(),
                field: format!("truth.{}", e.which),
                line: None,
                message: e.to_string(),
            })?;
        let state_names = self.names("state_names", &s.state_names, n, "x")?;
        let measurement_names = self.names("measurement_names", &s.measurement_names, m, "z")?;
        let system = System::Linear(Box::new(LinearProblem {
            truth,
            filter: FilterModel {
                F: fF,
                H: fH,
                x0: fx0,
                P0: fP0,
                q,
                r,
            },
        }));
        Ok((system, params, state_names, measurement_names))
    }

    fn catalog_problem(
        &self,
        s: &ProblemSpec,
        table: &toml::Table,
        dt: f64,
        mc: &McConfig,
    ) -> VResult<(System, ParamSpace, Vec<String>, Vec<String>)> {
        let known = || {
            catalog::entries()
                .iter()
                .map(|e| e.name)
                .collect::<Vec<_>>()
                .join(", ")
        };
        let name = match table.get("name") {
            Some(toml::Value::String(n)) => n.clone(),
            Some(_) => return self.err("model.name", "must be a string"),
            None => {
                return self.err(
                    "model.name",
                    format!("missing: name a catalog model ({})", known()),
                );
            }
        };
        let Some(entry) = catalog::find(&name) else {
            return self.err(
                "model.name",
                format!("unknown model '{name}' (known models: {})", known()),
            );
        };
        for (field, given) in [
            ("state_names", s.state_names.is_some()),
            ("measurement_names", s.measurement_names.is_some()),
        ] {
            if given {
                return self.err(field, format!("model '{name}' names its own components"));
            }
        }
        let mut rest = table.clone();
        rest.remove("name");
        let ctx = ModelContext {
            dt,
            steps: mc.steps,
        };
        let model = (entry.build)(&rest, &ctx).map_err(|e| ProblemError {
            file: self.file.to_path_buf(),
            field: if e.field.is_empty() {
                "model".into()
            } else {
                format!("model.{}", e.field)
            },
            line: None,
            message: e.message,
        })?;
        let given = self.params(&s.params)?;
        let expected: Vec<&str> = entry.params.iter().map(|p| p.name).collect();
        for p in &given.params {
            if !expected.contains(&p.name.as_str()) {
                return self.err(
                    format!("params.{}", p.name),
                    format!(
                        "not a parameter of model '{name}' (its parameters: {})",
                        expected.join(", ")
                    ),
                );
            }
        }
        // θ follows the model's order, whatever order the file lists them in.
        let mut params = Vec::with_capacity(expected.len());
        for info in entry.params {
            let Some(i) = given.index(info.name) else {
                return self.err(
                    format!("params.{}", info.name),
                    format!(
                        "missing: model '{name}' needs [params.{}] ({}, {})",
                        info.name, info.about, info.unit
                    ),
                );
            };
            let mut p = given.params[i].clone();
            if p.unit.is_empty() {
                p.unit = info.unit.to_string();
            }
            if p.about.is_empty() {
                p.about = info.about.to_string();
            }
            params.push(p);
        }
        let state_names = model.state_names();
        let measurement_names = model.measurement_names();
        let system = System::Catalog {
            entry,
            model: Arc::from(model),
        };
        Ok((
            system,
            ParamSpace { params },
            state_names,
            measurement_names,
        ))
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
