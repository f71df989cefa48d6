//! The raw problem-file schema, exactly as written in TOML. [`super::Problem`] is the
//! validated form the engine accepts.

#![allow(non_snake_case)]

use indexmap::IndexMap;
use serde::Deserialize;

/// A matrix as rows of numbers.
pub type MatrixSpec = Vec<Vec<f64>>;

/// The whole problem file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProblemSpec {
    /// Problem name, used for output file names (default: the file stem).
    pub name: Option<String>,
    /// One line saying what is modelled.
    pub description: Option<String>,
    /// Sample period between filter steps, s (required but for `[external]` problems).
    pub dt: Option<f64>,
    /// Names of the state components (default `x0`, `x1`, …).
    pub state_names: Option<Vec<String>>,
    /// Names of the measurement components (default `z0`, `z1`, …).
    pub measurement_names: Option<Vec<String>>,
    /// Monte Carlo settings.
    pub montecarlo: MonteCarloSpec,
    /// The truth model (linear problems; give this and `[filter]`, or `[model]`).
    pub truth: Option<TruthSpec>,
    /// The filter's model and its Q/R terms (linear problems).
    pub filter: Option<FilterSpec>,
    /// A named catalog model (`name = "…"` plus the model's own settings), instead of
    /// `[truth]` and `[filter]`.
    pub model: Option<toml::Table>,
    /// A filter and simulator in another program, driven over the worker protocol
    /// (docs/src/workers.md), instead of `[truth]`/`[filter]` or `[model]`.
    pub external: Option<ExternalSpec>,
    /// Named parameters, in file order.
    #[serde(default, deserialize_with = "in_file_order")]
    pub params: IndexMap<String, ParamSpec>,
    /// Tuner settings (all optional).
    #[serde(default)]
    pub tune: crate::tune::TuneSpec,
}

/// A TOML table in the order its keys appear in the file. The `toml` reader hands a table's
/// keys over sorted (its map is a `BTreeMap` without the `preserve_order` feature, which
/// would also reorder every table autotune writes), so each entry's position in the text
/// restores the file's order.
fn in_file_order<'de, D, T>(d: D) -> Result<IndexMap<String, T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    let table = IndexMap::<String, toml::Spanned<T>>::deserialize(d)?;
    let mut entries: Vec<(String, toml::Spanned<T>)> = table.into_iter().collect();
    entries.sort_by_key(|(_, v)| v.span().start);
    Ok(entries
        .into_iter()
        .map(|(k, v)| (k, v.into_inner()))
        .collect())
}

/// `[external]`: the worker program and what its records hold.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalSpec {
    /// The program and its arguments, run in the problem file's directory.
    pub command: Vec<String>,
    /// Sensor name → its component names, in order (the sensors in file order).
    #[serde(deserialize_with = "in_file_order")]
    pub sensors: IndexMap<String, Vec<String>>,
    /// Workers in parallel (default: the number of cores).
    pub workers: Option<i64>,
    /// Longest wait for one answer, s, start-up included (default 300).
    pub timeout: Option<f64>,
    /// The parameter values equal to the simulated noise, by name (optional; reports and
    /// tests compare with them).
    pub truth: Option<IndexMap<String, f64>>,
    /// Check on the first evaluation that run i's records depend on (seed, i) alone
    /// (default true).
    pub check_seed_contract: Option<bool>,
    /// Parameter name → the components it drives: state names (process noise) or
    /// measurement names `<sensor>_<component>` (measurement noise). Optional; it lets the
    /// advice and the diagnosis name the evidence, and the Gauss–Newton search match it.
    pub drives: Option<IndexMap<String, Vec<String>>>,
}

/// `[montecarlo]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MonteCarloSpec {
    /// Number of runs N.
    pub runs: i64,
    /// Steps per run T.
    pub steps: i64,
    /// Base seed.
    #[serde(default)]
    pub seed: u64,
    /// Significance level α of the two-sided tests (default 0.05).
    #[serde(default = "default_alpha")]
    pub alpha: f64,
    /// Largest innovation-autocorrelation lag reported, below `steps` (default 5, or
    /// `steps − 1` if that is smaller).
    #[serde(default)]
    pub lags: Option<i64>,
    /// Which tests the gate applies: "full" (default; time averages, components and
    /// whiteness at a family-wise α) or "mean" (the textbook ANEES/ANIS gate).
    #[serde(default)]
    pub gate: crate::stats::GateMode,
}

