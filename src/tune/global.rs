//! The global stage: the start and a Latin hypercube of quasi-random points in the log box,
//! and the choice of the points the local searches start from.

use rand::{Rng, SeedableRng};

use super::budget::Budget;
use super::choices::LocalSearch;
use super::cost::{Candidate, max_abs_diff};
use crate::rng::SimRng;

/// Local starts closer than this in every coordinate (log units, a factor 1.65) would
/// search the same basin.
const DISTINCT: f64 = 0.5;

/// Scores `y0` and `per_dim` points per free parameter spread over the box (a Latin
/// hypercube from `seed`), in parallel if `parallel`. Returns the points with a finite
/// score, best first (ties in point order).
pub(super) fn scan(
    budget: &mut Budget<'_>,
    y0: &[f64],
    per_dim: usize,
    seed: u64,
    parallel: bool,
) -> Vec<Candidate> {
    let cost = budget.cost();
    let d = y0.len();
    let mut points: Vec<Vec<f64>> = vec![y0.to_vec()];
    points.extend(latin_hypercube(per_dim * d, d, seed).iter().map(|u| {
        u.iter()
            .enumerate()
            .map(|(k, v)| cost.lo[k] + v * (cost.hi[k] - cost.lo[k]))
            .collect()
    }));
    let scores = budget.map(&points, parallel, |b, y| b.score(y).ok());
    let mut ranked: Vec<Candidate> = points
        .into_iter()
        .zip(scores)
        .filter_map(|(point, score)| {
            score
                .filter(|j| j.is_finite())
                .map(|cost| Candidate { point, cost })
        })
        .collect();
    ranked.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    ranked
}

/// Up to `starts` mutually distinct points from `ranked`, best first; with `GaussNewton`
/// the start `y0` is always the first. Never empty.
pub(super) fn choose_starts(
    ranked: &[Candidate],
    y0: &[f64],
    method: LocalSearch,
    starts: usize,
) -> Vec<Vec<f64>> {
    // Gauss–Newton stays in the basin it starts in, and the user's start is usually a
    // better-informed guess than a quasi-random point, so it is always one of the starts.
    let mut chosen: Vec<Vec<f64>> = match method {
        LocalSearch::GaussNewton => vec![y0.to_vec()],
        LocalSearch::Simplex => Vec::new(),
    };
    for c in ranked {
        if chosen.len() >= starts {
            break;
        }
        if chosen.iter().all(|s| max_abs_diff(s, &c.point) > DISTINCT) {
            chosen.push(c.point.clone());
        }
    }
    if chosen.is_empty() {
        chosen.push(y0.to_vec());
    }
    chosen
}

