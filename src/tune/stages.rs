//! `tune()` as its stages, in order: set up the objective and its cost (the start's
//! evaluation timed, the plan chosen), search, widen a bound the search ended on, refine on
//! the gate's own deviates, confirm on fresh seeds, and judge what the run showed (the
//! resolution and the status).

use std::time::{Duration, Instant};

use nalgebra::{DMatrix, DVector};

use super::budget::Budget;
use super::cost::{Candidate, Cost};
use super::refine::{self, Gate};
use super::result::Confirmation;
use super::separable::{self, Part, Searched};
use super::setup::{bound_flags, default_confirm_seed, exact_scoring};
use super::{
    Objective, Observer, Plan, Resolution, Scoring, Terms, TuneError, TuneResult, TuneSettings,
    TuneStatus, Widening, local,
};
use crate::estimate::{GateRanges, gate_ranges};
use crate::experiment::Experiment;
use crate::montecarlo::{McConfig, TapeUsage};
use crate::stats::{Accumulator, ConsistencyReport, GateMode};

/// One tuning run, its stages in order, without the certification of a misfit (what
/// [`super::tune`] runs first, and [`super::certify`] from each of its starts).
pub(super) fn search(
    model: &dyn Experiment,
    start: &[f64],
    fixed: &[bool],
    mc: &McConfig,
    settings: &TuneSettings,
    observer: &dyn Observer,
) -> Result<TuneResult, TuneError> {
    let mut run = Tuning::set_up(model, start, fixed, mc, settings, observer)?;
    let mut found = run.search(observer);
    run.widen(&mut found, observer);
    run.failed()?;
    let refined = run.refine(&found, observer);
    let confirmed = run.confirm(&refined, observer);
    let resolution = run.resolution(&found, &refined, &confirmed);
    let supported = run.supported(&confirmed);
    run.failed()?;
    let result = run.result(found, refined, confirmed, resolution, supported);
    Ok(result)
}

/// A tuning run's fixed parts, set up before the search: the experiment, the start, the
/// settings the plan chose, and the cost every stage evaluates through.
pub(super) struct Tuning<'a> {
    model: &'a dyn Experiment,
    start: &'a [f64],
    fixed: &'a [bool],
    mc: &'a McConfig,
    settings: TuneSettings,
    exact: bool,
    nis_only: bool,
    search_mc: McConfig,
    cost: Cost<'a>,
    acc0: Accumulator,
    objective_initial: Terms,
    plan: Plan,
    parts: Option<Vec<Part>>,
    t0: Instant,
    deadline: Instant,
    /// The experiment's truth cache before the first evaluation.
    tapes_before: TapeUsage,
}

/// What the search found: its bookkeeping, the best point, the bounds it widened.
pub(super) struct Found {
    searched: Searched,
    best: Candidate,
    widened: Vec<Widening>,
}

/// The point after the refinement, the gate's sensitivity there, and what it cost.
pub(super) struct Refined {
    point: Vec<f64>,
    sens: Option<(DVector<f64>, DMatrix<f64>)>,
    evaluations: usize,
    converged: bool,
}

/// The tuned values and the confirmation they passed or failed.
pub(super) struct Confirmed {
    tuned: Vec<f64>,
    objective_final: Terms,
    confirm_seed: u64,
    before: ConsistencyReport,
    after: ConsistencyReport,
    confirmation: Confirmation,
    deviates: Vec<DVector<f64>>,
    kept_start: bool,
}