fn default_alpha() -> f64 {
    0.05
}

/// `[truth]`: a linear-Gaussian system.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TruthSpec {
    /// Discrete state transition over one step `dt` (give this or `A`).
    pub F: Option<MatrixSpec>,
    /// Continuous-time system matrix; `F = e^{A dt}` (give this or `F`).
    pub A: Option<MatrixSpec>,
    /// Measurement matrix, m × n.
    pub H: MatrixSpec,
    /// Mean of the initial state.
    pub x0: Vec<f64>,
    /// Covariance of the initial state.
    pub P0: MatrixSpec,
    /// Process-noise terms (fixed values).
    pub Q: Vec<TermSpec>,
    /// Measurement-noise terms (fixed values).
    pub R: Vec<TermSpec>,
}

/// `[filter]`: the filter's own model; omitted matrices are the truth's.
///
/// A filter may carry fewer (or other) states than the truth: `map` (n_f × n_t) takes the
/// truth's state to the filter's, the NEES is taken on `e = map · x_true − x̂`, and the
/// filter then gives its own F (or A) and H of its own dimension n_f.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterSpec {
    /// From the truth's state to the filter's, n_f × n_t (default: the identity, n_f = n_t).
    pub map: Option<MatrixSpec>,
    /// Discrete state transition (default: the truth's; required with a map).
    pub F: Option<MatrixSpec>,
    /// Continuous-time system matrix (default: the truth's; required with a map, or F).
    pub A: Option<MatrixSpec>,
    /// Measurement matrix, m × n_f (default: the truth's; required with a map).
    pub H: Option<MatrixSpec>,
    /// Initial estimate (default: the truth's x0, through the map if there is one).
    pub x0: Option<Vec<f64>>,
    /// Initial covariance (default: the truth's P0, through the map if there is one).
    pub P0: Option<MatrixSpec>,
    /// Process-noise terms, each a named parameter or a fixed value.
    pub Q: Vec<TermSpec>,
    /// Measurement-noise terms, each a named parameter or a fixed value.
    pub R: Vec<TermSpec>,
}

/// The shape of one covariance term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TermKind {
    /// Discrete white-noise acceleration on a (position, velocity) pair; coefficient in
    /// (units/s²)².
    Dwna,
    /// Continuous white-noise acceleration on a (position, velocity) pair; coefficient is a
    /// spectral density in units²/s³.
    Cwna,
    /// The listed diagonal entries; coefficient in the component's units².
    Diag,
    /// A full symmetric PSD matrix times the coefficient.
    Matrix,
    /// Continuous white noise entering `ẋ = A x + g w` through `input = g`, discretized
    /// by Van Loan's method; coefficient is the spectral density of w.
    Continuous,
}

/// One term `coefficient × basis` of Q or R.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TermSpec {
    /// The term's shape.
    pub kind: TermKind,
    /// State indices (dwna/cwna: position then velocity) or diagonal entries (diag).
    pub indices: Option<Vec<i64>>,
    /// Basis matrix (kind = "matrix").
    pub matrix: Option<MatrixSpec>,
    /// Noise input vector g (kind = "continuous").
    pub input: Option<Vec<f64>>,
    /// Name of the parameter that scales the term.
    pub param: Option<String>,
    /// Fixed coefficient.
    pub value: Option<f64>,
}

/// `[params.NAME]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamSpec {
    /// Value the filter is configured with (the tuner's start).
    pub value: f64,
    /// Lower search bound (default value / 1e4).
    pub lower: Option<f64>,
    /// Upper search bound (default value × 1e4).
    pub upper: Option<f64>,
    /// Keep at `value` while tuning.
    #[serde(default)]
    pub fixed: bool,
    /// Unit of the value.
    #[serde(default)]
    pub unit: String,
    /// What the parameter models.
    #[serde(default)]
    pub about: String,
}