/// Quasi-random points in the unit cube: a Latin hypercube from `seed` (reproducible, and
/// every parameter's range is covered evenly).
fn latin_hypercube(points: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = SimRng::seed_from_u64(seed);
    let mut out = vec![vec![0.0; dim]; points];
    for d in 0..dim {
        let mut perm: Vec<usize> = (0..points).collect();
        for i in (1..points).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            perm.swap(i, j);
        }
        for (p, row) in out.iter_mut().enumerate() {
            let jitter = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
            row[d] = (perm[p] as f64 + jitter) / points as f64;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::*;
    use crate::tune::Silent;
    use crate::tune::tests::{cost, two_basins};

    /// The global stage's scan of the two-basin mock from (0, 0), 16 points per parameter
    /// from seed 0: what it returns, and every point it scored in scan order.
    fn scanned() -> (Vec<Candidate>, Vec<Vec<f64>>, crate::tune::tests::Mock) {
        let mock = two_basins();
        let ranked = {
            let cost = cost(&mock, &[false; 2]);
            let deadline = Instant::now() + Duration::from_secs(3600);
            let mut budget = Budget::new(&cost, 1000, deadline, &Silent);
            scan(&mut budget, &[0.0, 0.0], 16, 0, false)
        };
        // The first call is the cost's own start-up evaluation.
        let points = mock.log_points()[1..].to_vec();
        (ranked, points, mock)
    }

    #[test]
    fn scan_ranks_the_best_point_first() {
        // Independent reference: the mock's own formula for J at each scanned point,
        // sorted. The scan order (the start, then the Latin hypercube) is far from ranked,
        // so a ranking that is missing or reversed fails. Tolerances: points 1e-12 log units
        // (one exp and ln), J 1e-9 relative (the objective sums the same logs in another
        // order).
        let (ranked, points, mock) = scanned();
        assert_eq!(points.len(), 33, "the start and 16 points per parameter");
        assert_eq!(ranked.len(), 33, "every point scores finite");
        // The 32 quasi-random points fill the log box [ln 1e-4, ln 1e4]² as a Latin
        // hypercube: one point in each 32nd of each axis.
        let (lo, hi) = (1e-4f64.ln(), 1e4f64.ln());
        for k in 0..2 {
            let mut slices: Vec<usize> = points[1..]
                .iter()
                .map(|y| ((y[k] - lo) / (hi - lo) * 32.0).floor() as usize)
                .collect();
            slices.sort_unstable();
            assert_eq!(
                slices,
                (0..32).collect::<Vec<_>>(),
                "axis {k}: the scan's points map the unit cube onto the box"
            );
        }
        let j = |y: &[f64]| mock.j(&y.iter().map(|v| v.exp()).collect::<Vec<_>>());
        let mut by_formula: Vec<(f64, &Vec<f64>)> = points.iter().map(|y| (j(y), y)).collect();
        assert!(
            by_formula.windows(2).any(|w| w[0].0 > w[1].0),
            "the scan order must not be ranked already, or the test could not fail"
        );
        by_formula.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (i, (c, (want_j, want_y))) in ranked.iter().zip(&by_formula).enumerate() {
            assert!(
                max_abs_diff(&c.point, want_y) < 1e-12 && (c.cost - want_j).abs() <= 1e-9 * want_j,
                "ranking: place {i} should hold the {}-th best point {want_y:?} (J = {want_j:.4e}), \
                 not {:?} (J = {:.4e}); the first is the best, the last the worst",
                i + 1,
                c.point,
                c.cost
            );
        }
    }

    #[test]
    fn the_global_stage_starts_from_the_best_distinct_points_of_the_scan() {
        // The scan's points come unranked from the Latin hypercube; the local starts must be
        // the best of them by the mock's formula, mutually more than DISTINCT apart, and the
        // best lies in the deep basin (left of the ridge at y0 = −1).
        let (ranked, points, mock) = scanned();
        let j = |y: &[f64]| mock.j(&y.iter().map(|v| v.exp()).collect::<Vec<_>>());
        let mut want: Vec<Vec<f64>> = Vec::new();
        let mut order: Vec<&Vec<f64>> = points.iter().collect();
        order.sort_by(|a, b| j(a).total_cmp(&j(b)));
        for y in order {
            if want.len() < 3 && want.iter().all(|w| max_abs_diff(w, y) > DISTINCT) {
                want.push(y.clone());
            }
        }
        let starts = choose_starts(&ranked, &[0.0, 0.0], LocalSearch::Simplex, 3);
        assert_eq!(starts.len(), 3);
        for (i, (s, w)) in starts.iter().zip(&want).enumerate() {
            assert!(
                max_abs_diff(s, w) < 1e-12,
                "start {i}: {s:?}, but the {}-th best distinct point is {w:?} (ranking: best first)",
                i + 1
            );
        }
        assert!(
            starts[0][0] < -1.0,
            "the best start {:?} should be in the deep basin",
            starts[0]
        );
        let gn = choose_starts(&ranked, &[0.0, 0.0], LocalSearch::GaussNewton, 3);
        assert_eq!(
            gn[0],
            vec![0.0, 0.0],
            "Gauss–Newton keeps the user's start first"
        );
        assert!(
            max_abs_diff(&gn[1], &want[0]) < 1e-12,
            "then the best point: {gn:?}"
        );
    }

    #[test]
    fn latin_hypercube_puts_one_point_in_each_slice_of_every_axis() {
        let (n, dim) = (16, 3);
        let pts = latin_hypercube(n, dim, 7);
        for d in 0..dim {
            let mut slices: Vec<usize> = pts.iter().map(|p| (p[d] * n as f64) as usize).collect();
            slices.sort_unstable();
            assert_eq!(slices, (0..n).collect::<Vec<_>>(), "axis {d}");
        }
        assert_eq!(pts, latin_hypercube(n, dim, 7), "same seed, same points");
    }

    #[test]
    fn starts_are_distinct_and_gauss_newton_keeps_the_start() {
        let c = |x: f64, cost: f64| Candidate {
            point: vec![x],
            cost,
        };
        // 0.3 is within DISTINCT of 0.0, so it is passed over.
        let ranked = [c(0.0, 1.0), c(0.3, 2.0), c(2.0, 3.0), c(4.0, 4.0)];
        let simplex = choose_starts(&ranked, &[9.0], LocalSearch::Simplex, 2);
        assert_eq!(simplex, vec![vec![0.0], vec![2.0]]);
        let gn = choose_starts(&ranked, &[9.0], LocalSearch::GaussNewton, 2);
        assert_eq!(gn, vec![vec![9.0], vec![0.0]]);
        assert_eq!(
            choose_starts(&[], &[9.0], LocalSearch::Simplex, 3),
            vec![vec![9.0]]
        );
    }
}
