//! The search over an experiment's decoupled blocks, the once-widened bounds, and what
//! either search hands to the rest of the run.
//!
//! **Why block by block.** The pooled objective adds every component into the time
//! averages, so under a misfit in one block (an axis whose model is wrong) the search
//! lowers J by moving the parameters of other, correct blocks: they compensate the pooled
//! ANEES/ANIS. When the experiment says which parameters, states and measurements no matrix
//! couples ([`crate::experiment::Structure::blocks`]), each block's free parameters are
//! searched on that block's statistics alone ([`Objective::restricted`]), the others held
//! at their start values. A block's statistics do not depend on another block's
//! parameters, so on a well-specified problem the blocks' optima are the pooled optimum's
//! (exact scoring: the same zero of J), and under a misfit a correct block stays where its
//! own evidence puts it.
//!
//! The separable search runs whenever there are blocks, not only after a pooled fit was
//! found inconsistent: it costs no more (each block's search is smaller, and the budget is
//! split by dimension), its answer on a consistent problem is the pooled one, and deciding
//! by a first pooled search would spend its budget twice and tie the answer to that
//! search's noise. Blocks run one after another, each as the pooled search runs (candidates
//! in parallel under exact scoring, booked in order), so the result does not depend on the
//! thread count.

use std::time::Instant;

use super::budget::Budget;
use super::cost::{Candidate, Cost};
use super::local;
use super::objective::Objective;
use super::result::{Observer, Widening};
use super::settings::TuneSettings;
use crate::experiment::{Block, Experiment};
use crate::montecarlo::McConfig;
use crate::stats::Accumulator;

/// How far a bound moves outwards when a free parameter ends on it: a factor 1000 (3
/// decades in log space).
/// A designer's bound is a plausibility guess, and the misfits it hides move parameters by
/// factors of hundreds to thousands (issue #22 saw ×1,617 and ×2,278), so a smaller step
/// would often end on the new bound again; a larger one would let a filter that no value
/// fits wander to numerically meaningless covariances.
pub(super) const WIDEN: f64 = 1e3;

/// What a search (pooled or block by block) found and spent.
pub(super) struct Searched {
    /// The converged answer, as a log-point of the full cost; `None` when the budget ran
    /// out or nothing finite was found.
    pub found: Option<Candidate>,
    /// The best point booked, for when nothing converged.
    pub best: Option<Candidate>,
    /// Evaluations spent.
    pub evaluations: usize,
    /// Of those, candidates whose filter diverged.
    pub diverged: usize,
    /// The best objective after each evaluation (for the block search: the sum over the
    /// blocks of their restricted objectives, each block's best so far).
    pub history: Vec<f64>,
    /// The search stopped on its budget.
    pub exhausted: bool,
}

impl Searched {
    /// The record of a pooled search on `budget` that returned `found`.
    pub(super) fn pooled(budget: &Budget<'_>, found: Option<Candidate>) -> Self {
        Searched {
            found,
            best: budget.best(),
            evaluations: budget.evaluations(),
            diverged: budget.diverged(),
            history: budget.history(),
            exhausted: budget.exhausted(),
        }
    }

    /// Adds the evaluations of a later search on `budget` (the widened one), whose history
    /// values are offset by `base`.
    fn extend(&mut self, budget: &Budget<'_>, base: f64) {
        let last = self.history.last().copied().unwrap_or(f64::INFINITY);
        self.history
            .extend(budget.history().iter().map(|h| last.min(base + h)));
        self.evaluations += budget.evaluations();
        self.diverged += budget.diverged();
        self.exhausted |= budget.exhausted();
    }
}

/// One decoupled block with at least one free parameter, ready to search.
pub(super) struct Part {
    /// The block.
    pub block: Block,
    /// Which parameters this block's cost holds fixed: every parameter outside the block,
    /// and the block's own fixed ones.
    pub fixed: Vec<bool>,
    /// The objective restricted to the block.
    pub objective: Objective,
}

