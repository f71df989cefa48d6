//! The tuner: searches a problem's free noise parameters for the filter whose consistency
//! statistics sit at their targets, then confirms the winner on fresh Monte Carlo seeds.
//!
//! Search space: the logarithm of each free parameter, inside its bounds (variances span
//! decades; a log scale makes "×2" the same step everywhere). Candidates are scored by
//! [`Objective`] on either the exact expected statistics (linear problems whose filter has
//! the truth's F and H: noise-free and cheap) or a Monte Carlo run with common random
//! numbers (every candidate sees the same draws, so the score is a deterministic function
//! of the parameters). The search is a global stage of quasi-random points in the log box
//! followed by a local search from the best few ([`LocalSearch`]): Nelder–Mead (argmin),
//! each restarted once to polish, or Levenberg–Marquardt on the objective's residuals,
//! first on each parameter's own components and then on the whole objective; a
//! budget in evaluations and seconds bounds it. A candidate whose filter diverges scores
//! +∞ and the search goes on.

pub mod objective;
mod settings;

pub use objective::{Objective, Terms, Weights};
pub use settings::{LocalSearch, Scoring, TuneSettings};

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::Serialize;

use crate::SimRng;
use crate::experiment::Experiment;
use crate::input::SettingError;
use crate::montecarlo::McConfig;
use crate::params::{NoiseKind, Target};
use crate::stats::{Accumulator, ConsistencyReport};

/// How a tuning run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TuneStatus {
    /// The tuned filter passed the confirmation on fresh seeds.
    Consistent,
    /// The search finished but the tuned filter fails the confirmation.
    Inconsistent,
    /// The budget ran out before the search converged (the best point so far is reported).
    BudgetExhausted,
    /// No candidate gave a filter that stayed positive definite.
    Diverged,
}

/// How precisely the data pin down one parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Resolution {
    /// The factor by which the parameter can move (others re-adjusting) before the
    /// objective rises by its Monte Carlo noise level; `None` if fixed.
    pub factor: Option<f64>,
    /// False when that factor exceeds 2 (a flat direction of the objective) or the value
    /// sits on a search bound (the data might want it beyond).
    pub identifiable: bool,
    /// The tuned value is within 5% of its lower or upper search bound.
    pub at_bound: bool,
}

/// Observes a tuning run (progress bars, logs). All methods default to doing nothing.
pub trait Observer: Sync {
    /// Called after each evaluation with the count so far and the best objective value.
    fn evaluation(&self, _evals: usize, _best: f64) {}
    /// Called when a phase starts ("global", "local", "confirm").
    fn phase(&self, _name: &str) {}
}

/// An observer that does nothing.
pub struct Silent;

impl Observer for Silent {}

/// Everything a tuning run found.
#[derive(Debug, Clone, Serialize)]
pub struct TuneResult {
    /// Parameter names, in problem order.
    pub names: Vec<String>,
    /// Which parameters were held fixed.
    pub fixed: Vec<bool>,
    /// Starting values.
    pub initial: Vec<f64>,
    /// Tuned values.
    pub tuned: Vec<f64>,
    /// Objective at the start (as scored in the search).
    pub objective_initial: Terms,
    /// Objective at the tuned values.
    pub objective_final: Terms,
    /// How candidates were scored.
    pub scoring: Scoring,
    /// Evaluations spent by the search.
    pub evaluations: usize,
    /// Candidates whose filter diverged.
    pub diverged_evaluations: usize,
    /// Best objective after each evaluation (for plots).
    pub history: Vec<f64>,
    /// Resolution per parameter.
    pub resolution: Vec<Resolution>,
    /// Objective noise level used for the resolution: the objective of the tuned filter on
    /// the confirmation runs.
    pub noise_floor: f64,
    /// Seed used for the search's Monte Carlo runs (common random numbers).
    pub search_seed: u64,
    /// Seed of the confirmation runs.
    pub confirm_seed: u64,
    /// Monte Carlo settings of the confirmation.
    pub runs: usize,
    /// Steps of the confirmation.
    pub steps: usize,
    /// Significance level.
    pub alpha: f64,
    /// The starting filter on the confirmation seeds.
    pub before: ConsistencyReport,
    /// The tuned filter on the confirmation seeds.
    pub after: ConsistencyReport,
    /// How the run ended.
    pub status: TuneStatus,
    /// Wall time of the search and confirmation, s.
    pub seconds: f64,
}

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
}

