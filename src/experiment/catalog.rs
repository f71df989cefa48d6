//! A problem file's catalog `[model]` as an [`Experiment`].

use super::{Experiment, Info, RunOptions};
use crate::catalog::{CatalogEntry, CatalogModel};
use crate::montecarlo::{self, McConfig};
use crate::params::{ParamSpace, Target};
use crate::stats::Accumulator;

/// A named model of the catalog: its truth, its filter at θ, and the entry's parameter
/// targets. Nonlinear filters have data-dependent gains, so it runs the generic engine.
#[derive(Debug)]
pub struct CatalogExperiment {
    /// Name, description, source.
    pub info: Info,
    /// The catalog entry (name, parameters).
    pub entry: CatalogEntry,
    /// The model built from the file's `[model]` table.
    pub model: Box<dyn CatalogModel>,
    /// Named parameters, in the entry's order.
    pub params: ParamSpace,
    /// State component names (the model's).
    pub state_names: Vec<String>,
    /// Measurement component names (the model's).
    pub measurement_names: Vec<String>,
    /// The Monte Carlo test.
    pub mc: McConfig,
}

impl Experiment for CatalogExperiment {
    fn info(&self) -> &Info {
        &self.info
    }

    fn params(&self) -> &ParamSpace {
        &self.params
    }

    fn state_names(&self) -> &[String] {
        &self.state_names
    }

    fn measurement_names(&self) -> &[String] {
        &self.measurement_names
    }

    fn mc(&self) -> &McConfig {
        &self.mc
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Accumulator {
        montecarlo::run_generic_with_progress(
            self.model.truth(),
            &self.model.filter(theta),
            mc,
            options.progress,
        )
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.entry.params.get(i).map(|p| Target {
            kind: p.noise,
            components: p.components.to_vec(),
        })
    }

    fn truth_values(&self) -> Option<Vec<f64>> {
        Some(self.model.truth_values())
    }
}
