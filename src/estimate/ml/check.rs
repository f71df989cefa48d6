//! The convergence check at a point of the likelihood's search: the gradient, the observed
//! information, and whether a Newton step would still gain.

use nalgebra::{DMatrix, DVector};

use super::objective::Objective;

/// The estimate has converged when the quadratic model of `−log L` predicts less than this
/// (nats) still to gain: a millionth of a nat is far below anything a likelihood-ratio
/// test or a standard error can tell.
pub const PREDICTED_TOL: f64 = 1e-6;
/// Step of the differenced Hessian, in log space.
const HESS_STEP: f64 = 1e-3;
/// A parameter whose removal (θ_i = 0) changes `−log L` by less than this (nats) is at its
/// bound: the data cannot tell it from zero, and its log would walk to −∞.
const AT_BOUND_TOL: f64 = 1e-3;

/// The convergence check at one point: the gradient and the observed information of
/// `−log L` (nats) in φ over the free parameters not at their bound.
pub(super) struct Check {
    /// Gradient of `−log L` in φ, every free parameter (nats per e-fold).
    pub(super) gradient: Vec<f64>,
    /// Indices (into the free parameters) at their bound.
    pub(super) at_bound: Vec<usize>,
    /// Indices (into the free parameters) near zero whose likelihood pulls them up.
    pub(super) stuck: Vec<usize>,
    /// Indices (into the free parameters) not at their bound.
    pub(super) active: Vec<usize>,
    /// Observed information over `active`.
    pub(super) hess: DMatrix<f64>,
    /// `½ g' H⁻¹ g` over `active` (nats); infinite where H is not positive definite.
    pub(super) predicted: f64,
}

impl Check {
    pub(super) fn at(obj: &Objective<'_>, phi: &[f64]) -> Check {
        let p = phi.len();
        let base = obj.value(phi);
        let gradient: Vec<f64> = obj.gradient_at(phi).iter().map(|g| g * obj.scale).collect();
        // A parameter is at its bound when setting it to zero costs (almost) nothing and
        // the likelihood does not pull it up.
        // The pull is the derivative in θ at zero (in φ it vanishes with θ), differenced
        // over a millionth of the parameter's start value.
        let mut at_bound = Vec::new();
        let mut stuck = Vec::new();
        let nll_at = |k: usize, v: f64| {
            let mut t = obj.theta_at(phi);
            t[obj.free[k]] = v;
            obj.evaluations.set(obj.evaluations.get() + 1);
            (obj.nll)(&t)
        };
        for (k, &g) in gradient.iter().enumerate() {
            if g < -AT_BOUND_TOL {
                continue;
            }
            let Some(zero) = nll_at(k, 0.0) else {
                continue;
            };
            // Better at zero is no bound either: the point is not the maximum yet.
            if (zero - base * obj.scale).abs() >= AT_BOUND_TOL {
                continue;
            }
            let eps = 1e-6 * obj.theta[obj.free[k]];
            match nll_at(k, eps) {
                Some(v) if v < zero - 1e-11 * (1.0 + zero.abs()) => stuck.push(k),
                _ => at_bound.push(k),
            }
        }
        let active: Vec<usize> = (0..p).filter(|k| !at_bound.contains(k)).collect();
        let q = active.len();
        let mut hess = DMatrix::<f64>::zeros(q, q);
        let mut at = phi.to_vec();
        for (c, &j) in active.iter().enumerate() {
            at[j] = phi[j] + HESS_STEP;
            let up = obj.gradient_at(&at);
            at[j] = phi[j] - HESS_STEP;
            let down = obj.gradient_at(&at);
            at[j] = phi[j];
            for (r, &i) in active.iter().enumerate() {
                hess[(r, c)] = obj.scale * (up[i] - down[i]) / (2.0 * HESS_STEP);
            }
        }
        let hess = (&hess + hess.transpose()) * 0.5;
        let g = DVector::from_iterator(q, active.iter().map(|&k| gradient[k]));
        let predicted = match hess.clone().cholesky() {
            Some(c) => 0.5 * g.dot(&c.solve(&g)),
            None if q == 0 => 0.0,
            None => f64::INFINITY,
        };
        Check {
            gradient,
            at_bound,
            stuck,
            active,
            hess,
            predicted,
        }
    }

    pub(super) fn converged(&self) -> bool {
        self.predicted.is_finite() && self.predicted < PREDICTED_TOL && self.stuck.is_empty()
    }

    /// The Newton step over every free parameter (zero for those at their bound); where H
    /// is not positive definite, a steepest-descent step of unit length in φ.
    pub(super) fn newton_step(&self) -> Option<Vec<f64>> {
        let q = self.active.len();
        if q == 0 {
            return None;
        }
        let g = DVector::from_iterator(q, self.active.iter().map(|&k| self.gradient[k]));
        // Where H is not positive definite (a saddle, or a ridge), the step along each
        // eigenvector is scaled by |λ| instead (floored), so that it goes downhill and away
        // from the saddle rather than towards it.
        let d = match self.hess.clone().cholesky() {
            Some(c) => -c.solve(&g),
            None => {
                let eig = self.hess.clone().symmetric_eigen();
                let top = eig.eigenvalues.amax();
                if !(top > 0.0 && top.is_finite()) {
                    return None;
                }
                let mut d = DVector::<f64>::zeros(q);
                for (i, l) in eig.eigenvalues.iter().enumerate() {
                    let v = eig.eigenvectors.column(i);
                    d -= v * (v.dot(&g) / l.abs().max(1e-6 * top));
                }
                d
            }
        };
        let mut step = vec![0.0; self.gradient.len()];
        for (r, &k) in self.active.iter().enumerate() {
            step[k] = d[r];
        }
        step.iter().all(|v| v.is_finite()).then_some(step)
    }

    /// `√[H⁻¹]_kk` (the relative standard error of θ_k) for each free parameter; `None` at
    /// the bound, and for a parameter along a direction the information does not curve
    /// (those are dropped, and the others' errors come from what is left).
    pub(super) fn relative_errors(&self) -> Vec<Option<f64>> {
        let mut out = vec![None; self.gradient.len()];
        let mut keep: Vec<usize> = (0..self.active.len()).collect();
        loop {
            if keep.is_empty() {
                return out;
            }
            let h = self.hess.select_rows(&keep).select_columns(&keep);
            if let Some(c) = h.clone().cholesky() {
                let cov = c.inverse();
                for (r, &a) in keep.iter().enumerate() {
                    let v = cov[(r, r)];
                    if v.is_finite() && v > 0.0 {
                        out[self.active[a]] = Some(v.sqrt());
                    }
                }
                return out;
            }
            // Drop the parameter that weighs most in the flattest direction.
            let eig = h.symmetric_eigen();
            let (imin, _) =
                eig.eigenvalues
                    .iter()
                    .enumerate()
                    .fold(
                        (0, f64::INFINITY),
                        |b, (i, &v)| if v < b.1 { (i, v) } else { b },
                    );
            let v = eig.eigenvectors.column(imin);
            let (worst, _) =
                v.iter().enumerate().fold(
                    (0, -1.0),
                    |b, (i, &x)| if x.abs() > b.1 { (i, x.abs()) } else { b },
                );
            keep.remove(worst);
        }
    }
}