/// The seed of the confirmation runs when none is given: a fixed mix of the search seed,
/// never equal to it.
pub fn default_confirm_seed(seed: u64) -> u64 {
    // Flipping bits 0 and 40 changes the seed and keeps it below 2^63 when it was (TOML
    // files store seeds as signed 64-bit integers).
    seed ^ 0x0000_0100_0000_0001
}

struct Search<'a> {
    model: &'a dyn Experiment,
    mc: McConfig,
    exact: bool,
    objective: Objective,
    theta0: Vec<f64>,
    free: Vec<usize>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    evals: AtomicUsize,
    diverged: AtomicUsize,
    best: Mutex<(f64, Vec<f64>)>,
    history: Mutex<Vec<f64>>,
    max_evals: usize,
    deadline: Instant,
    /// Set once an evaluation was refused for the budget.
    out_of_budget: std::sync::atomic::AtomicBool,
    observer: &'a dyn Observer,
    method: LocalSearch,
    /// Per free parameter, the components it drives (all known, or `None`).
    targets: Option<Vec<Target>>,
}

#[derive(Debug)]
struct Budget;

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("budget exhausted")
    }
}

impl std::error::Error for Budget {}

impl Search<'_> {
    /// Full parameter vector from log-values of the free parameters (clamped to the box).
    fn theta(&self, y: &[f64]) -> Vec<f64> {
        let mut t = self.theta0.clone();
        for (k, &i) in self.free.iter().enumerate() {
            t[i] = y[k].clamp(self.lo[k], self.hi[k]).exp();
        }
        t
    }

    fn accumulate(&self, theta: &[f64]) -> Accumulator {
        match self
            .exact
            .then(|| self.model.expected(theta, &self.mc))
            .flatten()
        {
            Some(acc) => acc,
            None => self.model.monte_carlo(theta, &self.mc),
        }
    }

    /// Objective at log-point `y` (clamped into the box), without the penalty.
    fn objective_at(&self, y: &[f64]) -> f64 {
        self.objective
            .evaluate(&self.accumulate(&self.theta(y)))
            .total
    }

    /// Objective at log-point `y`, with a quadratic penalty outside the box so that the
    /// simplex walks back in; no budget accounting.
    fn score(&self, y: &[f64]) -> (f64, bool) {
        let acc = self.accumulate(&self.theta(y));
        let j = self.objective.evaluate(&acc).total;
        let pen: f64 = y
            .iter()
            .enumerate()
            .map(|(k, v)| (self.lo[k] - v).max(0.0).powi(2) + (v - self.hi[k]).max(0.0).powi(2))
            .sum();
        (j + 1e3 * pen, acc.diverged_runs > 0)
    }

    /// Takes one evaluation from the budget, returning its number.
    fn charge(&self) -> Result<usize, Budget> {
        let n = self.evals.fetch_add(1, Ordering::SeqCst);
        if n >= self.max_evals || Instant::now() > self.deadline {
            self.evals.fetch_sub(1, Ordering::SeqCst);
            self.out_of_budget.store(true, Ordering::SeqCst);
            return Err(Budget);
        }
        Ok(n)
    }

    /// Books evaluation `n` at `y` with score `j`: the best point, history and progress.
    fn record(&self, n: usize, y: &[f64], j: f64, diverged: bool) {
        if diverged {
            self.diverged.fetch_add(1, Ordering::SeqCst);
        }
        let best = {
            let mut b = self.best.lock().expect("no panics while holding the lock");
            if j < b.0 {
                *b = (j, y.to_vec());
            }
            b.0
        };
        self.history
            .lock()
            .expect("no panics while holding the lock")
            .push(best);
        self.observer.evaluation(n + 1, best);
    }

    /// Budgeted evaluation: counts, tracks the best point, reports progress.
    fn cost(&self, y: &[f64]) -> Result<f64, Budget> {
        let n = self.charge()?;
        let (j, diverged) = self.score(y);
        self.record(n, y, j, diverged);
        Ok(j)
    }

    /// Budgeted evaluation of a residual vector at `y` (inside the box): J's, or with
    /// `moments` one per free parameter, the mean log ratio of its own components
    /// ([`Search::moments`]). `None` when the filter diverged. The best point is tracked by J.
    fn residuals(&self, y: &[f64], moments: bool) -> Result<Option<Vec<f64>>, Budget> {
        let n = self.charge()?;
        let acc = self.accumulate(&self.theta(y));
        let r = self.objective.residuals(&acc);
        let j = r
            .as_ref()
            .map_or(f64::INFINITY, |r| r.iter().map(|v| v * v).sum());
        self.record(n, y, j, acc.diverged_runs > 0);
        Ok(if moments {
            r.and_then(|_| self.moments(&acc))
        } else {
            r
        })
    }

    /// The moment equations: for each free parameter, the mean over the components it
    /// drives of ln(e_j²/P_jj) (process noise) or ln(ν_j²/S_jj) (measurement noise), zero
    /// when those components are consistent on average. One equation per parameter, each
    /// moved mostly by its own parameter, so unlike J's many residuals they have no
    /// compromise minimum where one parameter stands in for another (a large bias random
    /// walk in place of white accelerometer noise, say).
    fn moments(&self, acc: &Accumulator) -> Option<Vec<f64>> {
        let targets = self.targets.as_ref()?;
        Some(
            targets
                .iter()
                .map(
                    |Target {
                         kind,
                         components: comps,
                     }| {
                        let (total, samples) = match kind {
                            NoiseKind::Process => (&acc.state_comp_total, &acc.state_comp_samples),
                            NoiseKind::Measurement => {
                                (&acc.meas_comp_total, &acc.meas_comp_samples)
                            }
                        };
                        let logs: Vec<f64> = comps
                            .iter()
                            .filter(|&&j| samples.get(j).is_some_and(|&s| s > 0.0))
                            .map(|&j| (total[j] / samples[j]).ln())
                            .collect();
                        if logs.is_empty() {
                            0.0
                        } else {
                            logs.iter().sum::<f64>() / logs.len() as f64
                        }
                    },
                )
                .collect(),
        )
    }

    /// Levenberg–Marquardt on J's residual vector in log-parameters, from `y0`, with a
    /// forward-difference Jacobian (step 0.05, i.e. 5%) and Marquardt's diagonal scaling;
    /// steps are projected into the box. Each iteration costs d + 1 evaluations or a few
    /// more. J is a sum of squared log-ratios that are close to linear in the
    /// log-parameters, so this converges in a handful of iterations where a simplex in 6
    /// dimensions wanders along the valleys that partly interchangeable parameters make.
    /// Returns the best point, its score, and whether the budget stopped it.
    fn levenberg_marquardt(&self, y0: &[f64], moments: bool) -> (Vec<f64>, f64, bool) {
        let d = y0.len();
        let clamp = |y: &[f64]| -> Vec<f64> {
            y.iter()
                .enumerate()
                .map(|(k, v)| v.clamp(self.lo[k], self.hi[k]))
                .collect()
        };
        let sum_sq = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
        let mut y = clamp(y0);
        let mut r = match self.residuals(&y, moments) {
            Err(Budget) => return (y, f64::INFINITY, true),
            Ok(None) => return (y, f64::INFINITY, false),
            Ok(Some(r)) => r,
        };
        let mut j = sum_sq(&r);
        let m = r.len();
        let h = 0.05;
        let mut lambda = 1e-3;
        for _ in 0..40 {
            let mut jac = DMatrix::<f64>::zeros(m, d);
            for k in 0..d {
                let fwd = |step: f64| -> Result<Option<Vec<f64>>, Budget> {
                    let mut v = y.clone();
                    v[k] += step;
                    self.residuals(&v, moments)
                };
                let step = if y[k] + h > self.hi[k] { -h } else { h };
                let (col, step) = match fwd(step) {
                    Err(Budget) => return (y, j, true),
                    Ok(Some(rk)) => (rk, step),
                    // A diverging neighbour: difference on the other side.
                    Ok(None) => match fwd(-step) {
                        Err(Budget) => return (y, j, true),
                        Ok(Some(rk)) => (rk, -step),
                        Ok(None) => continue,
                    },
                };
                if col.len() == m {
                    for i in 0..m {
                        jac[(i, k)] = (col[i] - r[i]) / step;
                    }
                }
            }
            let rv = DVector::from_column_slice(&r);
            let g = jac.tr_mul(&rv);
            let a = jac.tr_mul(&jac);
            let diag_max = (0..d).map(|k| a[(k, k)]).fold(0.0_f64, f64::max);
            if diag_max <= 0.0 {
                return (y, j, false);
            }
            let mut accepted = None;
            for _ in 0..12 {
                let mut lhs = a.clone();
                for k in 0..d {
                    lhs[(k, k)] += lambda * a[(k, k)].max(1e-9 * diag_max);
                }
                let Some(chol) = lhs.cholesky() else {
                    lambda *= 4.0;
                    continue;
                };
                let mut delta = chol.solve(&(-&g));
                // Trust at most a factor e² per iteration in any parameter.
                let big = delta.amax();
                if big > 2.0 {
                    delta *= 2.0 / big;
                }
                let trial = clamp(
                    &y.iter()
                        .zip(delta.iter())
                        .map(|(a, b)| a + b)
                        .collect::<Vec<_>>(),
                );
                match self.residuals(&trial, moments) {
                    Err(Budget) => return (y, j, true),
                    Ok(Some(rt)) if rt.len() == m && sum_sq(&rt) < j => {
                        accepted = Some((trial, rt));
                        lambda = (lambda / 3.0).max(1e-9);
                        break;
                    }
                    Ok(_) => lambda *= 4.0,
                }
            }
            let Some((trial, rt)) = accepted else {
                return (y, j, false);
            };
            let moved = max_abs_diff(&trial, &y);
            let j_new = sum_sq(&rt);
            let gain = j - j_new;
            y = trial;
            r = rt;
            j = j_new;
            if moved < 1e-3 || gain < 1e-4 * j + 1e-12 {
                break;
            }
        }
        (y, j, false)
    }

    /// Nelder–Mead from `y0` with initial steps `step` (log units). Returns the best point
    /// it found with its score, and whether it stopped for the budget (then the point is
    /// the start, and the shared best point is the fallback).
    fn nelder_mead(&self, y0: &[f64], step: f64) -> (Vec<f64>, f64, bool) {
        let d = y0.len();
        let mut simplex = vec![y0.to_vec()];
        for k in 0..d {
            let mut v = y0.to_vec();
            v[k] += if v[k] + step > self.hi[k] {
                -step
            } else {
                step
            };
            simplex.push(v);
        }
        let failed = (y0.to_vec(), f64::INFINITY, true);
        if self.out_of_budget.load(Ordering::SeqCst) {
            return failed;
        }
        let Ok(solver) = NelderMead::new(simplex).with_sd_tolerance(1e-10) else {
            return failed;
        };
        let problem = LocalProblem { search: self };
        let res = Executor::new(problem, solver)
            .configure(|s| s.max_iters((200 * d.max(1)) as u64))
            .run();
        let hit = self.out_of_budget.load(Ordering::SeqCst);
        match res {
            Ok(r) => {
                let st = r.state();
                let y = st.get_best_param().cloned().unwrap_or_else(|| y0.to_vec());
                (y, st.get_best_cost(), hit)
            }
            Err(_) => failed,
        }
    }

    /// One local search from `y0`. Simplex: Nelder–Mead, then a restart with a small simplex
    /// to polish (a restart undoes Nelder–Mead's occasional collapse onto a subspace).
    /// Gauss–Newton: Levenberg–Marquardt, falling back to the simplex if `y0` diverges.
    fn local(&self, y0: &[f64]) -> (Vec<f64>, f64, bool) {
        let (y1, c1, hit) = match self.method {
            LocalSearch::GaussNewton => {
                let mut y0 = y0.to_vec();
                if self.targets.is_some() {
                    let (y, c, hit) = self.levenberg_marquardt(&y0, true);
                    if hit {
                        return (y, f64::INFINITY, true);
                    }
                    if c.is_finite() {
                        y0 = y;
                    }
                }
                let (y, c, hit) = self.levenberg_marquardt(&y0, false);
                if hit || c.is_finite() {
                    return (y, c, hit);
                }
                self.nelder_mead(&y0, 0.7)
            }
            LocalSearch::Simplex => self.nelder_mead(y0, 0.7),
        };
        if hit {
            return (y1, c1, true);
        }
        let (y2, c2, hit) = self.nelder_mead(&y1, 0.1);
        if c2 < c1 {
            (y2, c2, hit)
        } else {
            (y1, c1, hit)
        }
    }
}

