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

use rand_xoshiro::SplitMix64;
use rand_xoshiro::rand_core::{RngCore, SeedableRng};

pub use super::result::{Certificate, CertifiedStart};
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

/// Whether `result` claims a misfit that needs its certificate: it failed its confirmation
/// after a converged search, or a bound stopped it after its widening.
pub fn needed(result: &TuneResult) -> bool {
    result.status == TuneStatus::Inconsistent
        || (result.status == TuneStatus::BudgetExhausted
            && result.widened.iter().any(|w| result.at_bound[w.param]))
}

/// Quasi-random points of the unit cube in `dim` dimensions (a Latin hypercube, each
/// coordinate's `k` strata shuffled by Fisher–Yates on a SplitMix64 stream of `seed`, offset
/// by a constant: the search's seed also seeds its own draws).
fn hypercube(k: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = SplitMix64::seed_from_u64(seed ^ 0x5EED_CE47_1F1C_A7E0);
    let mut next = || rng.next_u64();
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

/// How many of `scores` agree with the least finite one: within [`AGREE`] of it, relative
/// down to a floor of 0.1 (scores that small are near a fit anyway). Scores that are not
/// finite agree with none.
fn agreeing(scores: &[f64]) -> usize {
    let best = scores
        .iter()
        .copied()
        .filter(|j| j.is_finite())
        .fold(f64::INFINITY, f64::min);
    let tol = AGREE * best.abs().max(0.1);
    scores
        .iter()
        .filter(|j| j.is_finite() && (*j - best).abs() <= tol)
        .count()
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
        let r = super::stages::search(&wide, s, fixed, mc, &quiet, &Silent)?;
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
        evaluations: r.evaluations,
        refine_evaluations: r.refine_evaluations,
        seconds: r.seconds,
    };
    let certified: Vec<CertifiedStart> = starts
        .iter()
        .zip(&runs)
        .map(|(s, r)| record(s, r))
        .collect();
    let spent = Spent {
        evaluations: certified.iter().map(|c| c.evaluations).sum(),
        refine_evaluations: certified.iter().map(|c| c.refine_evaluations).sum(),
        seconds: certified.iter().map(|c| c.seconds).sum(),
    };
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
    let agreeing = agreeing(
        &runs
            .iter()
            .map(|r| r.objective_final.total)
            .collect::<Vec<_>>(),
    );
    let recheck_runs = mc.runs().saturating_mul(RECHECK);
    let recheck_mc = mc
        .with_runs(recheck_runs)?
        .with_seed(first.confirm_seed.wrapping_add(0x00C0_FFEE));
    let use_nees = settings.scores_nees(!model.state_names().is_empty());
    let report = crate::check::check(
        &wide,
        &runs[best].tuned,
        &recheck_mc,
        crate::check::Truth::from_use_nees(use_nees),
    )?;
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

/// What the certification's searches spent, all starts together.
struct Spent {
    evaluations: usize,
    refine_evaluations: usize,
    /// Wall-clock time, s.
    seconds: f64,
}

/// `r` (a start's search) as the run's result: the run's own start and its report, and the
/// evaluations (the searches' and the refinements') and time of the first search and every
/// start's.
fn fit_from(first: &TuneResult, r: &mut TuneResult, spent: Spent) -> TuneResult {
    let mut out = r.clone();
    out.initial = first.initial.clone();
    out.objective_initial = first.objective_initial;
    out.before = first.before.clone();
    out.evaluations = first.evaluations + spent.evaluations;
    out.refine_evaluations = first.refine_evaluations + spent.refine_evaluations;
    out.widened = first.widened.clone();
    out.seconds = first.seconds + spent.seconds;
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

    #[test]
    fn seeds_that_differ_in_any_one_bit_give_different_hypercubes() {
        // 8 strata in 3 dimensions: (8!)³ ≈ 6.6e13 cubes, so two seeds' cubes coincide by
        // chance with probability ~1.5e-14 per pair; 65 seeds, 2080 pairs.
        let mut seen: Vec<Vec<Vec<f64>>> = Vec::new();
        for seed in std::iter::once(0).chain((0..64).map(|b| 1u64 << b)) {
            let cube = hypercube(8, 3, seed);
            assert!(!seen.contains(&cube), "seed {seed:#x} repeats a cube");
            seen.push(cube);
        }
    }

    #[test]
    fn each_ordering_of_the_strata_is_equally_likely() {
        // Three strata in one dimension over 1200 seeds: each of the 3! orderings 200 times
        // on average, binomial SD √(1200 · 1/6 · 5/6) = 12.9; the band is ±4 SD (a uniform
        // shuffle leaves it with probability 4e-4 over the six counts). A shuffle that never
        // leaves a stratum in place (Sattolo's) gives the identity 0 times.
        let mut counts = std::collections::HashMap::new();
        for seed in 0..1200 {
            let order: Vec<usize> = hypercube(3, 1, seed)
                .iter()
                .map(|p| (p[0] * 3.0) as usize)
                .collect();
            *counts.entry(order).or_insert(0usize) += 1;
        }
        assert_eq!(counts.len(), 6, "{counts:?}");
        for (order, n) in &counts {
            assert!((148..=252).contains(n), "{order:?}: {n} of 1200");
        }
        // Each point at its stratum's middle.
        for p in hypercube(4, 2, 3).iter().flatten() {
            assert!(((p * 4.0).fract() - 0.5).abs() < 1e-12, "{p}");
        }
    }

    #[test]
    fn scores_agree_within_two_percent_of_the_best_down_to_a_floor_of_a_tenth() {
        // Best 2: within 0.04.
        assert_eq!(agreeing(&[2.03, 2.0, 2.05, f64::INFINITY, f64::NAN]), 2);
        assert_eq!(agreeing(&[2.0, 2.039, 2.02]), 3);
        // Best 0.001: the floor, within 0.002.
        assert_eq!(agreeing(&[0.0035, 0.001, 0.0025]), 2);
        assert_eq!(agreeing(&[0.5]), 1);
        assert_eq!(agreeing(&[f64::INFINITY, f64::NAN]), 0);
    }
}
