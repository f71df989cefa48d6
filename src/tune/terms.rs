//! The objective's terms by name: their weights as a problem file, a flag or a setter gives
//! them, and an objective's value split into them ([`super::objective`] computes them).

use serde::{Deserialize, Serialize};

use crate::input::SettingError;

/// One number per term of J: the terms' weights ([`Weights`], all ≥ 0), or their weighted
/// values (inside [`Terms`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerTerm {
    /// Time averages at their DOF targets.
    pub mean: f64,
    /// Time averages outside their intervals.
    pub interval: f64,
    /// Per-step averages outside their intervals.
    pub per_step: f64,
    /// Per-component normalized errors at 1.
    pub components: f64,
    /// Innovation autocorrelation at 0.
    pub whiteness: f64,
    /// NEES variance at 2 n_x.
    pub shape: f64,
    /// Normalized errors and innovations averaging to 0.
    pub bias: f64,
}

/// Weights of the objective's terms.
pub type Weights = PerTerm;

impl PerTerm {
    /// Zero in every term.
    pub const ZERO: PerTerm = PerTerm {
        mean: 0.0,
        interval: 0.0,
        per_step: 0.0,
        components: 0.0,
        whiteness: 0.0,
        shape: 0.0,
        bias: 0.0,
    };
}

/// The default weights: every term 1, but the distribution shape and the first moments 0.
impl Default for PerTerm {
    fn default() -> Self {
        PerTerm {
            mean: 1.0,
            interval: 1.0,
            per_step: 1.0,
            components: 1.0,
            whiteness: 1.0,
            shape: 0.0,
            bias: 0.0,
        }
    }
}

impl PerTerm {
    /// Set one weight by name (as on the command line); the error's setting is
    /// `weights.<name>`.
    pub fn set(&mut self, name: &str, value: f64) -> Result<(), SettingError> {
        let err = |m: String| SettingError::new(format!("weights.{name}"), m);
        if !(value.is_finite() && value >= 0.0) {
            return Err(err(format!(
                "weight {name} = {value} must be a finite number ≥ 0"
            )));
        }
        let slot = match name {
            "mean" => &mut self.mean,
            "interval" => &mut self.interval,
            "per_step" => &mut self.per_step,
            "components" => &mut self.components,
            "whiteness" => &mut self.whiteness,
            "shape" => &mut self.shape,
            "bias" => &mut self.bias,
            _ => {
                return Err(err(format!(
                    "unknown weight '{name}' (known: mean, interval, per_step, components, whiteness, shape, bias)"
                )));
            }
        };
        *slot = value;
        Ok(())
    }

    /// Refuses weights that are all 0: J would be 0 for every candidate, so the search
    /// could not tell one filter from another. The error's setting is `weights`.
    pub fn check_not_all_zero(&self) -> Result<(), SettingError> {
        let w = [
            self.mean,
            self.interval,
            self.per_step,
            self.components,
            self.whiteness,
            self.shape,
            self.bias,
        ];
        if w.iter().all(|&v| v == 0.0) {
            return Err(SettingError::new(
                "weights",
                "every weight is 0, so every candidate would score 0: give at least one weight > 0",
            ));
        }
        Ok(())
    }
}

/// The objective's value split into its terms (each already weighted).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Terms {
    /// Each term's weighted value.
    #[serde(flatten)]
    pub terms: PerTerm,
    /// Their sum (+∞ for a diverged filter).
    pub total: f64,
}

impl Default for Terms {
    fn default() -> Self {
        Terms {
            terms: PerTerm::ZERO,
            total: 0.0,
        }
    }
}