struct LocalProblem<'a, 'b> {
    search: &'a Search<'b>,
}

impl CostFunction for LocalProblem<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, p: &Self::Param) -> Result<f64, argmin::core::Error> {
        // Out of budget, every point scores +∞: argmin's Nelder–Mead unwraps the costs of
        // its starting simplex, so an error here would be a panic, and +∞ lets the simplex
        // finish harmlessly while `out_of_budget` records why.
        Ok(self.search.cost(p).unwrap_or(f64::INFINITY))
    }
}

/// Largest coordinate difference of two log-points (log units).
fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
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
    let free: Vec<usize> = (0..params.len()).filter(|&i| !fixed[i]).collect();
    let probe = McConfig::new(1, 1)?.with_seed(mc.seed());
    let exact_available = model.expected(start, &probe).is_some();
    let exact = match settings.scoring() {
        Scoring::Auto => exact_available,
        Scoring::Exact => {
            if !exact_available {
                return Err(SettingError::new(
                    "scoring",
                    "exact scoring needs a linear filter that uses the truth's F and H",
                )
                .into());
            }
            true
        }
        Scoring::MonteCarlo => false,
    };
    let search_mc = if exact {
        *mc
    } else {
        mc.with_runs(settings.search_runs().unwrap_or(4 * mc.runs()))?
    };
    let mut search = Search {
        model,
        mc: search_mc,
        exact,
        objective: Objective::new(settings.weights(), settings.nis_only(), mc.alpha()),
        theta0: start.to_vec(),
        lo: free.iter().map(|&i| params[i].lower.ln()).collect(),
        hi: free.iter().map(|&i| params[i].upper.ln()).collect(),
        evals: AtomicUsize::new(0),
        diverged: AtomicUsize::new(0),
        best: Mutex::new((f64::INFINITY, Vec::new())),
        history: Mutex::new(Vec::new()),
        max_evals: settings.max_evals(),
        deadline: t0 + Duration::from_secs_f64(settings.max_seconds()),
        out_of_budget: std::sync::atomic::AtomicBool::new(false),
        observer,
        method: settings.local(),
        targets: free
            .iter()
            .map(|&i| model.target(i).filter(|t| !t.components.is_empty()))
            .collect(),
        free,
    };
    let y0: Vec<f64> = search.free.iter().map(|&i| start[i].ln()).collect();
    let acc0 = search.accumulate(start);
    search.objective.prepare(&acc0);
    let objective_initial = search.objective.evaluate(&acc0);
    let d = y0.len();

    let mut budget_hit = false;
    let mut local_best: Option<(f64, Vec<f64>)> = None;
    if d > 0 {
        // Global stage. Exact scoring is sequential inside, so candidates run in parallel;
        // Monte Carlo scoring is parallel inside, so candidates run one after another.
        observer.phase("global");
        let unit = latin_hypercube(settings.global_points() * d, d, mc.seed());
        let mut points: Vec<Vec<f64>> = vec![y0.clone()];
        points.extend(unit.iter().map(|u| {
            u.iter()
                .enumerate()
                .map(|(k, v)| search.lo[k] + v * (search.hi[k] - search.lo[k]))
                .collect()
        }));
        let scored: Vec<(f64, Vec<f64>)> = if exact {
            points
                .into_par_iter()
                .filter_map(|y| search.cost(&y).ok().map(|j| (j, y)))
                .collect()
        } else {
            points
                .into_iter()
                .filter_map(|y| search.cost(&y).ok().map(|j| (j, y)))
                .collect()
        };
        let mut scored: Vec<(f64, Vec<f64>)> =
            scored.into_iter().filter(|(j, _)| j.is_finite()).collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0));
        // Gauss–Newton stays in the basin it starts in, and the user's start is usually a
        // better-informed guess than a quasi-random point, so it is always one of the starts.
        let mut starts: Vec<Vec<f64>> = match settings.local() {
            LocalSearch::GaussNewton => vec![y0.clone()],
            LocalSearch::Simplex => Vec::new(),
        };
        for (_, y) in &scored {
            if starts.len() >= settings.starts() {
                break;
            }
            let distinct = starts.iter().all(|s| max_abs_diff(s, y) > 0.5);
            if distinct {
                starts.push(y.clone());
            }
        }
        if starts.is_empty() {
            starts.push(y0.clone());
        }
        observer.phase("local");
        // Each start's search depends only on its start, and results are compared in start
        // order, so the outcome does not depend on the thread count (unless the budget runs
        // out mid-way, when the best point seen so far is taken).
        let results: Vec<(Vec<f64>, f64, bool)> = if exact {
            starts.par_iter().map(|s| search.local(s)).collect()
        } else {
            starts.iter().map(|s| search.local(s)).collect()
        };
        budget_hit = results.iter().any(|r| r.2) || search.out_of_budget.load(Ordering::SeqCst);
        let mut best: Option<(Vec<f64>, f64)> = None;
        for (y, c, _) in results {
            if c.is_finite() && best.as_ref().is_none_or(|b| c < b.1) {
                best = Some((y, c));
            }
        }
        // The simplex restarts once more from the best point; Levenberg–Marquardt has
        // converged where it stopped, and a restart would only repeat it.
        if let Some((y, c)) = best
            && !budget_hit
        {
            local_best = Some(if settings.local() == LocalSearch::Simplex {
                let (y2, c2, hit) = search.local(&y);
                budget_hit |= hit;
                if c2 < c { (c2, y2) } else { (c, y) }
            } else {
                (c, y)
            });
        }
    }
    budget_hit |= search.out_of_budget.load(Ordering::SeqCst);
    let (best_j, best_y) = match local_best {
        Some(b) if !budget_hit => b,
        _ if d == 0 => (objective_initial.total, y0.clone()),
        _ => search.best.lock().expect("lock").clone(),
    };
    let tuned = if best_y.is_empty() {
        start.to_vec()
    } else {
        search.theta(&best_y)
    };
    let objective_final = search.objective.evaluate(&search.accumulate(&tuned));

    // Confirmation on fresh seeds.
    observer.phase("confirm");
    let confirm_seed = settings
        .confirm_seed()
        .unwrap_or_else(|| default_confirm_seed(mc.seed()));
    let cmc = mc.with_seed(confirm_seed);
    let use_nees = !settings.nis_only();
    let report = |theta: &[f64]| {
        let acc = model.monte_carlo(theta, &cmc);
        let r = ConsistencyReport::from_accumulator(
            &acc,
            cmc.alpha(),
            model.state_names(),
            model.measurement_names(),
            use_nees,
        );
        (r, search.objective.evaluate(&acc).total)
    };
    let (before, _) = report(start);
    let (after, noise) = report(&tuned);
    let noise_floor = if noise.is_finite() {
        noise.max(1e-9)
    } else {
        1e-9
    };

    // The curvature says something only at a converged optimum.
    let resolution = if best_y.is_empty() || !best_j.is_finite() || budget_hit {
        (0..params.len())
            .map(|_| Resolution {
                factor: None,
                identifiable: true,
                at_bound: false,
            })
            .collect()
    } else {
        resolution(&search, &best_y, noise_floor, fixed)
    };

    let status = if !best_j.is_finite() {
        TuneStatus::Diverged
    } else if after.verdict.passes() {
        TuneStatus::Consistent
    } else if budget_hit {
        TuneStatus::BudgetExhausted
    } else {
        TuneStatus::Inconsistent
    };
    let history = search.history.lock().expect("lock").clone();
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
        evaluations: search.evals.load(Ordering::SeqCst),
        diverged_evaluations: search.diverged.load(Ordering::SeqCst),
        history,
        resolution,
        noise_floor,
        search_seed: mc.seed(),
        confirm_seed,
        runs: cmc.runs(),
        steps: cmc.steps(),
        alpha: cmc.alpha(),
        before,
        after,
        status,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Per-parameter resolution from the objective's curvature at the optimum: with Hessian H
