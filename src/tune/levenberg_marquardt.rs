//! Levenberg–Marquardt on a residual vector in log-parameters: J's own residuals, or the
//! moment equations (one per free parameter).
//!
//! J is a sum of squared log-ratios that are close to linear in the log-parameters, so
//! Gauss–Newton steps converge in a handful of iterations where a simplex in 6 dimensions
//! wanders along the valleys that partly interchangeable parameters make. The Jacobian is
//! a forward difference (step 0.05, i.e. 5%; central in a deep fit under exact scoring), the damping Marquardt's diagonal scaling,
//! and steps are projected into the box. Each iteration costs d + 1 evaluations or a few
//! more.

use nalgebra::{DMatrix, DVector};

use super::budget::{Budget, Exhausted};
use super::cost::Evaluation;
use super::cost::{Candidate, Cost, max_abs_diff};
use crate::params::{NoiseKind, Target};
use crate::stats::Accumulator;

/// Forward-difference step of the Jacobian, log units.
const H: f64 = 0.05;
/// Largest step of one iteration in any parameter, log units (a factor e²).
const MAX_STEP: f64 = 2.0;
const MAX_ITERS: usize = 40;
/// Damping increases before an iteration gives up.
const MAX_TRIALS: usize = 12;

/// The residual vector Levenberg–Marquardt drives to zero.
#[derive(Debug, Clone, Copy)]
pub(super) enum Equations<'t> {
    /// J's residuals ([`super::Objective::residuals`]).
    Objective,
    /// The moment equations of each free parameter's target components ([`moments`]).
    Moments(&'t [Target]),
}

/// Largest norm of the moment residuals (each a mean log-ratio of e²/P or ν²/S over a
/// parameter's own components) at which the moment equations count as solved: 5%, many
/// times their Monte Carlo noise at the catalog's search runs and far below any misfit
/// worth a global scan.
pub(super) const MATCHED: f64 = 0.05;

/// J at or below which a point scores as a consistent filter does, so that no other basin
/// can score meaningfully better: the catalog's consistent optima score 3e-4 to 3e-3 at
/// their search runs, the two-basin mock's shallow basin 0.08.
pub(super) const CONSISTENT_J: f64 = 0.01;

impl Equations<'_> {
    /// The sum of squares at or below which, under Monte Carlo scoring, the equations hold
    /// to within the noise of one evaluation: the moment equations solved ([`MATCHED`]), J
    /// at a consistent filter's score ([`CONSISTENT_J`]).
    fn noise_floor(self) -> f64 {
        match self {
            Equations::Moments(_) => MATCHED * MATCHED,
            Equations::Objective => CONSISTENT_J,
        }
    }
}

/// When Levenberg–Marquardt under Monte Carlo scoring has nothing left to gain. Its
/// residuals are those of a fixed set of runs (common random numbers), smooth in the
/// parameters, so it could drive them to rounding; but once they are at the noise floor
/// ([`Equations::noise_floor`]) what it would fit is those runs' noise, one full
/// evaluation a step, and the precision left to gain is the refinement's, on more runs
/// ([`super::refine`]). So it stops at a tenth of the floor, and on the floor at the
/// first step that fails to lower the sum (rather than damping it further or differencing
/// afresh) or gains less than a tenth of the floor. Exact scoring has no noise and
/// converges to the step and gain tolerances alone.
///
/// A search asked for a score below a given one (a hypothesis trial's `stop_below`) wants
/// the fit as deep as it goes, as exact scoring does: no floor, and a short step that
/// still halves the sum is not the end. Its residuals can be quadratic at the optimum (a
/// misalignment's angle moves e²/P by its square), where each step halves the error and
/// the sum falls 16-fold: stopped at the first step under 1e-3, a misaligned sensor's
/// angle ended 0.001 rad off, which 11 of 12 fresh seeds' gates see. Under exact scoring,
/// where an evaluation is cheap, a deep fit is *sharp*: along a valley such residuals make
/// with the gains, a step under 1e-3 still gained several percent of the sum, and stopping
/// at the first such step ended a fit at J 4e-3 (J 1e-6 at the truth), so there only the
/// gain ends it, after a fresh Jacobian, differenced on both sides.
#[derive(Debug, Clone, Copy)]
struct Settle {
    /// The noise floor of the sum; 0 under exact scoring or where a deep fit is asked.
    floor: f64,
    /// A score to get below was asked for.
    deep: bool,
    /// A deep fit under exact scoring.
    sharp: bool,
}

impl Settle {
    fn new(exact: bool, equations: Equations<'_>, deep: bool) -> Self {
        Settle {
            floor: if exact || deep {
                0.0
            } else {
                equations.noise_floor()
            },
            deep,
            sharp: deep && exact,
        }
    }

