//! An experiment with other search bounds: what the certification of a misfit searches in
//! (the tuner's box widened), everything else the inner experiment's.

use super::{
    Block, Covariances, Definition, Experiment, ExperimentError, LinearExperiment, RunOptions,
    TruthReuse,
};
use crate::montecarlo::{Engine, McConfig, TapeUsage};
use crate::params::Target;
use crate::stats::Accumulator;

/// `inner` with its parameters' bounds replaced.
pub struct Rebounded<'a> {
    inner: &'a dyn Experiment,
    definition: Definition,
}

impl<'a> Rebounded<'a> {
    /// `inner` with each parameter's bounds `bounds[i]` (lower, upper), in its units.
    pub fn new(inner: &'a dyn Experiment, bounds: &[(f64, f64)]) -> Self {
        let mut definition = inner.definition().clone();
        for (p, &(lo, hi)) in definition.params.params.iter_mut().zip(bounds) {
            p.lower = lo;
            p.upper = hi;
        }
        Rebounded { inner, definition }
    }
}
impl Experiment for Rebounded<'_> {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        self.inner.monte_carlo_with(theta, mc, options)
    }
}

impl crate::experiment::Structure for Rebounded<'_> {
    fn supports(&self, engine: Engine) -> bool {
        self.inner.supports(engine)
    }

    fn expected(&self, theta: &[f64], mc: &McConfig) -> Option<Accumulator> {
        self.inner.expected(theta, mc)
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.inner.target(i)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.inner.covariances(theta)
    }

    fn blocks(&self) -> Option<Vec<Block>> {
        self.inner.blocks()
    }

    fn truth_values(&self) -> Option<Vec<f64>> {
        self.inner.truth_values()
    }

    fn linear(&self) -> Option<&LinearExperiment> {
        self.inner.linear()
    }
}

impl crate::experiment::HeldAsCode for Rebounded<'_> {
    fn monte_carlo_corrected(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
        correction: &crate::filter::Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        self.inner
            .monte_carlo_corrected(theta, mc, options, correction)
    }

    fn innovation_scales(&self, theta: &[f64], mc: &McConfig) -> Option<Vec<f64>> {
        self.inner.innovation_scales(theta, mc)
    }
}

impl crate::experiment::Sampling for Rebounded<'_> {
    fn splits(&self) -> bool {
        self.inner.splits()
    }

    fn splits_runs(&self) -> bool {
        self.inner.splits_runs()
    }

    fn seed_free(&self) -> bool {
        self.inner.seed_free()
    }

    fn truth_reuse(&self, since: TapeUsage) -> TruthReuse {
        self.inner.truth_reuse(since)
    }

    fn tape_usage(&self) -> TapeUsage {
        self.inner.tape_usage()
    }
}
