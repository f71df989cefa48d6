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

use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use nalgebra::DMatrix;
use serde::Serialize;

use super::{LinearFilterModel, Measurements};

/// Relative step of the differenced gradient, in log space.
const GRAD_STEP: f64 = 1e-5;
/// Step of the differenced Hessian, in log space.
const HESS_STEP: f64 = 1e-3;

/// The maximum-likelihood estimate.
#[derive(Debug, Clone, Serialize)]
pub struct MlEstimate {
    /// Every parameter's value (fixed ones as given).
    pub theta: Vec<f64>,
    /// Standard errors of the free parameters (their units), `None` for fixed ones and for
    /// those not identified.
    pub std_errors: Vec<Option<f64>>,
    /// Free parameters the data cannot pin down (relative standard error above 1, or no
    /// curvature).
    pub not_identified: Vec<usize>,
    /// `−log L` at the estimate.
    pub neg_log_likelihood: f64,
    /// `−log L` at the start.
    pub start_neg_log_likelihood: f64,
    /// L-BFGS iterations.
    pub iterations: u64,
    /// Likelihood evaluations (the gradients' and the Hessian's included).
    pub evaluations: usize,
    /// Whether the search stopped on its tolerance rather than its iteration limit.
    pub converged: bool,
}

/// What L-BFGS sees: `−log L` over the free parameters' logs.
struct Objective<'a> {
    build: &'a dyn Fn(&[f64]) -> LinearFilterModel,
    data: &'a Measurements,
    theta: Vec<f64>,
    free: Vec<usize>,
    /// Measured values in the record.
    scale: f64,
    evaluations: std::cell::Cell<usize>,
}

impl Objective<'_> {
    fn theta_at(&self, phi: &[f64]) -> Vec<f64> {
        let mut t = self.theta.clone();
        for (&i, &p) in self.free.iter().zip(phi) {
            t[i] = p.exp();
        }
        t
    }

    /// `−log L` per measured value: O(1) whatever the record's length, so that L-BFGS's
    /// first step (along the gradient, of unit length) stays within a few e-folds.
    fn value(&self, phi: &[f64]) -> f64 {
        self.evaluations.set(self.evaluations.get() + 1);
        if phi.iter().any(|p| p.is_nan() || p.abs() >= 700.0) {
            return f64::MAX;
        }
        let model = (self.build)(&self.theta_at(phi));
        model
            .neg_log_likelihood(self.data)
            .map_or(f64::MAX, |v| v / self.scale)
    }

    fn gradient_at(&self, phi: &[f64]) -> Vec<f64> {
        let mut g = vec![0.0; phi.len()];
        let mut p = phi.to_vec();
        for i in 0..phi.len() {
            let h = GRAD_STEP;
            p[i] = phi[i] + h;
            let up = self.value(&p);
            p[i] = phi[i] - h;
            let down = self.value(&p);
            p[i] = phi[i];
            g[i] = (up - down) / (2.0 * h);
        }
        g
    }
}

impl CostFunction for &Objective<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, p: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        Ok(self.value(p))
    }
}

impl Gradient for &Objective<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;

    fn gradient(&self, p: &Vec<f64>) -> Result<Vec<f64>, argmin::core::Error> {
        Ok(self.gradient_at(p))
    }
}

/// Maximize the likelihood of `data` over the parameters not `fixed`, from `start` (all
/// positive). `build(θ)` is the filter at θ. `Err` when the start itself has no likelihood
/// (a covariance is not positive definite there) or the search fails.
pub fn estimate(
    build: &dyn Fn(&[f64]) -> LinearFilterModel,
    data: &Measurements,
    start: &[f64],
    fixed: &[bool],
    max_iterations: u64,
) -> Result<MlEstimate, String> {
    let free: Vec<usize> = (0..start.len()).filter(|&i| !fixed[i]).collect();
    let obj = Objective {
        build,
        data,
        theta: start.to_vec(),
        free: free.clone(),
        scale: data.values().max(1) as f64,
        evaluations: std::cell::Cell::new(0),
    };
    let phi0: Vec<f64> = free.iter().map(|&i| start[i].ln()).collect();
    let start_nll = obj.value(&phi0) * obj.scale;
    if start_nll.is_nan() || start_nll >= f64::MAX {
        return Err(
            "the likelihood is not defined at the start values (S is not positive definite)".into(),
        );
    }
    let (phi, iterations, converged) = if free.is_empty() {
        (phi0, 0, true)
    } else {
        let line = MoreThuenteLineSearch::new();
        let solver = LBFGS::new(line, 7)
            .with_tolerance_grad(1e-9)
            .map_err(|e| e.to_string())?
            .with_tolerance_cost(1e-12)
            .map_err(|e| e.to_string())?;
        let res = Executor::new(&obj, solver)
            .configure(|s| s.param(phi0.clone()).max_iters(max_iterations))
            .run()
            .map_err(|e| format!("the likelihood search failed: {e}"))?;
        let st = res.state();
        let best = st.get_best_param().cloned().unwrap_or(phi0);
        let iters = st.get_iter();
        (best, iters, iters < max_iterations)
    };
    let nll = obj.value(&phi) * obj.scale;
    let theta = obj.theta_at(&phi);
    // The observed information in φ, from differences of the gradient.
    let p = free.len();
    let mut hess = DMatrix::<f64>::zeros(p, p);
    let mut at = phi.clone();
    for j in 0..p {
        at[j] = phi[j] + HESS_STEP;
        let up = obj.gradient_at(&at);
        at[j] = phi[j] - HESS_STEP;
        let down = obj.gradient_at(&at);
        at[j] = phi[j];
        for i in 0..p {
            hess[(i, j)] = obj.scale * (up[i] - down[i]) / (2.0 * HESS_STEP);
        }
    }
    let hess = (&hess + hess.transpose()) * 0.5;
    let mut std_errors = vec![None; start.len()];
    let mut not_identified = Vec::new();
    let cov = hess.clone().cholesky().map(|c| c.inverse());
    for (k, &i) in free.iter().enumerate() {
        let rel = cov
            .as_ref()
            .map(|c| c[(k, k)])
            .filter(|v| v.is_finite() && *v > 0.0)
            .map(f64::sqrt);
        match rel {
            Some(r) if r <= 1.0 => std_errors[i] = Some(theta[i] * r),
            _ => not_identified.push(i),
        }
    }
    Ok(MlEstimate {
        theta,
        std_errors,
        not_identified,
        neg_log_likelihood: nll,
        start_neg_log_likelihood: start_nll,
        iterations,
        evaluations: obj.evaluations.get(),
        converged,
    })
}