impl<'a> Tuning<'a> {
    /// Check the shapes, choose the scoring, build the objective and its cost, evaluate
    /// the start (timed: what one evaluation of the search costs, an external worker's
    /// start-up included) and choose the plan.
    pub(super) fn set_up(
        model: &'a dyn Experiment,
        start: &'a [f64],
        fixed: &'a [bool],
        mc: &'a McConfig,
        settings: &TuneSettings,
        observer: &dyn Observer,
    ) -> Result<Self, TuneError> {
        let t0 = Instant::now();
        let tapes_before = model.tape_usage();
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
        let nis_only = !settings.scores_nees(!model.state_names().is_empty());
        let objective = Objective::new(settings.weights(), nis_only, mc.alpha());
        let mut cost = Cost::new(model, search_mc, exact, objective, start, fixed);
        cost.stop_below = settings.stop_below();
        let t_start = Instant::now();
        let acc0 = cost.accumulate(start);
        let seconds_per_eval = t_start.elapsed().as_secs_f64();
        cost.objective.prepare(&acc0);
        let objective_initial = cost.objective.evaluate(&acc0);
        let plan = settings.plan(
            cost.dim(),
            cost.targets.is_some(),
            exact,
            model.seed_free(),
            seconds_per_eval,
        );
        for note in &plan.notes {
            observer.note(note);
        }
        let settings = settings.clone().with_local(plan.local);
        let deadline = t0 + Duration::from_secs_f64(settings.max_seconds());
        let parts = if cost.dim() > 0 {
            separable::parts(model, fixed, &cost.objective)
        } else {
            None
        };
        Ok(Tuning {
            model,
            start,
            fixed,
            mc,
            settings,
            exact,
            nis_only,
            search_mc,
            cost,
            acc0,
            objective_initial,
            plan,
            parts,
            t0,
            deadline,
            tapes_before,
        })
    }

    /// The search: each decoupled block on its own statistics where the experiment names
    /// blocks, else the global stage and local searches on the whole objective. Exact
    /// scoring is sequential inside, so candidates run in parallel; Monte Carlo scoring is
    /// parallel inside, so candidates run one after another.
    pub(super) fn search(&mut self, observer: &dyn Observer) -> Found {
        let (cost, settings, seed) = (&self.cost, &self.settings, self.mc.seed());
        let searched = match &self.parts {
            Some(parts) => separable::search(
                self.model,
                cost,
                parts,
                self.start,
                &self.acc0,
                settings,
                seed,
                self.deadline,
                observer,
            ),
            None => {
                let mut budget = Budget::new(cost, settings.max_evals(), self.deadline, observer);
                let found = if cost.dim() > 0 {
                    local::search(&mut budget, settings, seed, self.exact, observer)
                } else {
                    None
                };
                Searched::pooled(&budget, found)
            }
        };
        let best = match searched.found.clone() {
            Some(c) => c,
            None if cost.dim() == 0 => Candidate {
                point: Vec::new(),
                cost: self.objective_initial.total,
            },
            None => searched.best.clone().unwrap_or(Candidate {
                point: Vec::new(),
                cost: f64::INFINITY,
            }),
        };
        Found {
            searched,
            best,
            widened: Vec::new(),
        }
    }

    /// A converged search that ends on a bound has not shown that no value fits: the data
    /// may want the parameter beyond it. Widen once and search again before any status.
    /// (A search the experiment failed in has not converged: the failure scores +∞ and
    /// stops it.)
    pub(super) fn widen(&mut self, found: &mut Found, observer: &dyn Observer) {
        if found.searched.found.is_none() || !found.best.cost.is_finite() {
            return;
        }
        let (w, y) = separable::widen_once(
            self.model,
            &mut self.cost,
            self.parts.as_deref(),
            &found.best.point,
            &self.settings,
            self.deadline,
            observer,
            &mut found.searched,
        );
        if !w.is_empty() {
            found.best = Candidate {
                cost: self.cost.score(&y).value,
                point: y,
            };
        }
        found.widened = w;
    }

    /// An error the experiment stored while the stages ran (an external worker broke the
    /// protocol): it ends the run, as any evaluation after it would fail too.
    pub(super) fn failed(&self) -> Result<(), TuneError> {
        match self.cost.failure() {
            Some(e) => Err(e.into()),
            None => Ok(()),
        }
    }

