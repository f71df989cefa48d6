//! Maximum likelihood: the free noise parameters that maximize the exact likelihood of the
//! filter over the record, searched by L-BFGS (argmin) in log space, with standard errors from
//! the observed information.
//!
//! In `φ = log θ` every candidate is positive, so Q and R built as positive sums of PSD terms
//! stay PSD and no step can make the filter's covariances indefinite (EM's unguarded
//! updates can). Gradients are central differences in φ with a relative step of 1e-5: the
//! negative log-likelihood is a smooth sum computed to about 1e-13 relative, so their error
//! is some 1e-6 of its scale, far below what the line search resolves. The observed
//! information is the Hessian of `−log L` in φ (differences of the gradient); its inverse is
//! the covariance of φ̂, and `se(θ̂_i) = θ̂_i √[H⁻¹]_ii` (the delta method). A parameter whose
//! relative standard error exceeds 1 (the data cannot tell θ from e·θ), or whose direction
//! the Hessian does not curve along, is reported as not identified.

use argmin::core::{Executor, State};
use argmin::solver::linesearch::BacktrackingLineSearch;
use argmin::solver::linesearch::condition::ArmijoCondition;
use argmin::solver::quasinewton::LBFGS;
use serde::Serialize;

mod check;
mod objective;

use check::Check;
pub use check::PREDICTED_TOL;
use objective::{LBFGS_BUDGET, Objective};

use super::{EstimateError, MeasurementRecord};
use crate::filter::KalmanFilter;

/// The maximum-likelihood estimate.
#[derive(Debug, Clone, Serialize)]
pub struct MlEstimate {
    /// Every parameter's value (fixed ones as given).
    pub theta: Vec<f64>,
    /// Standard errors of the free parameters (their units), `None` for fixed ones and for
    /// those not identified.
    pub std_errors: Vec<Option<f64>>,
    /// Free parameters the data cannot pin down (relative standard error above 1, or no
    /// curvature), apart from those at their bound.
    pub not_identified: Vec<usize>,
    /// Free parameters at their bound, zero: setting one to 0 changes `−log L` by less than
    /// a thousandth of a nat. The others' standard errors come from the information with
    /// these left out.
    pub at_bound: Vec<usize>,
    /// `−log L` at the estimate.
    pub neg_log_likelihood: f64,
    /// `−log L` at the start.
    pub start_neg_log_likelihood: f64,
    /// L-BFGS iterations, over every restart.
    pub iterations: u64,
    /// L-BFGS restarts after the first stop.
    pub restarts: u32,
    /// Newton steps after the restarts.
    pub newton_steps: u32,
    /// Likelihood evaluations (the gradients' and the Hessian's included).
    pub evaluations: usize,
    /// Whether the estimate is checked to be the maximum: the quadratic model at it predicts
    /// less than [`PREDICTED_TOL`] nats still to gain, over the parameters not at their
    /// bound, with a positive definite information.
    pub converged: bool,
    /// Gradient of `−log L` in log θ at the estimate, one per free parameter (nats).
    pub gradient: Vec<f64>,
    /// `½ g' H⁻¹ g`: what the quadratic model still predicts to gain (nats; infinite, null
    /// in JSON, when the information is not positive definite).
    pub predicted_improvement: f64,
    /// Free parameters left near zero although the likelihood pulls them up (the search
    /// did not get them out): the estimate is then not converged.
    pub stuck: Vec<usize>,
}

/// Maximize the likelihood of `data` over the parameters not `fixed`, from `start` (all
/// positive). `build(θ)` is the filter at θ. `Err` when the start itself has no likelihood
/// (a covariance is not positive definite there) or the search fails.
///
/// L-BFGS (a backtracking Armijo line search, which evaluates only `−log L` at its trial
/// points) stops on its own tolerances, which say nothing about the likelihood's maximum (a
/// line search that gives up, or a stall in a flat valley, stops it as well). So its stop is
/// followed by Newton steps on the differenced Hessian, until the improvement the quadratic
/// model still predicts, `½ g' H⁻¹ g`, is below [`PREDICTED_TOL`] nats; where they do not get
/// there, by restarts from the point reached, with fresh memory, until a restart no longer
/// moves, and Newton steps again. Only the Newton check makes `converged` true.
/// `max_iterations` bounds the L-BFGS iterations of all restarts.
pub fn estimate(
    build: &dyn Fn(&[f64]) -> KalmanFilter,
    data: &MeasurementRecord,
    start: &[f64],
    fixed: &[bool],
    max_iterations: u64,
) -> Result<MlEstimate, EstimateError> {
    let nll = |t: &[f64]| build(t).neg_log_likelihood(data).ok();
    estimate_by(&nll, data.values(), start, fixed, max_iterations)
}

