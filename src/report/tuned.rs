//! Tuned configs: the parameter values (and the Q and R they give) that `autotune check
//! --config` applies on top of a problem file.

use std::path::Path;

use indexmap::IndexMap;
use serde::{Deserialize, Serialize};

use crate::params::ParamSpace;
use crate::problem::{ProblemError, parse_toml};

/// A tuned config as stored on disk.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TunedConfig {
    /// Name of the problem it was tuned for.
    pub problem: String,
    /// Parameter values by name.
    pub params: IndexMap<String, f64>,
    /// Anything else the writer recorded (Q, R, provenance); not read back.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub provenance: Option<toml::Table>,
    /// Process noise covariance the parameters give, rows (informational).
    #[serde(default, rename = "Q", skip_serializing_if = "Option::is_none")]
    pub q: Option<Vec<Vec<f64>>>,
    /// Measurement noise covariance the parameters give, rows (informational).
    #[serde(default, rename = "R", skip_serializing_if = "Option::is_none")]
    pub r: Option<Vec<Vec<f64>>>,
}

impl TunedConfig {
    /// Read a tuned config and map its values onto `space`: every parameter of the problem
    /// must be given, and nothing else.
    pub fn load_values(path: &Path, space: &ParamSpace) -> Result<Vec<f64>, ProblemError> {
        let err = |field: String, message: String| ProblemError {
            file: path.to_path_buf(),
            field,
            line: None,
            message,
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| err(String::new(), format!("cannot read: {e}")))?;
        let cfg: TunedConfig = parse_toml(&text, path)?;
        let mut values = space.values();
        for (name, &v) in &cfg.params {
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
            if !cfg.params.contains_key(&p.name) {
                return Err(err(format!("params.{}", p.name), "missing".into()));
            }
        }
        Ok(values)
    }
}
