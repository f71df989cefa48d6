//! What the Rust builders of an experiment ([`super::RustModel::builder`],
//! [`super::LinearExperiment::builder`]) collect besides the model itself: its name,
//! description and program, the components' names, the parameters and the Monte Carlo
//! test, checked the same way for both, with errors naming the setting.

use super::{Definition, Info, Source};
use crate::input::SettingError;
use crate::montecarlo::McConfig;
use crate::params::{ParamDef, ParamSpace};

/// A builder's description of its experiment, before it is checked.
pub(super) struct Described {
    pub(super) name: String,
    pub(super) description: String,
    pub(super) program: Option<String>,
    pub(super) state_names: Option<Vec<String>>,
    pub(super) measurement_names: Option<Vec<String>>,
    pub(super) mc: Option<McConfig>,
}

impl Described {
    /// An experiment called `name`, described by nothing else yet.
    pub(super) fn new(name: &str) -> Described {
        Described {
            name: name.to_string(),
            description: String::new(),
            program: None,
            state_names: None,
            measurement_names: None,
            mc: None,
        }
    }

    /// The checked definition of an experiment with parameters `params` (already checked,
    /// [`param_space`]), n_x states and n_z measurement components; the name is checked
    /// first, by [`check_name`].
    pub(super) fn definition(
        self,
        params: ParamSpace,
        n_x: usize,
        n_z: usize,
    ) -> Result<Definition, SettingError> {
        let state_names = names(self.state_names, n_x, "x", "states")?;
        let measurement_names = names(self.measurement_names, n_z, "z", "measurements")?;
        let program = self.program.unwrap_or_else(|| {
            std::env::current_exe()
                .ok()
                .and_then(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
                .unwrap_or_else(|| "model".to_string())
        });
        let mc = match self.mc {
            Some(mc) => mc,
            None => McConfig::new(100, 100)?,
        };
        Ok(Definition {
            info: Info {
                name: self.name,
                description: self.description,
                source: Source::Program { name: program },
            },
            params,
            state_names,
            measurement_names,
            mc,
        })
    }
}

/// An experiment's name is used for output names: letters, digits, `_` and `-`.
pub(super) fn check_name(name: &str) -> Result<(), SettingError> {
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        return Err(SettingError::new(
            "name",
            format!("'{name}' must be letters, digits, _ and - only"),
        ));
    }
    Ok(())
}

/// The parameters, each checked ([`ParamDef::validate`]) and named once.
pub(super) fn param_space(
    defs: impl IntoIterator<Item = ParamDef>,
) -> Result<ParamSpace, SettingError> {
    let mut params: Vec<ParamDef> = Vec::new();
    for def in defs {
        def.validate()
            .map_err(|e| e.within(&format!("params.{}", def.name)))?;
        if params.iter().any(|d| d.name == def.name) {
            return Err(SettingError::new(
                format!("params.{}", def.name),
                "defined twice",
            ));
        }
        params.push(def);
    }
    Ok(ParamSpace { params })
}

/// `n` component names: the given ones (as many as there are components), or `prefix0`,
/// `prefix1`, ….
fn names(
    given: Option<Vec<String>>,
    n: usize,
    prefix: &str,
    setting: &str,
) -> Result<Vec<String>, SettingError> {
    match given {
        Some(v) if v.len() != n => Err(SettingError::new(
            setting,
            format!("{} names for {n} components", v.len()),
        )),
        Some(v) => Ok(v),
        None => Ok((0..n).map(|i| format!("{prefix}{i}")).collect()),
    }
}

/// The setters every experiment builder shares, on a builder with a `described` field.
macro_rules! description_setters {
    () => {
        /// One line saying what is modelled.
        pub fn description(mut self, text: &str) -> Self {
            self.described.description = text.to_string();
            self
        }

        /// The program's name in reports and in the `<program> check --config` hint
        /// (default: the running executable's file stem).
        pub fn program(mut self, name: &str) -> Self {
            self.described.program = Some(name.to_string());
            self
        }

        /// Names of the filter's state components, n_x (default `x0`, `x1`, …).
        pub fn states<I: IntoIterator<Item = S>, S: Into<String>>(mut self, names: I) -> Self {
            self.described.state_names = Some(names.into_iter().map(Into::into).collect());
            self
        }

        /// Names of all sensors' measurement components in sensor order (default `z0`, …).
        pub fn measurements<I: IntoIterator<Item = S>, S: Into<String>>(
            mut self,
            names: I,
        ) -> Self {
            self.described.measurement_names = Some(names.into_iter().map(Into::into).collect());
            self
        }

        /// The Monte Carlo test (default: 100 runs × 100 steps, seed 0, α = 0.05).
        pub fn montecarlo(mut self, mc: McConfig) -> Self {
            self.described.mc = Some(mc);
            self
        }
    };
}
pub(super) use description_setters;
