//! Before "no value of the free parameters fits" is claimed, it is proven (issue 38): one
//! search that ends with a filter failing its confirmation may have stopped in a local
//! minimum, or on a bound the data want beyond.
//!
//! The certification searches the box widened [`WIDEN`]-fold on every side of every free
//! parameter (a parameter at a bound is then inside), from [`STARTS`] points: the search's
//! own result and points spread over the widened box (a Latin hypercube in log space, from
//! the search's seed). Each start runs an independent search with the same settings.
//! - A start whose tuned filter passes its confirmation ends the matter: the filter fits,
//!   the first search had missed it, and that result is the run's ([`TuneStatus::Consistent`]).
//! - Otherwise the misfit is claimed ([`TuneStatus::Inconsistent`]) only when at least two
//!   starts agree on the best score (so the best is not one search's accident), and the
//!   best point fails the gate again on [`RECHECK`] times the runs, on a fresh seed (so the
//!   failure is not Monte Carlo noise at N runs; an inconclusive recheck is no failure). Else the run is
//!   [`TuneStatus::Undecided`], and the certificate says which condition failed.

use serde::Serialize;

use super::{Silent, TuneError, TuneResult, TuneSettings, TuneStatus};
use crate::experiment::{Experiment, Rebounded};
use crate::montecarlo::McConfig;

/// How far each free parameter's bounds are widened, as a factor on each side.
pub const WIDEN: f64 = 100.0;
/// Searches from different starts, the first search's result among them.
pub const STARTS: usize = 4;
/// The recheck's runs, in multiples of the confirmation's N.
pub const RECHECK: usize = 4;
/// Scores within this fraction of the best (and of 0.1, for a best near 0) agree.
const AGREE: f64 = 0.02;

/// One start's search in the widened box.
#[derive(Debug, Clone, Serialize)]
pub struct CertifiedStart {
    /// The start (problem order).
    pub start: Vec<f64>,
    /// Where its search ended.
    pub tuned: Vec<f64>,
    /// The objective there.
    pub score: f64,
    /// Fresh seeds its tuned filter passed, of those tried.
    pub passed: usize,
    /// Fresh seeds tried.
    pub seeds: usize,
    /// How its search ended.
    pub status: TuneStatus,
}

/// What the certification of a misfit found.
#[derive(Debug, Clone, Serialize)]
pub struct Certificate {
    /// The widened box, (lower, upper) per parameter (fixed ones as they were).
    pub bounds: Vec<(f64, f64)>,
    /// Each start's search, the first search's result first.
    pub starts: Vec<CertifiedStart>,
    /// Starts whose score agrees with the best one's.
    pub agreeing: usize,
    /// Runs of the recheck at the best point.
    pub recheck_runs: usize,
    /// Whether the best point passed the gate on the recheck (a misfit at the limit of N
    /// runs); `None` when no recheck ran (a start fit).
    pub recheck_passed: Option<bool>,
    /// Whether the misfit is proven.
    pub proven: bool,
}

/// Whether `result` claims a misfit that needs its certificate: it failed its confirmation
/// after a converged search, or a bound stopped it after its widening.
pub fn needed(result: &TuneResult) -> bool {
    result.status == TuneStatus::Inconsistent
        || (result.status == TuneStatus::BudgetExhausted
            && result.widened.iter().any(|w| result.at_bound[w.param]))
}

/// Quasi-random points of the unit cube in `dim` dimensions (a Latin hypercube, each
/// coordinate's `k` strata shuffled by a splitmix stream of `seed`).
fn hypercube(k: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut state = seed ^ 0x5EED_CE47_1F1C_A7E0;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let mut cols: Vec<Vec<usize>> = (0..dim)
        .map(|_| {
            let mut v: Vec<usize> = (0..k).collect();
            for i in (1..k).rev() {
                v.swap(i, (next() % (i as u64 + 1)) as usize);
            }
            v
        })
        .collect();
    (0..k)
        .map(|i| {
            cols.iter_mut()
                .map(|c| (c[i] as f64 + 0.5) / k as f64)
                .collect()
        })
        .collect()
}