impl Part {
    /// The block's cost around `theta` (every parameter's current value), with the full
    /// cost's box for its free parameters (widened ones included).
    pub(super) fn cost<'a>(
        &self,
        model: &'a dyn Experiment,
        full: &Cost<'_>,
        mc: McConfig,
        theta: &[f64],
    ) -> Cost<'a> {
        let mut c = Cost::new(
            model,
            mc,
            full.exact,
            self.objective.clone(),
            theta,
            &self.fixed,
        );
        for (k, &i) in full.free().iter().enumerate() {
            c.set_bounds(i, full.lo[k], full.hi[k]);
        }
        c.stop_below = full.stop_below;
        c
    }
}

/// The blocks of `model` that have a free parameter, each with its restricted objective;
/// `None` when the experiment has no blocks or none has a free parameter. One searchable
/// block is still searched on its own statistics: pooled, a block held entirely fixed (and
/// wrong) would pull it.
pub(super) fn parts(
    model: &dyn Experiment,
    fixed: &[bool],
    objective: &Objective,
) -> Option<Vec<Part>> {
    let parts: Vec<Part> = model
        .blocks()?
        .into_iter()
        .filter(|b| b.params.iter().any(|&i| !fixed[i]))
        .map(|block| Part {
            fixed: (0..fixed.len())
                .map(|i| fixed[i] || !block.params.contains(&i))
                .collect(),
            objective: objective
                .clone()
                .restricted(&block.states, &block.measurements),
            block,
        })
        .collect();
    (!parts.is_empty()).then_some(parts)
}

/// Passes a block's evaluations on with the count and the objective of the whole search.
struct Offset<'a> {
    inner: &'a dyn Observer,
    evals: usize,
    base: f64,
}

impl Observer for Offset<'_> {
    fn evaluation(&self, evals: usize, best: f64) {
        self.inner.evaluation(self.evals + evals, self.base + best);
    }
    fn phase(&self, name: &str) {
        self.inner.phase(name);
    }
    fn note(&self, line: &str) {
        self.inner.note(line);
    }
}

/// Each part's free parameters searched on its restricted objective from `start`, the
/// others held; the budget `max_evals` split by the parts' dimensions (what one block
/// leaves is the next's). `acc0` is the sums at the start. The answer is a log-point of
/// `full`.
#[allow(clippy::too_many_arguments)]
pub(super) fn search(
    model: &dyn Experiment,
    full: &Cost<'_>,
    parts: &[Part],
    start: &[f64],
    acc0: &Accumulator,
    settings: &TuneSettings,
    seed: u64,
    deadline: Instant,
    observer: &dyn Observer,
) -> Searched {
    let j0: Vec<f64> = parts
        .iter()
        .map(|p| p.objective.evaluate(acc0).total)
        .collect();
    let mut done: Vec<f64> = j0.clone();
    let mut y = full.start();
    let mut out = Searched {
        found: None,
        best: None,
        evaluations: 0,
        diverged: 0,
        history: Vec::new(),
        exhausted: false,
    };
    let mut converged = true;
    let dims: Vec<usize> = parts
        .iter()
        .map(|p| p.fixed.iter().filter(|f| !**f).count())
        .collect();
    for (b, part) in parts.iter().enumerate() {
        let cost = part.cost(model, full, *full.mc(), start);
        let remaining = settings.max_evals().saturating_sub(out.evaluations);
        let dims_left: usize = dims[b..].iter().sum();
        let share = (remaining * dims[b] / dims_left.max(1)).max(1);
        let others: f64 = done
            .iter()
            .enumerate()
            .filter(|(c, _)| *c != b)
            .map(|(_, j)| j)
            .sum();
        let offset = Offset {
            inner: observer,
            evals: out.evaluations,
            base: others,
        };
        let mut budget = Budget::new(&cost, share, deadline, &offset);
        let found = local::search(&mut budget, settings, seed, full.exact, &offset);
        let point = match (&found, budget.best()) {
            (Some(c), _) => Some(c.point.clone()),
            (None, Some(best)) => Some(best.point),
            (None, None) => None,
        };
        converged &= found.is_some() && !budget.exhausted();
        out.history
            .extend(budget.history().iter().map(|h| others + h.min(j0[b])));
        out.evaluations += budget.evaluations();
        out.diverged += budget.diverged();
        out.exhausted |= budget.exhausted();
        if let Some(p) = point {
            if let Some(best) = budget.best() {
                done[b] = done[b].min(best.cost);
            }
            for (k, &i) in cost.free().iter().enumerate() {
                if let Some(f) = full.free().iter().position(|&x| x == i) {
                    y[f] = p[k];
                }
            }
        }
    }
    // The assembled point is scored on the pooled objective (not charged: the blocks'
    // evaluations already decided it), which the rest of the run reads as the search's J.
    let assembled = Candidate {
        cost: full.score(&y).value,
        point: y,
    };
    if converged && !out.exhausted {
        out.found = Some(assembled.clone());
    }
    out.best = Some(assembled);
    out
}

