//! What a search is set up with: the confirmation's seed, whether it scores exactly, which
//! values lie at a bound of its box.

use super::cost::Cost;
use super::{Scoring, TuneError};
use crate::experiment::Experiment;
use crate::input::SettingError;
use crate::montecarlo::McConfig;

/// The seed of the confirmation runs when none is given: a fixed mix of the search seed,
/// never equal to it.
pub fn default_confirm_seed(seed: u64) -> u64 {
    // Flipping bits 0 and 40 changes the seed and keeps it below 2^63 when it was (TOML
    // files store seeds as signed 64-bit integers).
    seed ^ 0x0000_0100_0000_0001
}

/// Whether the search scores exactly: asked for, or chosen by `Auto` where the experiment
/// has exact sums.
pub(super) fn exact_scoring(
    model: &dyn Experiment,
    start: &[f64],
    mc: &McConfig,
    scoring: Scoring,
) -> Result<bool, TuneError> {
    let probe = McConfig::new(1, 1)?.with_seed(mc.seed());
    let available = model.expected(start, &probe).is_some();
    match scoring {
        Scoring::Auto => Ok(available),
        Scoring::Exact if !available => Err(SettingError::new(
            "scoring",
            "exact scoring needs a linear problem (its truth's and filter's matrices)",
        )
        .into()),
        Scoring::Exact => Ok(true),
        Scoring::MonteCarlo => Ok(false),
    }
}

/// Per parameter (problem order), whether `theta`'s value lies within 0.05 log units (5%)
/// of a bound of `cost`'s box; false for fixed parameters.
pub(super) fn bound_flags(cost: &Cost<'_>, theta: &[f64], fixed: &[bool]) -> Vec<bool> {
    let y: Vec<f64> = cost.free().iter().map(|&i| theta[i].ln()).collect();
    let mut flags = vec![false; fixed.len()];
    for (k, &i) in cost.free().iter().enumerate() {
        flags[i] = y[k].is_finite() && cost.near_bound(k, &y);
    }
    flags
}