/// Certify `first` (a run of [`super::tune`] on `model` that [`needed`] it):
/// the run's result with its [`Certificate`], which is a consistent result from another
/// start where one fit.
pub fn certify(
    model: &dyn Experiment,
    fixed: &[bool],
    mc: &McConfig,
    settings: &TuneSettings,
    first: TuneResult,
) -> Result<TuneResult, TuneError> {
    let params = &model.params().params;
    let bounds: Vec<(f64, f64)> = params
        .iter()
        .zip(fixed)
        .map(|(p, &f)| {
            if f {
                (p.lower, p.upper)
            } else {
                (p.lower / WIDEN, p.upper * WIDEN)
            }
        })
        .collect();
    let wide = Rebounded::new(model, &bounds);
    let quiet = settings
        .clone()
        .with_certify(false)
        .with_confirm_seed(Some(first.confirm_seed));
    let free: Vec<usize> = (0..fixed.len()).filter(|&i| !fixed[i]).collect();
    let mut starts = vec![first.tuned.clone()];
    for u in hypercube(STARTS - 1, free.len(), first.search_seed) {
        let mut s = first.tuned.clone();
        for (&i, x) in free.iter().zip(u) {
            let (lo, hi) = (bounds[i].0.ln(), bounds[i].1.ln());
            s[i] = (lo + x * (hi - lo)).exp();
        }
        starts.push(s);
    }
    let mut runs: Vec<TuneResult> = Vec::with_capacity(STARTS);
    for s in &starts {
        let r = super::tune(&wide, s, fixed, mc, &quiet, &Silent)?;
        // A filter that passes its confirmation fits, whether or not its search had
        // converged when its budget ran out.
        let fits = r.confirmation.holds();
        runs.push(r);
        if fits {
            break;
        }
    }
    let record = |s: &[f64], r: &TuneResult| CertifiedStart {
        start: s.to_vec(),
        tuned: r.tuned.clone(),
        score: r.objective_final.total,
        passed: r.confirmation.passed,
        seeds: r.confirmation.seeds,
        status: r.status,
    };
    let certified: Vec<CertifiedStart> = starts
        .iter()
        .zip(&runs)
        .map(|(s, r)| record(s, r))
        .collect();
    let spent: usize = runs
        .iter()
        .map(|r| r.evaluations + r.refine_evaluations)
        .sum();
    if let Some(k) = runs.iter().position(|r| r.confirmation.holds()) {
        let mut fit = runs.swap_remove(k);
        let certificate = Certificate {
            bounds,
            starts: certified,
            agreeing: 0,
            recheck_runs: 0,
            recheck_passed: None,
            proven: false,
        };
        return Ok(adopt(fit_from(&first, &mut fit, spent), certificate));
    }
    let best = runs
        .iter()
        .enumerate()
        .filter(|(_, r)| r.objective_final.total.is_finite())
        .min_by(|a, b| {
            a.1.objective_final
                .total
                .total_cmp(&b.1.objective_final.total)
        })
        .map(|(k, _)| k)
        .unwrap_or(0);
    let j_best = runs[best].objective_final.total;
    // Relative, down to a floor of 0.1 (scores that small are near a fit anyway).
    let tol = AGREE * j_best.abs().max(0.1);
    let agreeing = runs
        .iter()
        .filter(|r| {
            r.objective_final.total.is_finite() && (r.objective_final.total - j_best).abs() <= tol
        })
        .count();
    let recheck_runs = mc.runs().saturating_mul(RECHECK);
    let recheck_mc = mc
        .with_runs(recheck_runs)?
        .with_seed(first.confirm_seed.wrapping_add(0x00C0_FFEE));
    let use_nees = !settings.nis_only() && !model.state_names().is_empty();
    let report = crate::check::check(&wide, &runs[best].tuned, &recheck_mc, use_nees)?;
    let recheck_passed = report.verdict.passes();
    // An inconclusive recheck is no failure.
    let recheck_failed = !recheck_passed && report.verdict != crate::stats::Verdict::Inconclusive;
    let proven = agreeing >= 2 && recheck_failed;
    let certificate = Certificate {
        bounds,
        starts: certified,
        agreeing,
        recheck_runs,
        recheck_passed: Some(recheck_passed),
        proven,
    };
    let mut out = runs.swap_remove(best);
    let mut out = fit_from(&first, &mut out, spent);
    out.status = if proven {
        TuneStatus::Inconsistent
    } else {
        TuneStatus::Undecided
    };
    Ok(adopt(out, certificate))
}

/// `r` (a start's search) as the run's result: the run's own start and its report, and the
/// evaluations of every search.
fn fit_from(first: &TuneResult, r: &mut TuneResult, spent: usize) -> TuneResult {
    let mut out = r.clone();
    out.initial = first.initial.clone();
    out.objective_initial = first.objective_initial;
    out.before = first.before.clone();
    out.evaluations = first.evaluations + spent;
    out.widened = first.widened.clone();
    out.seconds += first.seconds;
    out
}

fn adopt(mut r: TuneResult, c: Certificate) -> TuneResult {
    r.certificate = Some(c);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hypercube_fills_each_stratum_once() {
        let pts = hypercube(5, 3, 7);
        assert_eq!(pts.len(), 5);
        for d in 0..3 {
            let mut strata: Vec<usize> = pts.iter().map(|p| (p[d] * 5.0) as usize).collect();
            strata.sort();
            assert_eq!(strata, vec![0, 1, 2, 3, 4]);
        }
        assert_ne!(hypercube(5, 3, 7), hypercube(5, 3, 8));
    }
}
