//! Why a run stops though its filter did not fail: its numbers would mean nothing.

use crate::filter::conditioning::MAX_CONDITION;
use crate::stats::StopCause;

/// Why a run stopped though its filter did not fail: its numbers would mean nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(in crate::montecarlo) enum Fault {
    /// The truth state stopped being finite.
    TruthOverflow,
    /// The estimate of `state` (on the exact path, the truth's root mean square) is `ratio`
    /// times both its standard deviation `√P_jj` and its actual error `|e_j|` away from
    /// zero, above [`MAX_CONDITION`]: the error `x − x̂` is then formed from two numbers
    /// whose rounding (`u |x̂|`, u = 1.1e-16) exceeds 1e-4 of the error's own size, the same
    /// loss the conditioning bound allows ([`crate::filter::conditioning`]). Both scales
    /// count, so that a filter whose P is far too small (its error is then far above √P,
    /// and its NEES a true "overconfident") is not mistaken for a truth outgrowing the
    /// double format.
    Resolution {
        /// Index of the filter's state.
        state: usize,
        /// `|x̂_j| / max(√P_jj, |e_j|)` (exact path: `√E[x_j²] / max(√P_jj, √E[e_j²])`).
        ratio: f64,
    },
    /// The NEES or NIS is not finite although truth and estimate are.
    Overflow,
}

/// `ratio²` above which [`Fault::Resolution`] stops a run.
pub(in crate::montecarlo) const MAX_RATIO_SQ: f64 = MAX_CONDITION * MAX_CONDITION;

impl Fault {
    /// How the report counts a run stopped by this fault: an estimate beyond double
    /// precision means the truth it tracks is (the filter's error is within its covariance
    /// until then, or the NEES would have said so); an overflowing NEES with finite truth
    /// and estimate is a filter whose error has left its covariance.
    pub(in crate::montecarlo) fn cause(self) -> StopCause {
        match self {
            Fault::TruthOverflow | Fault::Resolution { .. } => StopCause::TruthOverflow,
            Fault::Overflow => StopCause::Diverged,
        }
    }

    /// The divergence reason for a run stopped by this fault at `step`.
    pub(in crate::montecarlo) fn reason(self, step: usize) -> String {
        match self {
            Fault::TruthOverflow => format!(
                "the truth state overflowed at step {step}: the truth model is unstable over this horizon"
            ),
            Fault::Resolution { state, ratio } => format!(
                "state {state} outgrew double precision at step {step}: it is {ratio:.1e} standard deviations from zero (above {MAX_CONDITION:.0e}), so x − x̂ keeps fewer than 4 digits; the truth model is unstable over this horizon"
            ),
            Fault::Overflow => {
                format!(
                    "the NEES or NIS overflowed at step {step}: the error is beyond 1e154 standard deviations"
                )
            }
        }
    }

    /// The first of `n` states whose estimate has outgrown double precision, given
    /// `ratio_sq(j) = x̂_j² / max(P_jj, e_j²)` (a NaN is left to the NEES check).
    pub(in crate::montecarlo) fn resolution(
        n: usize,
        ratio_sq: impl Fn(usize) -> f64,
    ) -> Option<Fault> {
        (0..n).find_map(|j| {
            let r = ratio_sq(j);
            (r > MAX_RATIO_SQ).then(|| Fault::Resolution {
                state: j,
                ratio: r.sqrt(),
            })
        })
    }
}
