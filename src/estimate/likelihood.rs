//! The exact Gaussian log-likelihood of a linear filter over recorded measurements, by the
//! prediction-error decomposition: `−log L = ½ Σ_k [log det S_k + ν_k' S_k⁻¹ ν_k + m_k log 2π]`
//! over every sequence and step, with ν_k and S_k the Kalman filter's innovations and their
//! covariances (Schweppe 1965; Harvey 1989, §3.4).
//!
//! The covariance recursion does not depend on the data. When no measurement is missing it
//! is run once per parameter value, shared by every sequence, and stops as soon as it has
//! converged to its steady state (a time-invariant filter's gain settles within some tens of
//! steps), so a long record costs one pass of the means.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::Measurements;
use crate::linalg::cholesky;

/// A linear filter's model at one parameter value.
#[derive(Debug, Clone)]
pub struct LinearFilterModel {
    /// State transition, n × n.
    pub F: DMatrix<f64>,
    /// Measurement matrix, m × n.
    pub H: DMatrix<f64>,
    /// Process noise covariance, n × n.
    pub Q: DMatrix<f64>,
    /// Measurement noise covariance, m × m.
    pub R: DMatrix<f64>,
    /// Initial estimate, n.
    pub x0: DVector<f64>,
    /// Initial covariance, n × n.
    pub P0: DMatrix<f64>,
}

impl LinearFilterModel {
    /// The filter of the linear problem `lin` at parameter values `theta`.
    pub fn of(lin: &crate::experiment::LinearExperiment, theta: &[f64]) -> Self {
        let kf = lin.filter_at(theta);
        LinearFilterModel {
            F: kf.F,
            H: kf.H,
            Q: kf.Q,
            R: kf.R,
            x0: kf.x0,
            P0: kf.P0,
        }
    }
}

/// One step of the covariance recursion: the gain, `S⁻¹` and `log det S`.
struct Step {
    K: DMatrix<f64>,
    S_inv: DMatrix<f64>,
    log_det: f64,
}

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Why a likelihood could not be evaluated: a covariance lost definiteness.
#[derive(Debug, Clone, PartialEq)]
pub struct NotDefinite(pub String);

impl LinearFilterModel {
    /// `−log L` of `data` under this filter.
    pub fn neg_log_likelihood(&self, data: &Measurements) -> Result<f64, NotDefinite> {
        if data.complete() {
            self.shared(data)
        } else {
            data.sequences
                .iter()
                .map(|s| self.sequence_general(&s.z, data.dim))
                .sum()
        }
    }

    /// The covariance recursion up to `steps`, or to its steady state.
    fn recursion(&self, steps: usize) -> Result<Vec<Step>, NotDefinite> {
        let n = self.F.nrows();
        let mut P = self.P0.clone();
        let mut out: Vec<Step> = Vec::new();
        let eye = DMatrix::<f64>::identity(n, n);
        for k in 1..=steps {
            let Pp = &self.F * &P * self.F.transpose() + &self.Q;
            let S = &self.H * &Pp * self.H.transpose() + &self.R;
            let chol = cholesky(&S)
                .ok_or_else(|| NotDefinite(format!("S is not positive definite at step {k}")))?;
            let S_inv = chol.inverse();
            let log_det = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            let K = &Pp * self.H.transpose() * &S_inv;
            let ikh = &eye - &K * &self.H;
            let next = &ikh * &Pp * ikh.transpose() + &K * &self.R * K.transpose();
            let change = (&next - &P).abs().max();
            let scale = next.abs().max().max(f64::MIN_POSITIVE);
            P = next;
            out.push(Step { K, S_inv, log_det });
            if change <= 1e-14 * scale && k > 2 {
                break;
            }
        }
        Ok(out)
    }

    fn shared(&self, data: &Measurements) -> Result<f64, NotDefinite> {
        let steps = data.sequences.iter().map(|s| s.steps).max().unwrap_or(0);
        let rec = self.recursion(steps)?;
        let (n, m) = (self.F.nrows(), data.dim);
        let mut nll = 0.0;
        let mut x = DVector::<f64>::zeros(n);
        let mut xp = DVector::<f64>::zeros(n);
        let mut nu = DVector::<f64>::zeros(m);
        let mut w = DVector::<f64>::zeros(m);
        for s in &data.sequences {
            x.copy_from(&self.x0);
            for k in 0..s.steps {
                let st = &rec[k.min(rec.len() - 1)];
                xp.gemv(1.0, &self.F, &x, 0.0);
                nu.copy_from_slice(&s.z[k * m..(k + 1) * m]);
                nu.gemv(-1.0, &self.H, &xp, 1.0);
                w.gemv(1.0, &st.S_inv, &nu, 0.0);
                nll += 0.5 * (st.log_det + nu.dot(&w) + m as f64 * LN_2PI);
                x.copy_from(&xp);
                x.gemv(1.0, &st.K, &nu, 1.0);
            }
        }
        Ok(nll)
    }

    /// One sequence with missing components (NaN): each step uses the rows measured.
    fn sequence_general(&self, z: &[f64], m: usize) -> Result<f64, NotDefinite> {
        let n = self.F.nrows();
        let eye = DMatrix::<f64>::identity(n, n);
        let mut x = self.x0.clone();
        let mut P = self.P0.clone();
        let mut nll = 0.0;
        for (k, zk) in z.chunks(m).enumerate() {
            x = &self.F * &x;
            P = &self.F * &P * self.F.transpose() + &self.Q;
            let rows: Vec<usize> = (0..m).filter(|&j| zk[j].is_finite()).collect();
            if rows.is_empty() {
                continue;
            }
            let H = self.H.select_rows(&rows);
            let R = self.R.select_rows(&rows).select_columns(&rows);
            let S = &H * &P * H.transpose() + &R;
            let chol = cholesky(&S).ok_or_else(|| {
                NotDefinite(format!("S is not positive definite at step {}", k + 1))
            })?;
            let nu = DVector::from_iterator(rows.len(), rows.iter().map(|&j| zk[j])) - &H * &x;
            let log_det = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            let w = chol.solve(&nu);
            nll += 0.5 * (log_det + nu.dot(&w) + rows.len() as f64 * LN_2PI);
            let K = &P * H.transpose() * chol.inverse();
            x += &K * &nu;
            let ikh = &eye - &K * &H;
            P = &ikh * &P * ikh.transpose() + &K * &R * K.transpose();
        }
        Ok(nll)
    }
}
