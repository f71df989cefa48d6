//! The search after the global stage: a local search from each start, and which solvers
//! run in which order.

use super::budget::{Budget, Exhausted};
use super::choices::LocalSearch;
use super::cost::Candidate;
use super::global;
use super::levenberg_marquardt::{CONSISTENT_J, Equations, MATCHED, levenberg_marquardt};
use super::result::Observer;
use super::settings::TuneSettings;
use super::simplex::nelder_mead;

/// Initial simplex step of a local search, log units (a factor 2).
pub(super) const WIDE: f64 = 0.7;
/// Initial simplex step of a local search from an estimate, log units (about 20%).
const NEAR: f64 = 0.2;
/// Initial simplex step of the polishing restart, log units (10%).
const POLISH: f64 = 0.1;

/// The global stage, a local search from each of the best few points (in parallel if
/// `parallel`), and for the simplex a last restart from the winner. `None` when the budget
/// ran out (the budget's best point is then the answer) or no local search found a finite
/// score.
pub(super) fn search(
    budget: &mut Budget<'_>,
    settings: &TuneSettings,
    seed: u64,
    parallel: bool,
    observer: &dyn Observer,
) -> Option<Candidate> {
    let y0 = budget.cost().start();
    if let Some(found) = moment_matched(budget, settings, &y0, observer) {
        return found.ok();
    }
    // A start that is already an estimate of the answer needs no scan of the box.
    let (starts, step) = if settings.from_estimate() {
        (vec![y0.clone()], NEAR)
    } else {
        observer.phase("global");
        let ranked = global::scan(budget, &y0, settings.global_points(), seed, parallel);
        let starts = global::choose_starts(&ranked, &y0, settings.local(), settings.starts());
        (starts, WIDE)
    };
    observer.phase("local");
    let method = settings.local();
    let outcomes = budget.map(&starts, parallel, |b, s| local_search(b, method, s, step));
    if budget.exhausted() {
        return None;
    }
    let mut best: Option<Candidate> = None;
    for c in outcomes.into_iter().flatten() {
        if c.cost.is_finite() && best.as_ref().is_none_or(|b| c.cost < b.cost) {
            best = Some(c);
        }
    }
    let best = best?;
    // The simplex restarts once more from the best point; Levenberg–Marquardt has
    // converged where it stopped, and a restart would only repeat it.
    if method == LocalSearch::Simplex {
        let again = local_search(budget, method, &best.point, step).ok()?;
        return Some(if again.cost < best.cost { again } else { best });
    }
    Some(best)
}

/// Gauss–Newton with every parameter's components known: the moment equations solved from
/// the start, and where they are solved (every parameter matched its own components'
/// average), Levenberg–Marquardt on J from that point; if J ends at most [`CONSISTENT_J`],
/// that is the search's answer and the global stage's 1 + points · d evaluations are saved
/// (each a full Monte Carlo run). A moment-matched point whose J is already at most
/// [`CONSISTENT_J`] scores as a consistent filter does: J's own equations would fit the
/// search runs' noise, so it is the answer as it stands (the refinement follows on more
/// runs). `None` when this does not apply, the equations stay unsolved (a parameter pinned
/// at its bound, a model that cannot match) or J stays above: the global stage runs as
/// before, and its starts may find a deeper basin the start's side of a ridge hides.
fn moment_matched(
    budget: &mut Budget<'_>,
    settings: &TuneSettings,
    y0: &[f64],
    observer: &dyn Observer,
) -> Option<Result<Candidate, Exhausted>> {
    if settings.local() != LocalSearch::GaussNewton || settings.from_estimate() {
        return None;
    }
    let targets = budget.cost().targets.clone()?;
    observer.phase("local");
    let moments = match levenberg_marquardt(budget, y0, None, Equations::Moments(&targets)) {
        Ok(m) => m,
        Err(e) => return Some(Err(e)),
    };
    if !solved(moments.found.cost) {
        return None;
    }
    if consistent(moments.j()) {
        let j = moments.j();
        return Some(Ok(Candidate {
            point: moments.found.point,
            cost: j,
        }));
    }
    let known = moments.objective.as_deref();
    match levenberg_marquardt(budget, &moments.found.point, known, Equations::Objective) {
        Ok(lm) if !consistent(lm.found.cost) => None,
        found => Some(found.map(|lm| lm.found)),
    }
}

/// Whether moment equations whose residuals' sum of squares is `sum_sq` are solved (a
/// diverged start's +∞ and a NaN are not).
fn solved(sum_sq: f64) -> bool {
    sum_sq <= MATCHED * MATCHED
}

/// Whether J scores as a consistent filter does (+∞ and NaN do not).
fn consistent(j: f64) -> bool {
    j <= CONSISTENT_J
}

/// One local search from `y0`. Simplex: Nelder–Mead, then a restart with a small simplex
/// to polish (a restart undoes Nelder–Mead's occasional collapse onto a subspace).
/// Gauss–Newton: Levenberg–Marquardt, first on the moment equations where every parameter's
/// components are known, then on J; falling back to the simplex if `y0` diverges.
pub(super) fn local_search(
    budget: &mut Budget<'_>,
    method: LocalSearch,
    y0: &[f64],
    step: f64,
) -> Result<Candidate, Exhausted> {
    let first = match method {
        LocalSearch::GaussNewton => {
            let mut from = y0.to_vec();
            let mut known = None;
            if let Some(targets) = budget.cost().targets.as_deref() {
                let moments =
                    levenberg_marquardt(budget, &from, None, Equations::Moments(targets))?;
                if moments.found.cost.is_finite() {
                    from = moments.found.point;
                    known = moments.objective;
                }
            }
            let lm = levenberg_marquardt(budget, &from, known.as_deref(), Equations::Objective)?;
            if lm.found.cost.is_finite() {
                return Ok(lm.found);
            }
            nelder_mead(budget, &from, step)?
        }
        LocalSearch::Simplex => nelder_mead(budget, y0, step)?,
    };
    let polished = nelder_mead(budget, &first.point, POLISH)?;
    Ok(if polished.cost < first.cost {
        polished
    } else {
        first
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_moment_equations_are_solved_within_five_percent_and_j_is_consistent_to_a_hundredth() {
        // The norm of the moment residuals: 0.05 solves, 0.0501 does not.
        assert!(solved(0.0));
        assert!(solved(0.05 * 0.05));
        assert!(!solved(0.0501 * 0.0501));
        assert!(!solved(f64::INFINITY) && !solved(f64::NAN));
        assert!(consistent(0.0) && consistent(CONSISTENT_J));
        assert!(!consistent(0.0101) && !consistent(f64::INFINITY) && !consistent(f64::NAN));
    }
}
