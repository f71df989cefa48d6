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
