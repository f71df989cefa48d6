//! Options several commands share, and how their values become settings: every value goes
//! through the library's setters, and a refusal names the option as the command line spells
//! it.

use super::CommandError;
use crate::input::OneOf;
use crate::montecarlo::McConfig;
use crate::params::ParamSpace;
use crate::stats::GateMode;

/// Monte Carlo overrides shared by `check` and `tune`: the experiment's own settings with
/// these values in their place. Numeric values may be negative on the
/// command line (`--alpha -0.1` is a value, refused by the setter, not an unknown flag).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct McOverrides {
    /// Number of Monte Carlo runs N (overrides the file).
    #[arg(long, allow_negative_numbers = true)]
    runs: Option<usize>,
    /// Steps per run T (overrides the file).
    #[arg(long, allow_negative_numbers = true)]
    steps: Option<usize>,
    /// Base seed (overrides the file).
    #[arg(long, allow_negative_numbers = true)]
    seed: Option<u64>,
    /// Significance level α in (0, 1) (overrides the file).
    #[arg(long, allow_negative_numbers = true)]
    alpha: Option<f64>,
    /// Which tests the gate applies (overrides the file): full = the time averages, every
    /// component and the innovations' whiteness at a family-wise α (Šidák); mean = the
    /// textbook ANEES/ANIS test alone.
    #[arg(long, value_parser = OneOf::<GateMode>::new())]
    gate: Option<GateMode>,
    /// Set a parameter, NAME=VALUE (repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
}

impl McOverrides {
    /// The experiment's Monte Carlo settings with the overrides applied.
    pub fn apply(&self, mut mc: McConfig) -> Result<McConfig, CommandError> {
        if let Some(n) = self.runs {
            mc = mc.with_runs(n).map_err(CommandError::of_option("--runs"))?;
        }
        if let Some(t) = self.steps {
            mc = mc
                .with_steps(t)
                .map_err(CommandError::of_option("--steps"))?;
        }
        if let Some(s) = self.seed {
            mc = mc.with_seed(s);
        }
        if let Some(a) = self.alpha {
            mc = mc
                .with_alpha(a)
                .map_err(CommandError::of_option("--alpha"))?;
        }
        if let Some(g) = self.gate {
            mc = mc.with_gate(g);
        }
        Ok(mc)
    }

    /// Whether `--runs` was given.
    pub fn runs_given(&self) -> bool {
        self.runs.is_some()
    }

    /// `theta` with the `--set` values applied; returns the indices set.
    pub fn set_params(
        &self,
        params: &ParamSpace,
        theta: &mut [f64],
    ) -> Result<Vec<usize>, CommandError> {
        let mut set = Vec::with_capacity(self.set.len());
        for kv in &self.set {
            let (i, v) = name_value(params, "--set", kv)?;
            theta[i] = v;
            set.push(i);
        }
        Ok(set)
    }
}

/// Parse `NAME=VALUE` with VALUE a finite number > 0 naming one of the parameters.
pub(crate) fn name_value(
    params: &ParamSpace,
    flag: &str,
    kv: &str,
) -> Result<(usize, f64), CommandError> {
    let (name, value) = kv
        .split_once('=')
        .ok_or_else(|| CommandError::option(flag, format!("'{kv}' is not NAME=VALUE")))?;
    let i = param_index(params, flag, name)?;
    let v = value
        .trim()
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite() && *v > 0.0)
        .ok_or_else(|| {
            CommandError::option(flag, format!("{name}: '{value}' is not a number > 0"))
        })?;
    Ok((i, v))
}

/// The index of parameter `name`, or an error of `flag` listing the known ones.
pub(crate) fn param_index(
    params: &ParamSpace,
    flag: &str,
    name: &str,
) -> Result<usize, CommandError> {
    params.index(name.trim()).ok_or_else(|| {
        CommandError::option(
            flag,
            format!(
                "unknown parameter '{name}' (known: {})",
                params.names().join(", ")
            ),
        )
    })
}
