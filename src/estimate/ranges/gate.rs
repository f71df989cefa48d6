//! The gate's range: along each free parameter, how far the record still passes the gate,
//! traced by doubling outwards and then halving each end's bracket.

use serde::Serialize;

use super::{Range, RangeEnd};

/// The gate's range is traced by doubling outwards up to this factor, then halving the
/// bracket until its ends are within [`GATE_RATIO`].
const GATE_SPAN: f64 = 1e3;
/// Ratio of the ends of the gate's last bracket.
pub(super) const GATE_RATIO: f64 = 1.02;

/// The range along each free parameter (the others at the estimate) over which the record
/// passes the gate.
#[derive(Debug, Clone, Serialize)]
pub struct GateRanges {
    /// Whether the record passes at the point traced from (the estimate, or the tuned
    /// values); if not, there are no ranges.
    pub passes_at_point: bool,
    /// One per parameter, `None` for a fixed one (and for all when the estimate fails).
    pub ranges: Vec<Option<Range>>,
    /// Gate evaluations the trace took.
    pub evaluations: usize,
}

/// The range along each free parameter (the others held at `theta`, the estimate) over
/// which `passes(θ)` holds (`None` where the filter cannot run: a failure), traced by
/// doubling outwards up to a factor of 10³ and then halving each end's bracket to a ratio
/// of 1.02.
pub fn gate_ranges(
    passes: &dyn Fn(&[f64]) -> Option<bool>,
    theta: &[f64],
    fixed: &[bool],
) -> GateRanges {
    let mut evaluations = 1;
    let mut ranges = vec![None; fixed.len()];
    if passes(theta) != Some(true) {
        return GateRanges {
            passes_at_point: false,
            ranges,
            evaluations,
        };
    }
    for i in (0..fixed.len()).filter(|&i| !fixed[i]) {
        let mut end = |up: bool| {
            let f = if up { 2.0 } else { 0.5 };
            let mut ok = theta[i];
            let mut bad = None;
            // At most ten doublings (10³ is 2^9.97) and sixty halvings: bounded whatever
            // the numbers (a value that underflows to zero would never end a ratio test).
            let mut left = 70;
            while (ok / theta[i]).max(theta[i] / ok) < GATE_SPAN && left > 0 {
                left -= 1;
                let trial = ok * f;
                let mut t = theta.to_vec();
                t[i] = trial;
                evaluations += 1;
                if passes(&t) == Some(true) {
                    ok = trial;
                } else {
                    bad = Some(trial);
                    break;
                }
            }
            let Some(mut bad) = bad else {
                return RangeEnd {
                    value: ok,
                    reached: false,
                };
            };
            while (bad / ok).max(ok / bad) > GATE_RATIO && left > 0 {
                left -= 1;
                let mid = (ok * bad).sqrt();
                let mut t = theta.to_vec();
                t[i] = mid;
                evaluations += 1;
                if passes(&t) == Some(true) {
                    ok = mid;
                } else {
                    bad = mid;
                }
            }
            RangeEnd {
                value: ok,
                reached: true,
            }
        };
        let lower = end(false);
        let upper = end(true);
        ranges[i] = Some(Range { lower, upper });
    }
    GateRanges {
        passes_at_point: true,
        ranges,
        evaluations,
    }
}