    /// A step of log-size `moved` that took the sum from `before` to `after` ends the
    /// search: it moved less than 1e-3 (unless, in a deep fit, it halved the sum; never in
    /// a sharp one), or it gained less than 1e-4 of the sum.
    fn converged(self, moved: f64, before: f64, after: f64) -> bool {
        let halved = after <= 0.5 * before;
        let short = moved < 1e-3 && !self.sharp && !(self.deep && halved);
        short || before - after < 1e-4 * after + 1e-12
    }

    /// What follows a step that `converged` ([`Settle::converged`]) from a Jacobian that
    /// was `fresh` (differenced, not updated). A sharp fit's converged step on an updated
    /// Jacobian says the update has gone stale, not that the fit is done (measured: a
    /// misalignment's fit stopped at J 4e-3 on such a step; a fresh Jacobian went on):
    /// there only a fresh one's ends it.
    fn next(self, converged: bool, fresh: bool) -> Next {
        match (converged, self.sharp && !fresh) {
            (false, _) => Next::Go,
            (true, true) => Next::Refresh,
            (true, false) => Next::Stop,
        }
    }

    /// The sum is on the noise floor.
    fn settled(self, sum: f64) -> bool {
        sum <= self.floor
    }

    /// The sum is below a tenth of the floor, or a step on the floor gained less.
    fn done(self, sum: f64, gain: f64) -> bool {
        let tenth = 0.1 * self.floor;
        sum <= tenth || (self.settled(sum) && gain < tenth)
    }
}

/// What Levenberg–Marquardt does after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Next {
    /// Go on from the updated Jacobian.
    Go,
    /// Difference the Jacobian afresh, then go on.
    Refresh,
    /// The search has converged.
    Stop,
}

/// What one evaluation gives Levenberg–Marquardt: the residuals of its equations and J's
/// own residuals, `None` when the filter diverged.
type Residuals = Option<(Vec<f64>, Vec<f64>)>;

/// Charged evaluation of `equations` at `y` (inside the box): their residuals and J's.
/// The budget books J (the sum of J's squared residuals) whichever equations are solved,
/// so the best point is always judged by J.
fn evaluate(
    budget: &mut Budget<'_>,
    y: &[f64],
    equations: Equations<'_>,
) -> Result<Residuals, Exhausted> {
    budget.evaluate(y, |cost: &Cost<'_>, y: &[f64]| {
        let acc = cost.accumulate(&cost.theta(y));
        let r = cost.objective.residuals(&acc);
        let j = r
            .as_ref()
            .map_or(f64::INFINITY, |r| r.iter().map(|v| v * v).sum());
        let value = match equations {
            Equations::Objective => r.map(|r| (r.clone(), r)),
            Equations::Moments(targets) => r.map(|r| (moments(targets, &acc), r)),
        };
        Evaluation {
            j,
            diverged: acc.diverged_runs > 0,
            value,
        }
    })
}

/// Charged evaluation of `equations` at `y` (inside the box); `None` when the filter
/// diverged.
fn residuals(
    budget: &mut Budget<'_>,
    y: &[f64],
    equations: Equations<'_>,
) -> Result<Option<Vec<f64>>, Exhausted> {
    Ok(evaluate(budget, y, equations)?.map(|(r, _)| r))
}

/// The moment equations: for each free parameter, the mean over the components it
/// drives of ln(e_j²/P_jj) (process noise) or ln(ν_j²/S_jj) (measurement noise), zero
/// when those components are consistent on average. One equation per parameter, each
/// moved mostly by its own parameter, so unlike J's many residuals they have no
/// compromise minimum where one parameter stands in for another (a large bias random
/// walk in place of white accelerometer noise, say).
pub(super) fn moments(targets: &[Target], acc: &Accumulator) -> Vec<f64> {
    targets
        .iter()
        .map(|Target { kind, components }| {
            let (total, samples) = match kind {
                NoiseKind::Process => (&acc.state_comp_total, &acc.state_comp_samples),
                NoiseKind::Measurement => (&acc.meas_comp_total, &acc.meas_comp_samples),
            };
            let logs: Vec<f64> = components
                .iter()
                .filter(|&&j| samples.get(j).is_some_and(|&s| s > 0.0))
                .map(|&j| (total[j] / samples[j]).ln())
                .collect();
            if logs.is_empty() {
                0.0
            } else {
                logs.iter().sum::<f64>() / logs.len() as f64
            }
        })
        .collect()
}