/// [`estimate`] of any filter whose `−log L` at θ is `nll(θ)` (`None` where it has none),
/// over a record of `values` measured values (the objective's scale): a filter held as
/// code replayed over a record ([`super::FilterReplay::neg_log_likelihood`]).
pub fn estimate_by(
    nll: &dyn Fn(&[f64]) -> Option<f64>,
    values: usize,
    start: &[f64],
    fixed: &[bool],
    max_iterations: u64,
) -> Result<MlEstimate, EstimateError> {
    let free: Vec<usize> = (0..start.len()).filter(|&i| !fixed[i]).collect();
    let obj = Objective {
        nll,
        theta: start.to_vec(),
        free: free.clone(),
        scale: values.max(1) as f64,
        evaluations: std::cell::Cell::new(0),
        budget_end: std::cell::Cell::new(usize::MAX),
    };
    let phi0: Vec<f64> = free.iter().map(|&i| start[i].ln()).collect();
    let start_nll = obj.value(&phi0) * obj.scale;
    if start_nll.is_nan() || start_nll >= f64::MAX {
        return Err(EstimateError::UndefinedAtStart);
    }
    let mut search = Search {
        obj: &obj,
        phi: phi0,
        nll: start_nll,
        iterations: 0,
        restarts: 0,
        newton: 0,
        escapes: 0,
        max_iterations,
    };
    let mut first_round = true;
    let check = loop {
        let round_start = search.nll;
        // The first round trusts L-BFGS's stop as far as the Newton check after it: a stop
        // short of the maximum fails that check, and the next round restarts until still.
        if !free.is_empty() {
            search.lbfgs_until_still(first_round)?;
        }
        first_round = false;
        let check = search.newton_steps();
        // A parameter walked so close to zero that its log no longer feels the pull back
        // up: in φ its gradient is θ times the pull, and the quadratic model there predicts
        // nothing. Put it back where the likelihood along θ is best, and search again.
        if check.converged() || search.escapes >= MAX_ESCAPES || search.iterations >= max_iterations
        {
            break check;
        }
        search.escapes += 1;
        let moved_back = search.free_stuck(&check.stuck, start, &free);
        if !(search.nll < round_start - RESTART_TOL || moved_back) {
            break check;
        }
    };
    let theta = obj.theta_at(&search.phi);
    let mut std_errors = vec![None; start.len()];
    let mut not_identified = Vec::new();
    let at_bound: Vec<usize> = check.at_bound.iter().map(|&k| free[k]).collect();
    let rel = check.relative_errors();
    for (k, &i) in free.iter().enumerate() {
        if check.at_bound.contains(&k) {
            continue;
        }
        match rel[k] {
            Some(r) if r <= 1.0 => std_errors[i] = Some(theta[i] * r),
            _ => not_identified.push(i),
        }
    }
    let gradient: Vec<f64> = check.gradient.clone();
    Ok(MlEstimate {
        theta,
        std_errors,
        not_identified,
        at_bound,
        neg_log_likelihood: search.nll,
        start_neg_log_likelihood: start_nll,
        iterations: search.iterations,
        restarts: search.restarts,
        newton_steps: search.newton,
        evaluations: obj.evaluations.get(),
        converged: check.converged(),
        stuck: check.stuck.iter().map(|&k| free[k]).collect(),
        gradient,
        predicted_improvement: check.predicted,
    })
}

/// Where the likelihood search is (φ, its `−log L`) and what it has spent.
struct Search<'a, 'b> {
    obj: &'a Objective<'b>,
    phi: Vec<f64>,
    nll: f64,
    iterations: u64,
    restarts: u32,
    newton: u32,
    escapes: u32,
    max_iterations: u64,
}

