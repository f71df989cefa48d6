//! What a catalog model is to the rest of the tool: its entry (name, parameters, builder),
//! the trait it implements, the context and errors of building it from a `[model]` table.

use std::fmt::Debug;

use serde::de::DeserializeOwned;

use crate::filter::Filter;
use crate::model::TruthModel;
use crate::params::NoiseKind;

/// One named filter parameter of a catalog model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamInfo {
    /// Name, as the problem file's `[params.NAME]` spells it.
    pub name: &'static str,
    /// Unit of the value, e.g. `"(m/s²)²"`.
    pub unit: &'static str,
    /// What it models, one line.
    pub about: &'static str,
    /// Process or measurement noise.
    pub noise: NoiseKind,
    /// The state components (process noise) or measurement components (measurement noise,
    /// indices into the concatenated sensor components) it drives most directly; the
    /// report's per-axis advice reads their statistics.
    pub components: &'static [usize],
}

/// A catalog model built from a problem file: the truth, and the filter at given
/// parameter values.
pub trait CatalogModel: Send + Sync + Debug {
    /// Names of the filter's (error-)state components, n_x.
    fn state_names(&self) -> Vec<String>;
    /// Names of all sensors' measurement components, concatenated in sensor order.
    fn measurement_names(&self) -> Vec<String>;
    /// The truth model.
    fn truth(&self) -> &dyn TruthModel;
    /// The filter with parameter values `theta`, in the entry's [`CatalogEntry::params`]
    /// order.
    fn filter(&self, theta: &[f64]) -> Box<dyn Filter>;
    /// The parameter values that equal the truth's noise (the truth's own values where the
    /// filter shares the truth's noise structure, the closest equivalent otherwise), in
    /// [`CatalogEntry::params`] order.
    fn truth_values(&self) -> Vec<f64>;
}

/// Why a `[model]` table was refused: the field (relative to `[model]`, e.g.
/// `truth.accel_std`) and what is wrong, on one line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct ModelError {
    /// Dotted path below `[model]` (empty for the table itself).
    pub field: String,
    /// What is wrong.
    pub message: String,
}

impl ModelError {
    /// An error at `field`.
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        ModelError {
            field: field.into(),
            message: message.into(),
        }
    }
}

/// What the problem file fixes outside `[model]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelContext {
    /// Filter step, s (the file's `dt`).
    pub dt: f64,
    /// Steps per run T (`[montecarlo] steps`).
    pub steps: usize,
}

/// Builds a catalog model from its `[model]` table (without the `name` key).
pub type Builder = fn(&toml::Table, &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError>;

/// A named model: its parameters and how to build it.
#[derive(Debug, Clone, Copy)]
pub struct CatalogEntry {
    /// The name `[model] name` selects it by.
    pub name: &'static str,
    /// One line saying what it is.
    pub about: &'static str,
    /// The filter parameters the problem file must give under `[params]`, in θ order.
    pub params: &'static [ParamInfo],
    /// Build from the `[model]` table (without its `name` key).
    pub build: Builder,
}

/// Deserialize a `[model]` table into a model's own settings struct, with the failing
/// field's path in the error (use `#[serde(deny_unknown_fields)]` on the struct so a
/// misspelt key is refused by name).
pub fn parse_table<T: DeserializeOwned>(table: &toml::Table) -> Result<T, ModelError> {
    let value = toml::Value::Table(table.clone());
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        let field = if path == "." { String::new() } else { path };
        // The message alone: toml's Display adds the table's context on further lines.
        ModelError::new(field, e.into_inner().message().trim().to_string())
    })
}

/// Check that `v` is finite and positive.
pub fn positive(field: &str, v: f64) -> Result<f64, ModelError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(ModelError::new(
            field,
            format!("must be finite and > 0, got {v}"),
        ))
    }
}
