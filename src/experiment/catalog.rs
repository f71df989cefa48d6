//! A problem file's catalog `[model]` as an [`Experiment`].

use super::held::Held;
use super::{Definition, Experiment, ExperimentError, RunOptions};
use crate::catalog::{CatalogEntry, CatalogModel};
use crate::filter::Correction;
use crate::montecarlo::{McConfig, TruthCache};
use crate::params::Target;
use crate::stats::Accumulator;

/// A named model of the catalog: its truth, its filter at θ, and the entry's parameter
/// targets. Nonlinear filters have data-dependent gains, so it runs the generic engine.
#[derive(Debug)]
pub struct CatalogExperiment {
    /// Name, source, parameters (in the entry's order), the model's component names, and
    /// the Monte Carlo test.
    pub definition: Definition,
    /// The catalog entry (name, parameters).
    pub entry: CatalogEntry,
    /// The model built from the file's `[model]` table.
    pub model: Box<dyn CatalogModel>,
    /// The truth of seed sets evaluated more than once (a catalog truth does not depend on
    /// θ: the parameters are the filter's).
    pub truth_cache: TruthCache,
}

impl CatalogExperiment {
    fn held(&self) -> Held<'_, dyn crate::model::TruthModel + '_> {
        Held {
            truth: self.model.truth(),
            cache: &self.truth_cache,
        }
    }
}

impl Experiment for CatalogExperiment {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        self.held().monte_carlo(&self.model.filter(theta), mc, run)
    }
}

impl crate::experiment::Structure for CatalogExperiment {
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

impl crate::experiment::HeldAsCode for CatalogExperiment {
    fn monte_carlo_corrected(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
        correction: &Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        self.held()
            .corrected(&self.model.filter(theta), mc, run, correction)
    }

    fn replay_filter(&self, theta: &[f64]) -> Option<Box<dyn crate::filter::Filter + '_>> {
        Some(self.model.filter(theta))
    }

    fn simulation_truth(&self) -> Option<&dyn crate::model::TruthModel> {
        Some(self.model.truth())
    }

    fn innovation_scales(&self, theta: &[f64], mc: &McConfig) -> Option<Vec<f64>> {
        self.held().innovation_scales(&self.model.filter(theta), mc)
    }
}

impl crate::experiment::Sampling for CatalogExperiment {
    // Every evaluation runs the generic engine (`Held::monte_carlo`).
    fn splits_runs(&self) -> bool {
        true
    }

    fn truth_reuse(&self, since: crate::montecarlo::TapeUsage) -> super::TruthReuse {
        self.held().truth_reuse(since)
    }

    fn tape_usage(&self) -> crate::montecarlo::TapeUsage {
        self.held().tape_usage()
    }
}
