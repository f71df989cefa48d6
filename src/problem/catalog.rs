//! A catalog problem: `[model]` selects a named model of [`crate::catalog`] and becomes a
//! [`CatalogExperiment`].

use super::spec::ProblemSpec;
use super::validate::{VResult, Validator};
use crate::catalog::{self, ModelContext};
use crate::experiment::{CatalogExperiment, Definition, Info};
use crate::input::FileError;
use crate::montecarlo::McConfig;
use crate::params::ParamSpace;

impl Validator<'_> {
    /// Build the named catalog model from `[model]`, with the parameters it declares in its
    /// own order.
    pub(super) fn catalog_problem(
        &self,
        s: &ProblemSpec,
        table: &toml::Table,
        info: Info,
        mc: McConfig,
    ) -> VResult<CatalogExperiment> {
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
            dt: s.dt.unwrap_or(1.0),
            steps: mc.steps(),
        };
        let model = (entry.build)(&rest, &ctx).map_err(|e| {
            let field = if e.field.is_empty() {
                "model".into()
            } else {
                format!("model.{}", e.field)
            };
            FileError::new(self.file, field, e.message)
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
        for declared in entry.params {
            let Some(i) = given.index(declared.name) else {
                return self.err(
                    format!("params.{}", declared.name),
                    format!(
                        "missing: model '{name}' needs [params.{}] ({}, {})",
                        declared.name, declared.about, declared.unit
                    ),
                );
            };
            let mut p = given.params[i].clone();
            if p.unit.is_empty() {
                p.unit = declared.unit.to_string();
            }
            if p.about.is_empty() {
                p.about = declared.about.to_string();
            }
            params.push(p);
        }
        Ok(CatalogExperiment {
            definition: Definition {
                info,
                params: ParamSpace { params },
                state_names: model.state_names(),
                measurement_names: model.measurement_names(),
                mc,
            },
            entry,
            model,
            truth_cache: Default::default(),
        })
    }
}