fn sum_sq(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Where Levenberg–Marquardt stopped.
#[derive(Debug, Clone)]
pub(super) struct Solved {
    /// The point, with the sum of squares of the equations there (+∞ if the start
    /// diverged).
    pub(super) found: Candidate,
    /// J's residuals at the point (`None` if it diverged), so that a search on J from here
    /// need not evaluate it again.
    pub(super) objective: Option<Vec<f64>>,
}

impl Solved {
    /// J at the point (+∞ if it diverged).
    pub(super) fn j(&self) -> f64 {
        self.objective.as_deref().map_or(f64::INFINITY, sum_sq)
    }
}

/// Levenberg–Marquardt on `equations` from `y0`, whose J residuals are `known` when an
/// earlier search ended there (J's equations then cost no evaluation to start).
///
/// The Jacobian is a forward difference at the start; after each accepted step it takes
/// Broyden's rank-one update from the step and the residuals' change (one evaluation an
/// iteration instead of d + 1: the residuals are close to linear in the log-parameters, so
/// the updated Jacobian stays close to the true one). Only when the updated Jacobian gives
/// no step that lowers the sum is it differenced afresh; a fresh Jacobian that gives none
/// ends the search. Under Monte Carlo scoring it ends at the noise floor ([`Settle`]).
pub(super) fn levenberg_marquardt(
    budget: &mut Budget<'_>,
    y0: &[f64],
    known: Option<&[f64]>,
    equations: Equations<'_>,
) -> Result<Solved, Exhausted> {
    let cost = budget.cost();
    let settle = Settle::new(cost.exact, equations, cost.stop_below > 0.0);
    let mut y = cost.clamp(y0);
    let start = match (known, equations) {
        (Some(r), Equations::Objective) if y == y0 => Some((r.to_vec(), r.to_vec())),
        _ => evaluate(budget, &y, equations)?,
    };
    let Some((mut r, mut objective)) = start else {
        return Ok(Solved {
            found: Candidate {
                point: y,
                cost: f64::INFINITY,
            },
            objective: None,
        });
    };
    let mut j = sum_sq(&r);
    if settle.done(j, f64::INFINITY) {
        return Ok(Solved {
            found: Candidate { point: y, cost: j },
            objective: Some(objective),
        });
    }
    let mut lambda = 1e-3;
    let mut jac = difference(budget, &y, &r, equations, settle.sharp)?;
    let mut fresh = true;
    for _ in 0..MAX_ITERS {
        let before = lambda;
        let trials = if settle.settled(j) { 1 } else { MAX_TRIALS };
        let step = damped_step(budget, &jac, &y, &r, &mut lambda, trials, equations)?;
        let Some((trial, rt, ot)) = step else {
            if fresh {
                break;
            }
            if settle.settled(j) {
                break;
            }
            // The damping rose for the stale Jacobian's sake; the fresh one starts where
            // the last accepted step left it.
            lambda = before;
            jac = difference(budget, &y, &r, equations, settle.sharp)?;
            fresh = true;
            continue;
        };
        broyden(&mut jac, &trial, &y, &rt, &r);
        let moved = max_abs_diff(&trial, &y);
        let j_new = sum_sq(&rt);
        let gain = j - j_new;
        let next = settle.next(settle.converged(moved, j, j_new), fresh);
        fresh = false;
        y = trial;
        r = rt;
        objective = ot;
        j = j_new;
        match next {
            Next::Stop => break,
            Next::Refresh => {
                jac = difference(budget, &y, &r, equations, settle.sharp)?;
                fresh = true;
                continue;
            }
            Next::Go => {}
        }
        if settle.done(j, gain) {
            break;
        }
    }
    Ok(Solved {
        found: Candidate { point: y, cost: j },
        objective: Some(objective),
    })
}

/// The forward-difference Jacobian of `equations` at `y` (residuals `r`), m × d; a column
/// whose neighbours both diverge stays zero. `central` differences both sides where the box
/// allows: a deep fit's residuals can be quadratic at its optimum (a misalignment's angle),
/// where a forward difference of 0.05 sees the slope 0.025 away, many times the slope
/// there, and the Gauss–Newton steps shrink to nothing 0.001 rad short (measured: its
/// fresh seeds' gates pass 7 of 12 there, 12 of 12 at the truth).
fn difference(
    budget: &mut Budget<'_>,
    y: &[f64],
    r: &[f64],
    equations: Equations<'_>,
    central: bool,
) -> Result<DMatrix<f64>, Exhausted> {
    let (m, d) = (r.len(), y.len());
    let (lo, hi) = (budget.cost().lo.clone(), budget.cost().hi.clone());
    let mut jac = DMatrix::<f64>::zeros(m, d);
    for k in 0..d {
        let mut neighbour = |step: f64| {
            let mut v = y.to_vec();
            v[k] += step;
            residuals(budget, &v, equations)
        };
        let both = central && y[k] - H >= lo[k] && y[k] + H <= hi[k];
        let step = if y[k] + H > hi[k] { -H } else { H };
        let (col, step) = match neighbour(step)? {
            Some(rk) if both => match neighbour(-step)? {
                Some(rl) => {
                    let d: Vec<f64> = rk.iter().zip(&rl).map(|(a, b)| a - b).collect();
                    (d, 2.0 * step)
                }
                _ => (rk.iter().zip(r).map(|(a, b)| a - b).collect(), step),
            },
            Some(rk) => (rk.iter().zip(r).map(|(a, b)| a - b).collect(), step),
            // A diverging neighbour: difference on the other side.
            None => match neighbour(-step)? {
                Some(rk) => (rk.iter().zip(r).map(|(a, b)| b - a).collect(), step),
                None => continue,
            },
        };
        if col.len() == m {
            for i in 0..m {
                jac[(i, k)] = col[i] / step;
            }
        }
    }
    Ok(jac)
}

/// Broyden's rank-one update of `jac` after the step from `y` (residuals `r`) to `trial`
/// (residuals `rt`): the least change that makes `jac` map the step onto the change.
fn broyden(jac: &mut DMatrix<f64>, trial: &[f64], y: &[f64], rt: &[f64], r: &[f64]) {
    let s = DVector::from_iterator(y.len(), trial.iter().zip(y).map(|(a, b)| a - b));
    let ss = s.norm_squared();
    if ss == 0.0 {
        return;
    }
    let dr = DVector::from_iterator(r.len(), rt.iter().zip(r).map(|(a, b)| a - b));
    let miss = dr - &*jac * &s;
    *jac += miss * s.transpose() / ss;
}

/// Marquardt's scale of the damping in parameter k: JᵀJ's own diagonal entry, floored at
/// 1e-9 of the largest so that a parameter the residuals barely see is still damped.
fn marquardt_scale(a_kk: f64, diag_max: f64) -> f64 {
    a_kk.max(1e-9 * diag_max)
}

/// An accepted step: the new point, its residuals and J's.
type Step = (Vec<f64>, Vec<f64>, Vec<f64>);

/// A damped Gauss–Newton step from `y` on `jac` that lowers the sum of squares, raising
/// the damping `lambda` until one does (at most `trials` times) and lowering it after;
/// `None` when none does.
fn damped_step(
    budget: &mut Budget<'_>,
    jac: &DMatrix<f64>,
    y: &[f64],
    r: &[f64],
    lambda: &mut f64,
    trials: usize,
    equations: Equations<'_>,
) -> Result<Option<Step>, Exhausted> {
    let d = y.len();
    let rv = DVector::from_column_slice(r);
    let g = jac.tr_mul(&rv);
    let a = jac.tr_mul(jac);
    let diag_max = (0..d).map(|k| a[(k, k)]).fold(0.0_f64, f64::max);
    if diag_max <= 0.0 {
        return Ok(None);
    }
    let j = sum_sq(r);
    for _ in 0..trials {
        let mut lhs = a.clone();
        for k in 0..d {
            lhs[(k, k)] += *lambda * marquardt_scale(a[(k, k)], diag_max);
        }
        // JᵀJ plus a positive diagonal is positive definite: a factorization that fails
        // anyway has lost its digits, and no step from it can be trusted.
        let Some(chol) = lhs.cholesky() else {
            return Ok(None);
        };
        let mut delta = chol.solve(&(-&g));
        let big = delta.amax();
        if big > MAX_STEP {
            delta *= MAX_STEP / big;
        }
        let trial = budget.cost().clamp(
            &y.iter()
                .zip(delta.iter())
                .map(|(a, b)| a + b)
                .collect::<Vec<_>>(),
        );
        match evaluate(budget, &trial, equations)? {
            Some((rt, ot)) if rt.len() == r.len() && sum_sq(&rt) < j => {
                *lambda = (*lambda / 3.0).max(1e-9);
                return Ok(Some((trial, rt, ot)));
            }
            _ => *lambda *= 4.0,
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::*;
    use crate::tune::Silent;
    use crate::tune::tests::{Mock, cost};

    #[test]
    fn moment_equations_average_the_log_ratios_of_each_parameters_own_components() {
        let e = f64::exp;
        let mut acc = Accumulator::new(1, 3, 2, 0);
        // Mean e²/P of e, e², and a component with no samples; mean ν²/S of 1/e, 1/e².
        acc.state_comp_total = vec![10.0 * e(1.0), 10.0 * e(2.0), 7.0];
        acc.state_comp_samples = vec![10.0, 10.0, 0.0];
        acc.meas_comp_total = vec![5.0 * e(-1.0), 5.0 * e(-2.0)];
        acc.meas_comp_samples = vec![5.0, 5.0];
        let targets = [
            Target::process(&[0]),
            Target::measurement(&[0, 1]),
            Target::process(&[1, 2]),
            Target::process(&[2]),
        ];
        let m = moments(&targets, &acc);
        let want = [1.0, -1.5, 2.0, 0.0];
        for (k, (got, want)) in m.iter().zip(want).enumerate() {
            assert!((got - want).abs() < 1e-12, "equation {k}: {got} vs {want}");
        }
    }

    fn quadratic_budget_test(check: impl Fn(&mut Budget<'_>, &Mock)) {
        let mock = Mock::new(&[0.3, 20.0], &[&[4.0, 2.0], &[0.0, 8.0]]);
        let cost = cost(&mock, &[false; 2]);
        let deadline = Instant::now() + Duration::from_secs(3600);
        let mut b = Budget::new(&cost, 1000, deadline, &Silent);
        check(&mut b, &mock);
    }

    #[test]
    fn a_damped_step_is_marquardts_and_one_that_raises_the_sum_is_refused() {
        quadratic_budget_test(|b, _| {
            let y = vec![0.5, -0.5];
            let r = residuals(b, &y, Equations::Objective).unwrap().unwrap();
            let jac = difference(b, &y, &r, Equations::Objective, false).unwrap();
            // δ = −(A + λ diag A)⁻¹ Jᵀ r with A = JᵀJ, by hand.
            let lambda0 = 10.0;
            let a = jac.tr_mul(&jac);
            let mut lhs = a.clone();
            for k in 0..2 {
                lhs[(k, k)] += lambda0 * a[(k, k)];
            }
            let g = jac.tr_mul(&DVector::from_column_slice(&r));
            let delta = lhs.cholesky().unwrap().solve(&(-g));
            let mut lambda = lambda0;
            let (trial, rt, _) = damped_step(
                b,
                &jac,
                &y,
                &r,
                &mut lambda,
                MAX_TRIALS,
                Equations::Objective,
            )
            .unwrap()
            .expect("a short step down a linear residual lowers the sum");
            for k in 0..2 {
                assert!(
                    (trial[k] - (y[k] + delta[k])).abs() < 1e-12,
                    "{trial:?} vs {delta}"
                );
            }
            assert!(sum_sq(&rt) < sum_sq(&r));
            assert_eq!(lambda, lambda0 / 3.0, "an accepted step lowers the damping");
            // With the Jacobian's sign flipped every damped step climbs: none is taken,
            // after MAX_TRIALS raises of the damping by 4.
            let mut lambda = 1e-3;
            let wrong = -jac;
            let before = b.evaluations();
            let got = damped_step(
                b,
                &wrong,
                &y,
                &r,
                &mut lambda,
                MAX_TRIALS,
                Equations::Objective,
            )
            .unwrap();
            assert!(got.is_none(), "{got:?}");
            assert_eq!(b.evaluations() - before, MAX_TRIALS);
            let want = 1e-3 * 4f64.powi(MAX_TRIALS as i32);
            assert!((lambda / want - 1.0).abs() < 1e-12, "{lambda} vs {want}");
        });
    }

    #[test]
    fn the_jacobian_steps_inwards_at_the_upper_bound() {
        // From p0 at its upper bound (1e4) a step outwards would be clamped back: a zero
        // column, and p0 could never move. Differenced inwards, the search converges.
        quadratic_budget_test(|b, mock| {
            let y0 = vec![b.cost().hi[0], 0.0];
            let found = levenberg_marquardt(b, &y0, None, Equations::Objective)
                .unwrap()
                .found;
            let err = max_abs_diff(&found.point, &mock.y_star());
            assert!(err < 1e-6, "{err:.2e} from {y0:?}");
        });
    }

    #[test]
    fn broydens_update_maps_the_step_onto_the_change_and_leaves_other_directions() {
        // J = [[1, 2], [3, 4], [5, 6]]; the step s = (0.5, −1) and the residuals' change
        // Δr = (1, 0, −2) (J s = (−1.5, −2.5, −3.5)). After the update J s = Δr (the
        // secant condition), and J v is unchanged for v ⟂ s, v = (2, 1): (4, 10, 16).
        let mut jac = DMatrix::from_row_slice(3, 2, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let (y, trial) = ([1.0, 1.0], [1.5, 0.0]);
        let (r, rt) = ([0.0, 1.0, 2.0], [1.0, 1.0, 0.0]);
        broyden(&mut jac, &trial, &y, &rt, &r);
        let s = DVector::from_column_slice(&[0.5, -1.0]);
        let v = DVector::from_column_slice(&[2.0, 1.0]);
        let (js, jv) = (&jac * s, &jac * v);
        for (got, want) in js.iter().zip([1.0, 0.0, -2.0]) {
            assert!((got - want).abs() < 1e-12, "J s = {js}");
        }
        for (got, want) in jv.iter().zip([4.0, 10.0, 16.0]) {
            assert!((got - want).abs() < 1e-12, "J v = {jv}");
        }
        // A zero step changes nothing.
        let before = jac.clone();
        broyden(&mut jac, &y, &y, &rt, &r);
        assert_eq!(jac, before);
    }

    #[test]
    fn solves_the_objective_and_the_moment_equations_of_a_quadratic() {
        // Linear residuals in log space: each damped Gauss–Newton step leaves λ/(1 + λ) ≤
        // 1e-3 of the error, and the iteration stops after a step shorter than 1e-3, so
        // the error is then below 1e-6 (and J below 64 · 1e-12 with exponents up to 8).
        let mock = Mock::new(&[0.3, 20.0], &[&[4.0, 2.0], &[0.0, 8.0]]);
        let cost = cost(&mock, &[false; 2]);
        let targets = cost.targets.clone().expect("the mock names every target");
        for equations in [Equations::Objective, Equations::Moments(&targets)] {
            let deadline = Instant::now() + Duration::from_secs(3600);
            let mut b = Budget::new(&cost, 1000, deadline, &Silent);
            let found = levenberg_marquardt(&mut b, &[0.0, 0.0], None, equations)
                .unwrap()
                .found;
            let err = max_abs_diff(&found.point, &mock.y_star());
            assert!(err < 1e-6, "{equations:?}: {err:.2e}");
            assert!(found.cost < 1e-10, "{equations:?}: {}", found.cost);
            assert!(b.evaluations() < 40, "{equations:?}: {}", b.evaluations());
        }
    }

    #[test]
    fn under_monte_carlo_scoring_it_stops_at_the_noise_floor_not_at_rounding() {
        // The same quadratic scored both ways (the mock's Monte Carlo sums are its exact
        // ones): exactly, the search goes on to rounding; under Monte Carlo scoring it stops
        // once J is below a tenth of a consistent filter's score, sooner.
        let mock = Mock::new(&[0.3, 20.0], &[&[4.0, 2.0], &[0.0, 8.0]]);
        let solve = |exact: bool| {
            let mut cost = cost(&mock, &[false; 2]);
            cost.exact = exact;
            let deadline = Instant::now() + Duration::from_secs(3600);
            let mut b = Budget::new(&cost, 1000, deadline, &Silent);
            let found = levenberg_marquardt(&mut b, &[0.0, 0.0], None, Equations::Objective)
                .unwrap()
                .found;
            (found.cost, b.evaluations())
        };
        let (j_exact, n_exact) = solve(true);
        let (j_mc, n_mc) = solve(false);
        assert!(j_exact < 1e-10, "{j_exact}");
        assert!(
            j_mc <= 0.1 * CONSISTENT_J && j_mc > j_exact,
            "{j_mc} vs {j_exact}"
        );
        assert!(n_mc < n_exact, "{n_mc} vs {n_exact} evaluations");
        // Started on the floor with its residuals known, it costs nothing.
        let mut cost = cost(&mock, &[false; 2]);
        cost.exact = false;
        let deadline = Instant::now() + Duration::from_secs(3600);
        let mut b = Budget::new(&cost, 1000, deadline, &Silent);
        let near = mock.y_star().iter().map(|y| y + 1e-3).collect::<Vec<_>>();
        let r = residuals(&mut b, &near, Equations::Objective)
            .unwrap()
            .unwrap();
        assert!(sum_sq(&r) <= 0.1 * CONSISTENT_J);
        let before = b.evaluations();
        let again = levenberg_marquardt(&mut b, &near, Some(&r), Equations::Objective).unwrap();
        assert_eq!(b.evaluations(), before);
        assert_eq!(again.found.point, near);
        // Residuals known at a point outside the box are not the clamped point's: they are
        // evaluated afresh (here the known ones, all zero, would end the search at once).
        let outside = vec![b.cost().hi[0] + 1.0, 0.0];
        let zeros = vec![0.0; r.len()];
        let before = b.evaluations();
        let from_outside =
            levenberg_marquardt(&mut b, &outside, Some(&zeros), Equations::Objective).unwrap();
        assert!(b.evaluations() > before);
        assert!(
            from_outside.found.cost > 0.0 || from_outside.found.point != b.cost().clamp(&outside)
        );
    }

    #[test]
    fn on_the_noise_floor_a_step_that_gains_under_a_tenth_of_it_ends_the_search() {
        // Three components off by ±7% that two parameters cannot all remove (J's minimum
        // (3 · 0.07²)/3 = 0.0049 lies on the floor, CONSISTENT_J = 0.01, above a tenth of
        // it), with a bend that makes the last steps slow. The mock's Monte Carlo sums are
        // its exact ones, so a Monte Carlo search is the exact search cut short, where the
        // floor's rules cut it: its evaluations are the first ones of the exact search's.
        let solve = |mock: &Mock, exact: bool| {
            let mut cost = cost(mock, &[false; 2]);
            cost.exact = exact;
            let deadline = Instant::now() + Duration::from_secs(3600);
            let mut b = Budget::new(&cost, 1000, deadline, &Silent);
            levenberg_marquardt(&mut b, &[0.0, 0.0], None, Equations::Objective).unwrap();
            b.history()
        };
        let floor = CONSISTENT_J;
        let mock = |bend: f64| {
            Mock::new(&[0.3, 20.0], &[&[1.0, 0.0], &[0.0, 1.0], &[1.0, 1.0]])
                .misfit(&[0.07, 0.07, -0.07], usize::MAX)
                .bent(&[&[bend, 0.0], &[0.0, bend], &[bend, -bend]])
        };
        // A step that lands on the floor, then one that gains under a tenth of it: there
        // the search ends (39 evaluations; the exact search goes on to 60).
        let (exact, mc) = (solve(&mock(1.0), true), solve(&mock(1.0), false));
        let n = mc.len();
        assert_eq!(mc[..], exact[..n]);
        assert!(n + 10 < exact.len(), "{n} of {}", exact.len());
        let (before, landed, last) = (mc[n - 3], mc[n - 2], mc[n - 1]);
        assert!(landed <= floor && before - landed >= 0.1 * floor, "{mc:?}");
        assert!(last < landed && landed - last < 0.1 * floor, "{mc:?}");
        // On the floor, the first trial that does not lower the sum ends it too: one trial,
        // no fresh Jacobian (7 evaluations; the exact search differences afresh and goes on
        // to 22).
        let (exact, mc) = (solve(&mock(0.1), true), solve(&mock(0.1), false));
        let n = mc.len();
        assert_eq!(mc[..], exact[..n]);
        assert!(n + 10 < exact.len(), "{n} of {}", exact.len());
        assert!(mc[n - 1] == mc[n - 2] && mc[n - 2] <= floor, "{mc:?}");
        assert!(mc[n - 3] - mc[n - 2] >= 0.1 * floor, "{mc:?}");
    }

    #[test]
    fn a_deep_fit_differences_both_sides_where_the_box_allows() {
        // ln c = 100 d²: a residual quadratic in d, whose slope 2 r / d the central
        // difference gives exactly and the forward one as (2d + H) / (2d) of it.
        let mock = Mock::new(&[0.3], &[&[0.0]]).bent(&[&[100.0]]);
        let cost = cost(&mock, &[false]);
        let deadline = Instant::now() + Duration::from_secs(3600);
        let mut b = Budget::new(&cost, 1000, deadline, &Silent);
        let d = 0.01;
        let y = [mock.y_star()[0] + d];
        let r = residuals(&mut b, &y, Equations::Objective)
            .unwrap()
            .unwrap();
        let k = r
            .iter()
            .position(|x| x.abs() > 1e-12)
            .expect("a residual off zero");
        let slope = 2.0 * r[k] / d;
        let central = difference(&mut b, &y, &r, Equations::Objective, true).unwrap();
        let forward = difference(&mut b, &y, &r, Equations::Objective, false).unwrap();
        assert!(
            (central[(k, 0)] / slope - 1.0).abs() < 1e-6,
            "{}",
            central[(k, 0)]
        );
        let f = (2.0 * d + H) / (2.0 * d);
        assert!(
            (forward[(k, 0)] / slope / f - 1.0).abs() < 1e-6,
            "{}",
            forward[(k, 0)]
        );
        // Within H of the upper bound there is one side only: it differences inwards.
        let mut near = crate::tune::tests::cost(&mock, &[false]);
        near.hi[0] = y[0] + 0.5 * H;
        let mut b = Budget::new(&near, 1000, deadline, &Silent);
        let inward = difference(&mut b, &y, &r, Equations::Objective, false).unwrap();
        let one_side = difference(&mut b, &y, &r, Equations::Objective, true).unwrap();
        let f = (2.0 * d - H) / (2.0 * d);
        assert!(
            (inward[(k, 0)] / slope / f - 1.0).abs() < 1e-6,
            "{}",
            inward[(k, 0)]
        );
        assert_eq!(inward, one_side);
        // A side exactly H away from either bound is inside the box: both sides are taken.
        for (lo, hi) in [(y[0] - H, y[0] + 1.0), (y[0] - 1.0, y[0] + H)] {
            let mut edge = crate::tune::tests::cost(&mock, &[false]);
            (edge.lo[0], edge.hi[0]) = (lo, hi);
            let mut b = Budget::new(&edge, 1000, deadline, &Silent);
            let both = difference(&mut b, &y, &r, Equations::Objective, true).unwrap();
            assert!(
                (both[(k, 0)] / slope - 1.0).abs() < 1e-6,
                "{}",
                both[(k, 0)]
            );
        }
        // One side only where the other is outside the box or diverges: the forward
        // difference where the lower side is (its slope (2d + H) / (2d) of the truth's),
        // the backward where the upper side is ((2d − H) / (2d)), central asked or not.
        let forward = (2.0 * d + H) / (2.0 * d);
        let backward = (2.0 * d - H) / (2.0 * d);
        let (below, above) = ((y[0] - 0.5 * H).exp(), (y[0] + 0.5 * H).exp());
        let bent = || Mock::new(&[0.3], &[&[0.0]]).bent(&[&[100.0]]);
        let sides = [
            (bent().diverging_below(0, below), forward, false),
            (bent().diverging_above(0, above), backward, false),
            (bent(), forward, true),
        ];
        for (m, f, low_bound) in &sides {
            let mut c = crate::tune::tests::cost(m, &[false]);
            if *low_bound {
                c.lo[0] = y[0] - 0.5 * H;
            }
            for central in [true, false] {
                let mut b = Budget::new(&c, 1000, deadline, &Silent);
                let one = difference(&mut b, &y, &r, Equations::Objective, central).unwrap();
                let got = one[(k, 0)] / (slope * f);
                assert!((got - 1.0).abs() < 1e-6, "{f} {central}: {got}");
            }
        }
    }

    #[test]
    fn a_deep_fit_goes_on_past_the_floor_while_short_steps_halve_the_sum() {
        // ln c = 100 d²: residuals quadratic at the optimum, so each Gauss–Newton step
        // halves d and J = 10⁴ d⁴ falls 16-fold. Under Monte Carlo scoring the search stops
        // at a tenth of the floor (J ≤ 1e-3); asked for J < 1e-10 it goes on, through steps
        // shorter than 1e-3 (from d = 2e-3 on, J = 1.6e-7) to d ≈ 2.5e-4.
        let mock = Mock::new(&[0.3], &[&[0.0]]).bent(&[&[100.0]]);
        let solve = |stop_below: f64| {
            let mut cost = cost(&mock, &[false]);
            cost.exact = false;
            cost.stop_below = stop_below;
            let deadline = Instant::now() + Duration::from_secs(3600);
            let mut b = Budget::new(&cost, 1000, deadline, &Silent);
            let start = [mock.y_star()[0] - 0.5];
            let _ = levenberg_marquardt(&mut b, &start, None, Equations::Objective);
            b.best().expect("a point was evaluated").cost
        };
        let shallow = solve(0.0);
        assert!(shallow <= 0.1 * CONSISTENT_J && shallow > 1e-6, "{shallow}");
        let deep = solve(1e-10);
        assert!(deep < 1e-10, "{deep}");
        // The rule itself: a short step ends the search unless, in a deep fit, it halved
        // the sum (in a sharp fit, never); a step gaining under 1e-4 of the sum ends it
        // whatever the fit.
        let (plain, deep, sharp) = (
            Settle::new(false, Equations::Objective, false),
            Settle::new(false, Equations::Objective, true),
            Settle::new(true, Equations::Objective, true),
        );
        assert_eq!(deep.floor, 0.0);
        assert!(
            !deep.sharp && sharp.sharp && !Settle::new(true, Equations::Objective, false).sharp
        );
        assert!(plain.converged(5e-4, 1.0, 0.1) && !deep.converged(5e-4, 1.0, 0.1));
        assert!(deep.converged(5e-4, 1.0, 0.6) && !deep.converged(5e-4, 1.0, 0.5));
        assert!(!sharp.converged(5e-4, 1.0, 0.9) && !sharp.converged(1e-6, 1.0, 0.99));
        assert!(sharp.converged(1e-6, 1.0, 1.0 - 0.9e-4));
        assert!(!plain.converged(2e-3, 1.0, 0.9) && !deep.converged(2e-3, 1.0, 0.9));
        assert!(deep.converged(2e-3, 1.0, 1.0 - 0.9e-4) && !deep.converged(2e-3, 1.0, 0.9998));
        // After a converged step a sharp fit differences afresh unless its Jacobian was.
        assert_eq!(sharp.next(false, false), Next::Go);
        assert_eq!(sharp.next(true, false), Next::Refresh);
        assert_eq!(sharp.next(true, true), Next::Stop);
        assert_eq!(deep.next(true, false), Next::Stop);
        assert_eq!(plain.next(false, true), Next::Go);
        // At the edges: halved means at most half of the sum before (here 2), a step of
        // 1e-3 exactly is not short, and a gain of exactly 1e-12 above a sum of 0 is not
        // too small (one of half that is).
        assert!(!deep.converged(5e-4, 2.0, 1.0) && deep.converged(5e-4, 2.0, 1.01));
        assert!(!plain.converged(1e-3, 1.0, 0.9));
        assert!(!plain.converged(2e-3, 1e-12, 0.0) && plain.converged(2e-3, 5e-13, 0.0));
    }

    #[test]
    fn the_noise_floor_is_a_consistent_filters_j_and_five_percent_moment_residuals() {
        // J's floor is CONSISTENT_J; the moment equations' is a residual norm of MATCHED
        // (5%), i.e. a sum of squares of 0.0025: settled on it, done at a tenth of it, and
        // neither below it under exact scoring.
        let targets = [Target::process(&[0])];
        for (equations, floor) in [
            (Equations::Objective, CONSISTENT_J),
            (Equations::Moments(&targets), MATCHED * MATCHED),
        ] {
            let s = Settle::new(false, equations, false);
            assert!(
                s.settled(0.99 * floor) && !s.settled(1.01 * floor),
                "{equations:?}"
            );
            assert!(s.done(0.099 * floor, f64::INFINITY) && !s.done(0.101 * floor, f64::INFINITY));
            // On the floor, a gain below a tenth of it ends the search; above, it goes on.
            assert!(s.done(0.5 * floor, 0.099 * floor) && !s.done(0.5 * floor, 0.101 * floor));
            assert!(
                !s.done(0.5 * floor, 0.1 * floor),
                "a gain of a tenth exactly goes on"
            );
            assert!(!s.done(1.01 * floor, 0.0), "{equations:?}: above the floor");
            let exact = Settle::new(true, equations, false);
            assert!(!exact.settled(0.5 * floor) && !exact.done(1e-30, 0.0));
        }
    }
}