/// Widens once the bounds that free parameters ended on after a converged search (within
/// 5% of a bound), by [`WIDEN`] outwards, on `full` and then searches again locally from `y`
/// in the widened box: the whole point, or under `parts` each block that holds a widened
/// parameter. Returns the widenings and the new point (`y` when nothing was widened);
/// the searches' evaluations are added to `searched`.
#[allow(clippy::too_many_arguments)]
pub(super) fn widen_once(
    model: &dyn Experiment,
    full: &mut Cost<'_>,
    parts: Option<&[Part]>,
    y: &[f64],
    settings: &TuneSettings,
    deadline: Instant,
    observer: &dyn Observer,
    searched: &mut Searched,
) -> (Vec<Widening>, Vec<f64>) {
    let mut widened = Vec::new();
    for k in 0..full.dim() {
        if !full.near_bound(k, y) {
            continue;
        }
        let param = full.free()[k];
        // In the parameter's units from the file's bounds, so that the bounds reported and
        // written are the designer's numbers times 1000, not their logarithms' round trip.
        let p = &model.params().params[param];
        let (lower, upper) = (p.lower, p.upper);
        let to_lower = if y[k] - full.lo[k] < 0.05 {
            lower / WIDEN
        } else {
            lower
        };
        let to_upper = if full.hi[k] - y[k] < 0.05 {
            upper * WIDEN
        } else {
            upper
        };
        full.set_bounds(param, to_lower.ln(), to_upper.ln());
        widened.push(Widening {
            param,
            from: (lower, upper),
            to: (to_lower, to_upper),
        });
    }
    if widened.is_empty() {
        return (widened, y.to_vec());
    }
    observer.phase("widen");
    let full: &Cost<'_> = full;
    let method = settings.local();
    let mut y = y.to_vec();
    let step = local::WIDE;
    match parts {
        None => {
            let remaining = settings.max_evals().saturating_sub(searched.evaluations);
            let mut budget = Budget::new(full, remaining.max(1), deadline, observer);
            if let Ok(c) = local::local_search(&mut budget, method, &y, step)
                && c.cost.is_finite()
                && c.cost <= full.score(&y).value
            {
                y = c.point;
            }
            searched.extend(&budget, 0.0);
        }
        Some(parts) => {
            let theta = full.theta(&y);
            for part in parts {
                if !widened.iter().any(|w| part.block.params.contains(&w.param)) {
                    continue;
                }
                let cost = part.cost(model, full, *full.mc(), &theta);
                let remaining = settings.max_evals().saturating_sub(searched.evaluations);
                let mut budget = Budget::new(&cost, remaining.max(1), deadline, observer);
                let from = cost.start();
                let j_from = cost.score(&from).value;
                if let Ok(c) = local::local_search(&mut budget, method, &from, step)
                    && c.cost.is_finite()
                    && c.cost <= j_from
                {
                    for (k, &i) in cost.free().iter().enumerate() {
                        if let Some(f) = full.free().iter().position(|&x| x == i) {
                            y[f] = c.point[k];
                        }
                    }
                }
                searched.extend(&budget, 0.0);
            }
        }
    }
    (widened, y)
}
