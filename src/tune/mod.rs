//! The tuner: searches an experiment's free noise parameters for the filter whose
//! consistency statistics sit at their targets, then confirms the winner on fresh Monte
//! Carlo seeds.
//!
//! The method, one file per step:
//! - `cost`: the search space is the logarithm of each free parameter inside its bounds,
//!   and a candidate scores [`Objective`] J ([`objective`]) on either the exact
//!   expected statistics (linear problems whose filter has the truth's F and H: noise-free
//!   and cheap) or a Monte Carlo run with common random numbers (every candidate sees the
//!   same draws, so the score is a deterministic function of the parameters).
//! - `budget`: every evaluation goes through one wrapper that counts it against a budget
//!   in evaluations and seconds, books the best point, the history and the diverged
//!   candidates, and tells the [`Observer`]. A candidate whose filter diverges scores +∞
//!   and the search goes on.
//! - `global`: a Latin hypercube of quasi-random points in the log box, and the choice of
//!   the best few mutually distinct points as local starts.
//! - `local`, `simplex`, `levenberg_marquardt`: a local search from each start
//!   ([`LocalSearch`]): Nelder–Mead (argmin), each restarted once to polish, or
//!   Levenberg–Marquardt on J's residuals, first on each parameter's own components (the
//!   moment equations) and then on the whole objective.
//! - `separable`: where the experiment names decoupled blocks, each block's free
//!   parameters searched on that block's own statistics (a correct axis is never moved to
//!   compensate a wrong one); and a parameter that ends on a search bound after a converged
//!   search gets that bound widened once (log space) and one more local search.
//! - `resolution`: how precisely the data pin each parameter down, from J's curvature at
//!   the optimum against J's noise level on the confirmation runs.
//!
//! Under exact scoring the candidates of the global stage and the local starts run in
//! parallel; their evaluations are booked in point and start order, so the result and its
//! history do not depend on the thread count.

mod budget;
mod cost;
mod global;
mod levenberg_marquardt;
mod local;
pub mod objective;
mod refine;
mod result;
mod separable;
mod settings;
mod simplex;
mod spec;
#[cfg(test)]
mod tests;

pub use objective::{Objective, Terms, Weights};
pub use refine::{Confirmation, band_low, seed_at};
pub use result::{Observer, Resolution, Silent, TuneResult, TuneStatus, Widening};
pub use settings::{LocalSearch, Plan, Scoring, TuneSettings};
pub use spec::TuneSpec;

use std::time::{Duration, Instant};

use self::budget::Budget;
use self::cost::{Candidate, Cost};
use self::refine::Gate;
use self::separable::Searched;
use crate::experiment::{Experiment, ExperimentError};
use crate::input::SettingError;
use crate::montecarlo::McConfig;
use crate::stats::GateMode;

/// Errors that stop a tuning run before it starts.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TuneError {
    /// A setting does not suit this experiment.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// The start or the fixed flags do not match the parameters.
    #[error("{start} start values and {fixed} fixed flags for {params} parameters")]
    Shape {
        /// Start values given.
        start: usize,
        /// Fixed flags given.
        fixed: usize,
        /// Parameters of the experiment.
        params: usize,
    },
    /// The experiment itself failed (an external worker broke the protocol).
    #[error(transparent)]
    Experiment(#[from] ExperimentError),
}

/// The seed of the confirmation runs when none is given: a fixed mix of the search seed,
/// never equal to it.
pub fn default_confirm_seed(seed: u64) -> u64 {
    // Flipping bits 0 and 40 changes the seed and keeps it below 2^63 when it was (TOML
    // files store seeds as signed 64-bit integers).
    seed ^ 0x0000_0100_0000_0001
}

/// Whether the search scores exactly: asked for, or chosen by `Auto` where the experiment
/// has exact sums.
fn exact_scoring(
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
            "exact scoring needs a linear filter with the truth's states that uses its F and H",
        )
        .into()),
        Scoring::Exact => Ok(true),
        Scoring::MonteCarlo => Ok(false),
    }
}