impl Search<'_, '_> {
    /// L-BFGS from the point reached: with `once`, a single run (the Newton check after it
    /// decides whether its stop was the maximum); otherwise restarted with fresh memory until
    /// a restart no longer moves (at least one restart), the iterations run out, or
    /// [`MAX_RESTARTS`].
    fn lbfgs_until_still(&mut self, once: bool) -> Result<(), EstimateError> {
        let mut first = true;
        loop {
            let (next, its) = lbfgs(
                self.obj,
                self.phi.clone(),
                self.max_iterations - self.iterations,
            )?;
            self.iterations += its;
            let next_nll = self.obj.value(&next) * self.obj.scale;
            let moved = self.nll - next_nll;
            if next_nll < self.nll {
                self.phi = next;
                self.nll = next_nll;
            }
            if once
                || (!first && moved < RESTART_TOL)
                || self.iterations >= self.max_iterations
                || self.restarts >= MAX_RESTARTS
            {
                return Ok(());
            }
            first = false;
            self.restarts += 1;
        }
    }

    /// Newton steps (halved until they gain) until the quadratic model predicts nothing
    /// left to gain; the check at the point reached.
    fn newton_steps(&mut self) -> Check {
        let mut check = Check::at(self.obj, &self.phi);
        let mut steps = 0;
        while check.predicted >= PREDICTED_TOL && steps < MAX_NEWTON {
            let Some(step) = check.newton_step() else {
                break;
            };
            let mut t = 1.0;
            let mut moved = false;
            for _ in 0..30 {
                let trial: Vec<f64> = self.phi.iter().zip(&step).map(|(p, s)| p + t * s).collect();
                let v = self.obj.value(&trial) * self.obj.scale;
                if v < self.nll {
                    self.phi = trial;
                    self.nll = v;
                    moved = true;
                    break;
                }
                t *= 0.5;
            }
            steps += 1;
            self.newton += 1;
            if !moved {
                break;
            }
            check = Check::at(self.obj, &self.phi);
        }
        check
    }

    /// Put each `stuck` free parameter (index into `free`) back where the likelihood along
    /// θ is best, halving from its start value; whether any moved.
    fn free_stuck(&mut self, stuck: &[usize], start: &[f64], free: &[usize]) -> bool {
        let mut improved = false;
        for &k in stuck {
            let mut best = (self.nll, self.phi[k]);
            for j in 0..40 {
                let mut trial = self.phi.clone();
                trial[k] = start[free[k]].ln() - j as f64 * std::f64::consts::LN_2;
                let v = self.obj.value(&trial) * self.obj.scale;
                if v < best.0 {
                    best = (v, trial[k]);
                }
            }
            if best.0 < self.nll {
                self.nll = best.0;
                self.phi[k] = best.1;
                improved = true;
            }
        }
        improved
    }
}

/// A restart that gains less than this (nats) no longer moves: `−log L` of a record of
/// 10⁵ values is computed to some 1e-11 nats, so this is well above its noise.
const RESTART_TOL: f64 = 1e-9;
/// Restarts of L-BFGS after its first stop.
const MAX_RESTARTS: u32 = 20;
/// Newton steps after the restarts (each round).
const MAX_NEWTON: u32 = 20;
/// Rounds of restarts and Newton steps after the first that did not converge (a parameter
/// stuck near zero is put back first).
const MAX_ESCAPES: u32 = 5;

/// One L-BFGS run from `phi0` with fresh memory: the best point and the iterations taken.
fn lbfgs(
    obj: &Objective<'_>,
    phi0: Vec<f64>,
    max_iters: u64,
) -> Result<(Vec<f64>, u64), EstimateError> {
    obj.budget_end
        .set(obj.evaluations.get().saturating_add(LBFGS_BUDGET));
    let line = BacktrackingLineSearch::new(ArmijoCondition::new(1e-4).expect("in (0, 1)"));
    // argmin refuses only negative tolerances.
    let solver = LBFGS::new(line, 7)
        .with_tolerance_grad(1e-9)
        .expect("a positive gradient tolerance")
        .with_tolerance_cost(1e-12)
        .expect("a positive cost tolerance");
    let res = Executor::new(obj, solver)
        .configure(|s| s.param(phi0.clone()).max_iters(max_iters))
        .run()
        .map_err(|e| EstimateError::SearchFailed(e.to_string()))?;
    let st = res.state();
    let best = st.get_best_param().cloned().unwrap_or(phi0);
    Ok((best, st.get_iter()))
}