    /// The gate at the problem's N.
    fn gate(&self) -> Gate<'_> {
        Gate::new(self.model, &self.cost, *self.mc, !self.nis_only)
    }

    /// The gate's own deviates at the optimum: how they move with each parameter (for the
    /// refinement and the resolution), on the search's runs from its seed; and under Monte
    /// Carlo scoring, Levenberg–Marquardt steps on them over more runs. Under blocks the
    /// refinement, too, runs block by block on each block's own deviates: the pooled
    /// deviates would move a correct block to compensate a wrong one.
    pub(super) fn refine(&self, found: &Found, observer: &dyn Observer) -> Refined {
        let (cost, mc, best) = (&self.cost, self.mc, &found.best);
        let converged = found.searched.evaluations > 0 && !found.searched.exhausted;
        let sens_runs = self.search_mc.runs();
        let mut point = best.point.clone();
        let mut evaluations = 0;
        let refine_runs = self
            .settings
            .refine_runs()
            .unwrap_or_else(|| sens_runs.saturating_mul(4));
        if let (false, Some(parts), true) =
            (self.exact, &self.parts, converged && best.cost.is_finite())
        {
            observer.phase("refine");
            let theta = cost.theta(&point);
            for part in parts {
                let cb = part.cost(self.model, cost, self.search_mc, &theta);
                let gb = Gate::new(self.model, &cb, *mc, !self.nis_only)
                    .for_block(&part.block.states, &part.block.measurements);
                let yb = cb.start();
                evaluations += yb.len() + 1;
                let Some((_, d)) = refine::sensitivity(&gb, &cb, &yb, sens_runs, mc.seed()) else {
                    continue;
                };
                if d.nrows() == 0 {
                    continue;
                }
                let d_refine = d * (refine_runs as f64 / sens_runs as f64).sqrt();
                let (refined, evals) =
                    refine::refine(&gb, &cb, &yb, &d_refine, refine_runs, mc.seed());
                evaluations += evals;
                for (k, &i) in cb.free().iter().enumerate() {
                    if let Some(f) = cost.free().iter().position(|&x| x == i) {
                        point[f] = refined[k];
                    }
                }
            }
        }
        let gate = self.gate();
        let sens = if converged && !point.is_empty() && best.cost.is_finite() {
            observer.phase("refine");
            evaluations += point.len() + 1;
            refine::sensitivity(&gate, cost, &point, sens_runs, mc.seed())
        } else {
            None
        };
        if let (false, None, Some((_, d))) = (self.exact, &self.parts, &sens) {
            let d_refine = d * (refine_runs as f64 / sens_runs as f64).sqrt();
            let (refined, evals) =
                refine::refine(&gate, cost, &point, &d_refine, refine_runs, mc.seed());
            point = refined;
            evaluations += evals;
        }
        Refined {
            point,
            sens,
            evaluations,
            converged,
        }
    }

    /// The tuned values confirmed on fresh seeds (one record: the record once), with the
    /// start's report beside them. On one record the objective is exact and the gate is one
    /// deterministic test, so a search that ends worse than where it started, or fails the
    /// gate where its start passes, has not found the best fit: the start is kept (often
    /// an estimate from the same record), rather than the conclusion that no value fits.
    pub(super) fn confirm(&self, refined: &Refined, observer: &dyn Observer) -> Confirmed {
        observer.phase("confirm");
        let (cost, start) = (&self.cost, self.start);
        let mut tuned = if refined.point.is_empty() {
            start.to_vec()
        } else {
            cost.theta(&refined.point)
        };
        let gate = self.gate();
        let confirm_seed = self
            .settings
            .confirm_seed()
            .unwrap_or_else(|| default_confirm_seed(self.mc.seed()));
        let recorded = self.model.seed_free();
        let seeds = self.settings.confirm_seeds();
        // Side by side: the final score on the search's runs and the start's report take
        // a thread each while the seeds' reports share the rest.
        let ((mut objective_final, before), (mut confirmation, mut after, mut deviates)) =
            rayon::join(
                || {
                    rayon::join(
                        || cost.objective.evaluate(&cost.accumulate(&tuned)),
                        || gate.report(start, self.mc.runs(), confirm_seed),
                    )
                },
                || refine::confirm(&gate, &tuned, confirm_seed, seeds, recorded),
            );
        let mut kept_start = false;
        if recorded
            && tuned != start
            && (objective_final.total > self.objective_initial.total
                || (!confirmation.holds() && before.verdict.passes()))
        {
            tuned = start.to_vec();
            objective_final = self.objective_initial;
            kept_start = true;
            (confirmation, after, deviates) =
                refine::confirm(&gate, &tuned, confirm_seed, 1, recorded);
        }
        Confirmed {
            tuned,
            objective_final,
            confirm_seed,
            before,
            after,
            confirmation,
            deviates,
            kept_start,
        }
    }

    /// How precisely the gate's data pin each parameter down. It means something only at a
    /// converged optimum, and the seed-to-seed spread it rests on does not exist for one
    /// record (only the bounds are checked).
    pub(super) fn resolution(
        &self,
        found: &Found,
        refined: &Refined,
        confirmed: &Confirmed,
    ) -> Option<Vec<Resolution>> {
        let (cost, point, fixed) = (&self.cost, &refined.point, self.fixed);
        let recorded = self.model.seed_free();
        if confirmed.kept_start {
            None
        } else if recorded && !point.is_empty() && found.best.cost.is_finite() {
            Some(refine::bounds_only(cost, point, fixed))
        } else if recorded || (!refined.converged && cost.dim() > 0) {
            None
        } else if point.is_empty() || !found.best.cost.is_finite() {
            Some(vec![Resolution::FIXED; fixed.len()])
        } else {
            refined.sens.as_ref().map(|(_, d)| {
                let d_n = d * (self.mc.runs() as f64 / self.search_mc.runs() as f64).sqrt();
                refine::resolution(cost, point, &d_n, &confirmed.deviates, fixed)
            })
        }
    }

    /// On one record that passes the gate at the tuned values, the range along each free
    /// parameter over which it still passes (the others at their tuned values): one record
    /// is one deterministic test, so this is what it says of each value's precision.
    pub(super) fn supported(&self, confirmed: &Confirmed) -> Option<GateRanges> {
        if !self.model.seed_free() || !confirmed.confirmation.holds() {
            return None;
        }
        let gate = self.gate();
        let passes = |t: &[f64]| {
            Some(
                gate.report(t, self.mc.runs(), confirmed.confirm_seed)
                    .verdict
                    .passes(),
            )
        };
        Some(gate_ranges(&passes, &confirmed.tuned, self.fixed))
    }

    /// What the run showed. A search that ran out of budget did not converge, whatever the
    /// confirmation says: its values are the best found so far, never reported as the
    /// tuned answer. A parameter still on a bound after its widening was stopped by the
    /// box, as a budget stops a search: "no value of the free parameters fits" would claim
    /// what the search never tried.
    fn status(&self, found: &Found, confirmed: &Confirmed, at_bound: &[bool]) -> TuneStatus {
        let boxed_in = found.widened.iter().any(|w| at_bound[w.param]);
        if self.cost.dim() > 0 && found.searched.evaluations == 0 {
            TuneStatus::BudgetExhausted
        } else if !found.best.cost.is_finite() {
            TuneStatus::Diverged
        } else if found.searched.exhausted {
            TuneStatus::BudgetExhausted
        } else if confirmed.confirmation.holds() {
            TuneStatus::Consistent
        } else if boxed_in {
            TuneStatus::BudgetExhausted
        } else {
            TuneStatus::Inconsistent
        }
    }

    /// The run's result.
    pub(super) fn result(
        self,
        found: Found,
        refined: Refined,
        confirmed: Confirmed,
        resolution: Option<Vec<Resolution>>,
        supported: Option<GateRanges>,
    ) -> TuneResult {
        let at_bound = bound_flags(&self.cost, &confirmed.tuned, self.fixed);
        let status = self.status(&found, &confirmed, &at_bound);
        let (mc, params) = (self.mc, &self.model.params().params);
        TuneResult {
            names: params.iter().map(|p| p.name.clone()).collect(),
            fixed: self.fixed.to_vec(),
            initial: self.start.to_vec(),
            tuned: confirmed.tuned,
            objective_initial: self.objective_initial,
            objective_final: confirmed.objective_final,
            scoring: if self.exact {
                Scoring::Exact
            } else {
                Scoring::MonteCarlo
            },
            local: self.plan.local,
            evaluations: found.searched.evaluations,
            diverged_evaluations: found.searched.diverged,
            history: found.searched.history,
            resolution,
            at_bound,
            widened: found.widened,
            separable: self.parts.is_some(),
            refine_evaluations: refined.evaluations,
            search_seed: mc.seed(),
            confirm_seed: confirmed.confirm_seed,
            confirmation: confirmed.confirmation,
            runs: mc.runs(),
            steps: mc.steps(),
            alpha: mc.alpha(),
            before: confirmed.before,
            after: confirmed.after,
            status,
            supported,
            certificate: None,
            truth: self.model.truth_reuse(self.tapes_before),
            seconds: self.t0.elapsed().as_secs_f64(),
        }
    }
}
