//! Nelder–Mead through argmin, charged to the [`Budget`].

use std::cell::RefCell;

use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;

use super::budget::{Budget, Exhausted};
use super::cost::Candidate;

/// The simplex stops when the standard deviation of its vertices' scores falls below this
/// under exact scoring. (argmin's default never stops; J is dimensionless and O(1) far from
/// the optimum.)
const SD_TOLERANCE: f64 = 1e-10;
/// The same under Monte Carlo scoring: J carries the search runs' noise, so polishing it
/// further buys nothing; the refinement on more runs takes over from here.
const SD_TOLERANCE_MONTE_CARLO: f64 = 1e-5;

/// Iterations per free parameter.
const ITERS_PER_DIM: usize = 200;

/// Nelder–Mead from `y0` with an initial simplex of steps `step` (log units) along each
/// axis, away from the upper bound where one is near. Returns the best vertex it found,
/// or `Exhausted` if the budget ran out before or during the search.
pub(super) fn nelder_mead(
    budget: &mut Budget<'_>,
    y0: &[f64],
    step: f64,
) -> Result<Candidate, Exhausted> {
    if budget.exhausted() {
        return Err(Exhausted);
    }
    let hi = &budget.cost().hi;
    let d = y0.len();
    let mut simplex = vec![y0.to_vec()];
    for k in 0..d {
        let mut v = y0.to_vec();
        v[k] += if v[k] + step > hi[k] { -step } else { step };
        simplex.push(v);
    }
    let tolerance = if budget.cost().exact {
        SD_TOLERANCE
    } else {
        SD_TOLERANCE_MONTE_CARLO
    };
    let solver = NelderMead::new(simplex)
        .with_sd_tolerance(tolerance)
        .expect("the tolerances are positive");
    let run = Executor::new(Charged(RefCell::new(&mut *budget)), solver)
        .configure(|s| s.max_iters((ITERS_PER_DIM * d.max(1)) as u64))
        .run();
    // argmin fails only on a cost error, and `Charged` returns none.
    let found = run.ok().map(|r| {
        let st = r.state();
        Candidate {
            point: st.get_best_param().cloned().unwrap_or_else(|| y0.to_vec()),
            cost: st.get_best_cost(),
        }
    });
    if budget.exhausted() {
        return Err(Exhausted);
    }
    Ok(found.unwrap_or(Candidate {
        point: y0.to_vec(),
        cost: f64::INFINITY,
    }))
}

/// The budget as argmin's cost function. argmin calls `cost(&self)`, hence the `RefCell`;
/// one search runs on one thread.
struct Charged<'b, 'a>(RefCell<&'b mut Budget<'a>>);

impl CostFunction for Charged<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, p: &Self::Param) -> Result<f64, argmin::core::Error> {
        // Out of budget, every point scores +∞. argmin's Nelder–Mead unwraps the costs of
        // its starting simplex, so an error here would be a panic; +∞ lets the simplex
        // finish harmlessly (each further call is refused at once), and the budget itself
        // records that it ran out, which `nelder_mead` reads afterwards. This is the only
        // place an out-of-budget evaluation becomes a number.
        Ok(self.0.borrow_mut().score(p).unwrap_or(f64::INFINITY))
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::*;
    use crate::tune::Silent;
    use crate::tune::tests::{Mock, cost};

    /// The log-points Nelder–Mead evaluates from (0, 0) with a step of 0.7 on `mock`, its
    /// first `n` evaluations (the cost's own start-up call left out).
    fn first_points(mock: &Mock, n: usize) -> Vec<Vec<f64>> {
        let cost = cost(mock, &[false; 2]);
        let skip = mock.log_points().len();
        let deadline = Instant::now() + Duration::from_secs(3600);
        let mut budget = Budget::new(&cost, n, deadline, &Silent);
        // The budget runs out on call n + 1.
        assert_eq!(nelder_mead(&mut budget, &[0.0, 0.0], 0.7), Err(Exhausted));
        mock.log_points()[skip..].to_vec()
    }

