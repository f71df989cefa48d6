//! What the experiments whose filter is held as code share (a catalog model, a Rust user's
//! model): a truth and the cache of its runs, through which a filter built at θ runs the
//! generic engine, reads through a correction, gives its innovations' scales, and says how
//! the truth's runs were reused.

use super::definition::TruthReuse;
use crate::filter::{Corrected, Correction, Filter};
use crate::model::TruthModel;
use crate::montecarlo::{self, McConfig, RunOptions, TapeUsage, TruthCache};
use crate::stats::Accumulator;

use super::error::ExperimentError;

/// A truth, and the truth runs of seed sets evaluated more than once (the truth of a
/// filter held as code does not depend on θ: the parameters are the filter's).
pub(super) struct Held<'a, T: ?Sized> {
    /// The truth the filters are tested against.
    pub truth: &'a T,
    /// Its runs, kept between evaluations.
    pub cache: &'a TruthCache,
}

impl<T: TruthModel + ?Sized> Held<'_, T> {
    /// The Monte Carlo sums of `filter` (built at θ) against the truth.
    pub(super) fn monte_carlo<F: Filter + ?Sized>(
        &self,
        filter: &F,
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        Ok(montecarlo::run_generic_cached(
            self.truth, filter, mc, run, self.cache,
        ))
    }

    /// The sums of `filter` reading its measurements through `correction`, where the
    /// filter can be read through it.
    pub(super) fn corrected<F: Filter + ?Sized>(
        &self,
        filter: &F,
        mc: &McConfig,
        run: RunOptions<'_>,
        correction: &Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        let read = Corrected::new(filter, correction)?;
        Some(self.monte_carlo(&read, mc, run))
    }

    /// The scale of each measurement component's innovations under `filter`.
    pub(super) fn innovation_scales<F: Filter + ?Sized>(
        &self,
        filter: &F,
        mc: &McConfig,
    ) -> Option<Vec<f64>> {
        montecarlo::innovation_scales(self.truth, filter, mc)
    }

    /// How the truth's runs were reused since `since`.
    pub(super) fn truth_reuse(&self, since: TapeUsage) -> TruthReuse {
        TruthReuse::taped(self.cache, since)
    }

    /// The cache's usage so far.
    pub(super) fn tape_usage(&self) -> TapeUsage {
        self.cache.usage()
    }
}