/// in log-parameters, the objective rises by `δ²/(2 (H⁻¹)_ii)` when parameter i moves by δ
/// and the others re-adjust; solving for a rise equal to the noise floor gives
/// `δ_i = √(2 floor (H⁻¹)_ii)` and the factor `e^{δ_i}`.
fn resolution(search: &Search<'_>, y: &[f64], floor: f64, fixed: &[bool]) -> Vec<Resolution> {
    let d = y.len();
    let h = 0.05;
    let f = |v: &[f64]| search.objective_at(v);
    let f0 = f(y);
    let mut hess = DMatrix::zeros(d, d);
    let shift = |a: usize, sa: f64, b: Option<(usize, f64)>| {
        let mut v = y.to_vec();
        v[a] += sa;
        if let Some((bi, sb)) = b {
            v[bi] += sb;
        }
        v
    };
    for a in 0..d {
        let fp = f(&shift(a, h, None));
        let fm = f(&shift(a, -h, None));
        hess[(a, a)] = (fp - 2.0 * f0 + fm) / (h * h);
        for b in 0..a {
            let fpp = f(&shift(a, h, Some((b, h))));
            let fpm = f(&shift(a, h, Some((b, -h))));
            let fmp = f(&shift(a, -h, Some((b, h))));
            let fmm = f(&shift(a, -h, Some((b, -h))));
            let v = (fpp - fpm - fmp + fmm) / (4.0 * h * h);
            hess[(a, b)] = v;
            hess[(b, a)] = v;
        }
    }
    let eig = SymmetricEigen::new(hess);
    let lmax = eig.eigenvalues.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let floor_l = (1e-12 * lmax).max(1e-300);
    let inv_diag: Vec<f64> = (0..d)
        .map(|i| {
            (0..d)
                .map(|k| eig.eigenvectors[(i, k)].powi(2) / eig.eigenvalues[k].max(floor_l))
                .sum()
        })
        .collect();
    let mut out = Vec::with_capacity(fixed.len());
    let mut k = 0;
    for &fx in fixed {
        if fx {
            out.push(Resolution {
                factor: None,
                identifiable: true,
                at_bound: false,
            });
        } else {
            let delta = (2.0 * floor * inv_diag[k]).sqrt();
            let factor = delta.exp();
            let at_bound = y[k] - search.lo[k] < 0.05 || search.hi[k] - y[k] < 0.05;
            out.push(Resolution {
                factor: Some(factor),
                identifiable: factor.is_finite() && factor <= 2.0 && !at_bound,
                at_bound,
            });
            k += 1;
        }
    }
    out
}