    /// Compares evaluated log-points with hand-derived ones. Tolerance 1e-12 log units:
    /// each point goes through exp and ln once (relative error ~1e-16) after a few additions.
    fn assert_points(got: &[Vec<f64>], want: &[[f64; 2]], steps: &[&str]) {
        assert_eq!(got.len(), want.len());
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            let err = (g[0] - w[0]).abs().max((g[1] - w[1]).abs());
            assert!(
                err < 1e-12,
                "evaluation {}: {} should be {w:?}, the simplex went to {g:?}",
                i + 1,
                steps[i]
            );
        }
    }

    #[test]
    fn simplex_reflects_with_coefficient_one_and_expands_with_two() {
        // J = [(−3 − y0)² + 4 (−3 − y1)²] / 2 (A = diag(1, 2), y* = (−3, −3)). The
        // vertices (0, 0), (0.7, 0), (0, 0.7) score 22.5, 24.845, 31.88. Centroid of the
        // best two c = (0.35, 0); reflection c + α (c − worst) with α = 1: (0.7, −0.7),
        // 17.425, better than the best, so expansion c + γ (x_r − c) with γ = 2:
        // (1.05, −1.4), 13.32, kept. Next: best two (1.05, −1.4), (0, 0), c = (0.525, −0.7);
        // reflection of (0.7, 0): (0.35, −1.4), 10.73, again the best: expansion
        // (0.175, −2.1), 6.66.
        let mock = Mock::new(&[(-3f64).exp(), (-3f64).exp()], &[&[1.0, 0.0], &[0.0, 2.0]]);
        let got = first_points(&mock, 7);
        assert_points(
            &got,
            &[
                [0.0, 0.0],
                [0.7, 0.0],
                [0.0, 0.7],
                [0.7, -0.7],
                [1.05, -1.4],
                [0.35, -1.4],
                [0.175, -2.1],
            ],
            &[
                "the start",
                "the first simplex step (+0.7 on axis 0)",
                "the first simplex step (+0.7 on axis 1)",
                "the reflection with coefficient α = 1",
                "the expansion with coefficient γ = 2",
                "the reflection with coefficient α = 1",
                "the expansion with coefficient γ = 2",
            ],
        );
    }

    #[test]
    fn simplex_contracts_inside_with_coefficient_one_half() {
        // J = [y0² + 4 y1²] / 2 (y* = 0): the vertices score 0, 0.245, 0.98; the reflection
        // (0.7, −0.7) scores 1.225, worse than the worst, so the inside contraction
        // c + ρ (worst − c) with ρ = 1/2: (0.175, 0.35), 0.260, kept. Next: c = (0.35, 0)
        // again, reflection of (0.175, 0.35): (0.525, −0.35), 0.383, worse than the
        // worst: contraction (0.2625, 0.175), 0.096.
        let mock = Mock::new(&[1.0, 1.0], &[&[1.0, 0.0], &[0.0, 2.0]]);
        let got = first_points(&mock, 7);
        assert_points(
            &got,
            &[
                [0.0, 0.0],
                [0.7, 0.0],
                [0.0, 0.7],
                [0.7, -0.7],
                [0.175, 0.35],
                [0.525, -0.35],
                [0.2625, 0.175],
            ],
            &[
                "the start",
                "the first simplex step (+0.7 on axis 0)",
                "the first simplex step (+0.7 on axis 1)",
                "the reflection with coefficient α = 1",
                "the inside contraction with coefficient ρ = 1/2",
                "the reflection with coefficient α = 1",
                "the inside contraction with coefficient ρ = 1/2",
            ],
        );
    }

    #[test]
    fn the_first_simplex_steps_away_from_a_near_upper_bound() {
        // The box is ±ln 1e4 = ±9.21: from (9.0, 0) a step of +0.7 on axis 0 would leave
        // it, so the first simplex steps to (8.3, 0) instead.
        let mock = Mock::new(&[1.0, 1.0], &[&[1.0, 0.0], &[0.0, 2.0]]);
        let cost = cost(&mock, &[false; 2]);
        let skip = mock.log_points().len();
        let deadline = Instant::now() + Duration::from_secs(3600);
        let mut budget = Budget::new(&cost, 3, deadline, &Silent);
        assert_eq!(nelder_mead(&mut budget, &[9.0, 0.0], 0.7), Err(Exhausted));
        assert_points(
            &mock.log_points()[skip..],
            &[[9.0, 0.0], [8.3, 0.0], [9.0, 0.7]],
            &[
                "the start",
                "the first simplex step, away from the upper bound",
                "the first simplex step (+0.7 on axis 1)",
            ],
        );
    }

    #[test]
    fn a_simplex_that_finds_no_finite_point_stops_after_200_iterations_per_parameter() {
        // Every candidate diverges (+∞), so the vertices' spread is never below the
        // tolerance and only the iteration cap stops the search. Each iteration then
        // evaluates the reflection, the inside contraction and a shrink of the d other
        // vertices: d + 1 + (d + 2) · 200 d evaluations in all, 1603 for d = 2 and 3004 for
        // d = 3.
        for (d, want) in [(2, 1603), (3, 3004)] {
            let mock = Mock::new(&vec![1.0; d], &[&vec![1.0; d]]).diverging_above(0, 0.0);
            let cost = cost(&mock, &vec![false; d]);
            let deadline = Instant::now() + Duration::from_secs(3600);
            let mut budget = Budget::new(&cost, 100_000, deadline, &Silent);
            let found = nelder_mead(&mut budget, &vec![0.0; d], 0.7).unwrap();
            assert!(found.cost.is_infinite());
            assert_eq!(
                budget.evaluations(),
                want,
                "{d} parameters: the iteration cap is {ITERS_PER_DIM} iterations per parameter"
            );
        }
    }
}
