//! What L-BFGS sees: `−log L` over the free parameters' logs, its budget and its
//! differenced gradient.

use argmin::core::{CostFunction, Gradient};

/// Likelihood evaluations one L-BFGS run may spend (a search of a few parameters takes a
/// few hundred): past it the run stops with an error rather than looping (a line search
/// that cannot satisfy its condition).
pub(super) const LBFGS_BUDGET: usize = 20_000;
/// Relative step of the differenced gradient, in log space.
const GRAD_STEP: f64 = 1e-5;

/// What L-BFGS sees: `−log L` over the free parameters' logs.
pub(super) struct Objective<'a> {
    /// `−log L` at θ (`None` where the filter has no likelihood there).
    pub(super) nll: &'a dyn Fn(&[f64]) -> Option<f64>,
    pub(super) theta: Vec<f64>,
    pub(super) free: Vec<usize>,
    /// Measured values in the record.
    pub(super) scale: f64,
    pub(super) evaluations: std::cell::Cell<usize>,
    /// Evaluations after which the running L-BFGS is stopped ([`LBFGS_BUDGET`] past its
    /// start).
    pub(super) budget_end: std::cell::Cell<usize>,
}

impl Objective<'_> {
    pub(super) fn theta_at(&self, phi: &[f64]) -> Vec<f64> {
        let mut t = self.theta.clone();
        for (&i, &p) in self.free.iter().zip(phi) {
            t[i] = p.exp();
        }
        t
    }

    /// `−log L` per measured value: O(1) whatever the record's length, so that L-BFGS's
    /// first step (along the gradient, of unit length) stays within a few e-folds.
    pub(super) fn value(&self, phi: &[f64]) -> f64 {
        self.evaluations.set(self.evaluations.get() + 1);
        if phi.iter().any(|p| p.is_nan() || p.abs() >= 700.0) {
            return f64::MAX;
        }
        (self.nll)(&self.theta_at(phi))
            .filter(|v| v.is_finite())
            .map_or(f64::MAX, |v| v / self.scale)
    }

    /// Central differences; one-sided where one neighbour has no likelihood (a bound the
    /// filter fails past), and zero where neither has: a gradient is always finite, so the
    /// search's steps are (an infinite one would make its line search run forever).
    pub(super) fn gradient_at(&self, phi: &[f64]) -> Vec<f64> {
        let mut g = vec![0.0; phi.len()];
        let mut p = phi.to_vec();
        let mut centre = None;
        for i in 0..phi.len() {
            let h = GRAD_STEP;
            p[i] = phi[i] + h;
            let up = self.value(&p);
            p[i] = phi[i] - h;
            let down = self.value(&p);
            p[i] = phi[i];
            let defined = |v: f64| v < f64::MAX;
            g[i] = match (defined(up), defined(down)) {
                (true, true) => (up - down) / (2.0 * h),
                (false, false) => 0.0,
                (up_ok, _) => {
                    let v = *centre.get_or_insert_with(|| self.value(phi));
                    match (defined(v), up_ok) {
                        (false, _) => 0.0,
                        (true, true) => (up - v) / h,
                        (true, false) => (v - down) / h,
                    }
                }
            };
        }
        g
    }
}

impl CostFunction for &Objective<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, p: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        if self.evaluations.get() >= self.budget_end.get() {
            return Err(argmin::core::Error::msg(format!(
                "L-BFGS spent {LBFGS_BUDGET} likelihood evaluations in one run without stopping"
            )));
        }
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