/// Tune `model` from parameter values `start`, holding the parameters marked in `fixed`,
/// with the Monte Carlo test `mc` (the confirmation's; the search may use more runs).
pub fn tune(
    model: &dyn Experiment,
    start: &[f64],
    fixed: &[bool],
    mc: &McConfig,
    settings: &TuneSettings,
    observer: &dyn Observer,
) -> Result<TuneResult, TuneError> {
    let t0 = Instant::now();
    let params = &model.params().params;
    if start.len() != params.len() || fixed.len() != params.len() {
        return Err(TuneError::Shape {
            start: start.len(),
            fixed: fixed.len(),
            params: params.len(),
        });
    }
    let exact = exact_scoring(model, start, mc, settings.scoring())?;
    // The objective needs no gate intervals, so the search skips the full gate's
    // per-component null variances.
    let search_mc = if exact {
        *mc
    } else {
        mc.with_runs(settings.search_runs().unwrap_or(4 * mc.runs()))?
    }
    .with_gate(GateMode::Mean);
    // Without states (no ground truth) only the innovations can be scored.
    let nis_only = settings.nis_only() || model.state_names().is_empty();
    let objective = Objective::new(settings.weights(), nis_only, mc.alpha());
    let mut cost = Cost::new(model, search_mc, exact, objective, start, fixed);
    // The start's evaluation, timed: what one evaluation of the search costs (an external
    // worker's start-up included, so an overestimate on the first call).
    let t_start = Instant::now();
    let acc0 = cost.accumulate(start);
    let seconds_per_eval = t_start.elapsed().as_secs_f64();
    cost.objective.prepare(&acc0);
    let objective_initial = cost.objective.evaluate(&acc0);
    let plan = settings.plan(cost.dim(), cost.targets.is_some(), exact, seconds_per_eval);
    for note in &plan.notes {
        observer.note(note);
    }
    let settings = &settings.clone().with_local(plan.local);

    // Exact scoring is sequential inside, so candidates run in parallel; Monte Carlo
    // scoring is parallel inside, so candidates run one after another.
    let deadline = t0 + Duration::from_secs_f64(settings.max_seconds());
    let parts = if cost.dim() > 0 {
        separable::parts(model, fixed, &cost.objective)
    } else {
        None
    };
    let mut searched = match &parts {
        Some(parts) => separable::search(
            model,
            &cost,
            parts,
            start,
            &acc0,
            settings,
            mc.seed(),
            deadline,
            observer,
        ),
        None => {
            let mut budget = Budget::new(&cost, settings.max_evals(), deadline, observer);
            let found = if cost.dim() > 0 {
                local::search(&mut budget, settings, mc.seed(), exact, observer)
            } else {
                None
            };
            Searched::pooled(&budget, found)
        }
    };
    let mut best = match searched.found.clone() {
        Some(c) => c,
        None if cost.dim() == 0 => Candidate {
            point: Vec::new(),
            cost: objective_initial.total,
        },
        None => searched.best.clone().unwrap_or(Candidate {
            point: Vec::new(),
            cost: f64::INFINITY,
        }),
    };
    // A converged search that ends on a bound has not shown that no value fits: the data
    // may want the parameter beyond it. Widen once and search again before any status.
    let mut widened = Vec::new();
    if searched.found.is_some() && best.cost.is_finite() && cost.failure().is_none() {
        let (w, y) = separable::widen_once(
            model,
            &mut cost,
            parts.as_deref(),
            &best.point,
            settings,
            deadline,
            observer,
            &mut searched,
        );
        if !w.is_empty() {
            best = Candidate {
                cost: cost.score(&y).value,
                point: y,
            };
        }
        widened = w;
    }
    let cost = cost;
    // The gate's own deviates at the optimum: how they move with each parameter (for the
    // refinement and the resolution), on the search's runs from its seed.
    let use_nees = !nis_only;
    if let Some(e) = cost.failure() {
        return Err(e.into());
    }
    let gate = Gate::new(model, &cost, *mc, use_nees);
    let converged = searched.evaluations > 0 && !searched.exhausted;
    let sens_runs = search_mc.runs();
    let mut point = best.point.clone();
    let mut refine_evaluations = 0;
    // Under blocks the refinement, too, runs block by block on each block's own deviates:
    // the pooled deviates would move a correct block to compensate a wrong one.
    if let (false, Some(parts), true) = (exact, &parts, converged && best.cost.is_finite()) {
        observer.phase("refine");
        let runs = settings
            .refine_runs()
            .unwrap_or_else(|| sens_runs.saturating_mul(4));
        let theta = cost.theta(&point);
        for part in parts {
            let cb = part.cost(model, &cost, search_mc, &theta);
            let gb = Gate::new(model, &cb, *mc, !nis_only)
                .for_block(&part.block.states, &part.block.measurements);
            let yb = cb.start();
            refine_evaluations += yb.len() + 1;
            let Some((_, d)) = refine::sensitivity(&gb, &cb, &yb, sens_runs, mc.seed()) else {
                continue;
            };
            if d.nrows() == 0 {
                continue;
            }
            let d_refine = d * (runs as f64 / sens_runs as f64).sqrt();
            let (refined, evals) = refine::refine(&gb, &cb, &yb, &d_refine, runs, mc.seed());
            refine_evaluations += evals;
            for (k, &i) in cb.free().iter().enumerate() {
                if let Some(f) = cost.free().iter().position(|&x| x == i) {
                    point[f] = refined[k];
                }
            }
        }
    }
    let sens = if converged && !point.is_empty() && best.cost.is_finite() {
        observer.phase("refine");
        refine_evaluations += point.len() + 1;
        refine::sensitivity(&gate, &cost, &point, sens_runs, mc.seed())
    } else {
        None
    };
    if let (false, None, Some((_, d))) = (exact, &parts, &sens) {
        let runs = settings
            .refine_runs()
            .unwrap_or_else(|| sens_runs.saturating_mul(4));
        let d_refine = d * (runs as f64 / sens_runs as f64).sqrt();
        let (refined, evals) = refine::refine(&gate, &cost, &point, &d_refine, runs, mc.seed());
        point = refined;
        refine_evaluations += evals;
    }
    let mut tuned = if point.is_empty() {
        start.to_vec()
    } else {
        cost.theta(&point)
    };
    let mut objective_final = cost.objective.evaluate(&cost.accumulate(&tuned));

    observer.phase("confirm");
    let confirm_seed = settings
        .confirm_seed()
        .unwrap_or_else(|| default_confirm_seed(mc.seed()));
    let before = gate.report(start, mc.runs(), confirm_seed);
    let recorded = model.seed_free();
    let (mut confirmation, mut after, mut deviates) = refine::confirm(
        &gate,
        &tuned,
        confirm_seed,
        settings.confirm_seeds(),
        recorded,
    );
    let mut kept_start = false;
    // On one record the objective is exact and the gate is one deterministic test, so a
    // search that ends worse than where it started, or fails the gate where its start
    // passes, has not found the best fit: keep the start (often an estimate from the same
    // record), rather than conclude that no value fits.
    if recorded
        && tuned != start
        && (objective_final.total > objective_initial.total
            || (!confirmation.holds() && before.verdict.passes()))
    {
        tuned = start.to_vec();
        objective_final = objective_initial;
        kept_start = true;
        (confirmation, after, deviates) = refine::confirm(&gate, &tuned, confirm_seed, 1, recorded);
    }

    // The resolution means something only at a converged optimum, and the seed-to-seed
    // spread it rests on does not exist for one record (only the bounds are checked).
    let resolution = if kept_start {
        None
    } else if recorded && !point.is_empty() && best.cost.is_finite() {
        Some(refine::bounds_only(&cost, &point, fixed))
    } else if recorded || (!converged && cost.dim() > 0) {
        None
    } else if point.is_empty() || !best.cost.is_finite() {
        Some(vec![Resolution::FIXED; params.len()])
    } else {
        sens.as_ref().map(|(_, d)| {
            let d_n = d * (mc.runs() as f64 / sens_runs as f64).sqrt();
            refine::resolution(&cost, &point, &d_n, &deviates, fixed)
        })
    };
    if let Some(e) = cost.failure() {
        return Err(e.into());
    }
    // A search that ran out of budget did not converge, whatever the confirmation says:
    // its values are the best found so far, never reported as the tuned answer.
    let at_bound = bound_flags(&cost, &tuned, fixed);
    // A parameter still on a bound after its widening was stopped by the box, as a budget
    // stops a search: "no value of the free parameters fits" would claim what the search
    // never tried, so the run reports the best point found so far instead.
    let boxed_in = widened.iter().any(|w| at_bound[w.param]);
    let status = if cost.dim() > 0 && searched.evaluations == 0 {
        TuneStatus::BudgetExhausted
    } else if !best.cost.is_finite() {
        TuneStatus::Diverged
    } else if searched.exhausted {
        TuneStatus::BudgetExhausted
    } else if confirmation.holds() {
        TuneStatus::Consistent
    } else if boxed_in {
        TuneStatus::BudgetExhausted
    } else {
        TuneStatus::Inconsistent
    };
    Ok(TuneResult {
        names: params.iter().map(|p| p.name.clone()).collect(),
        fixed: fixed.to_vec(),
        initial: start.to_vec(),
        tuned,
        objective_initial,
        objective_final,
        scoring: if exact {
            Scoring::Exact
        } else {
            Scoring::MonteCarlo
        },
        local: plan.local,
        evaluations: searched.evaluations,
        diverged_evaluations: searched.diverged,
        history: searched.history,
        resolution,
        at_bound,
        widened,
        separable: parts.is_some(),
        refine_evaluations,
        search_seed: mc.seed(),
        confirm_seed,
        confirmation,
        runs: mc.runs(),
        steps: mc.steps(),
        alpha: mc.alpha(),
        before,
        after,
        status,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Per parameter (problem order), whether `theta`'s value lies within 0.05 log units (5%)
/// of a bound of `cost`'s box; false for fixed parameters.
fn bound_flags(cost: &Cost<'_>, theta: &[f64], fixed: &[bool]) -> Vec<bool> {
    let y: Vec<f64> = cost.free().iter().map(|&i| theta[i].ln()).collect();
    let mut flags = vec![false; fixed.len()];
    for (k, &i) in cost.free().iter().enumerate() {
        flags[i] = y[k].is_finite() && cost.near_bound(k, &y);
    }
    flags
}
