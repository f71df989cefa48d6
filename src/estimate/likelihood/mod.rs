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

use super::{MeasurementRecord, NotDefinite};
use crate::filter::KalmanFilter;
use crate::linalg::cholesky;

mod gaps;
mod step;
mod tree;

use gaps::Gaps;
use step::LN_2PI;

/// One step of the covariance recursion: the gain, `S⁻¹` and `log det S`.
struct Step {
    K: DMatrix<f64>,
    S_inv: DMatrix<f64>,
    log_det: f64,
}

/// The likelihood of a filter's innovations, on the filter's own model: its F, H, Q, R, x0
/// and P0 are the parameter value's.
impl KalmanFilter {
    /// `−log L` of `data` under this filter.
    pub fn neg_log_likelihood(&self, data: &MeasurementRecord) -> Result<f64, NotDefinite> {
        if data.complete() {
            self.shared(data)
        } else {
            self.with_gaps(data)
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
            let chol = cholesky(&S).ok_or(NotDefinite { step: k })?;
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

    fn shared(&self, data: &MeasurementRecord) -> Result<f64, NotDefinite> {
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

    /// A record with missing components (NaN). The covariance recursion does not depend on
    /// the values, only on which components are missing since the start or since the
    /// steady state, so its steps are memoized on that history: a tree whose nodes are
    /// covariances and whose edges are the steps from them with one pattern of measured
    /// components. A step whose covariance is back on the steady state (within 1e-12
    /// relative, some tens of steps after a gap) returns to the steady node, so a gap of
    /// a pattern seen before costs one pass of the means, like a complete record.
    ///
    /// Gaps closer together than that are the common case (with 1% of the cells of a
    /// two-component record empty, a gap comes every 50 steps and the covariance takes
    /// 50–120 steps to settle), and each such history is new, so most steps still take
    /// a covariance step of their own. Those steps run on row-major scratch space and flat
    /// arenas and allocate nothing: with nalgebra's allocating products a record with 1%
    /// empty cells cost 5–27× a complete one per evaluation.
    fn with_gaps(&self, data: &MeasurementRecord) -> Result<f64, NotDefinite> {
        let steps = data.sequences.iter().map(|s| s.steps).max().unwrap_or(0);
        let mut gaps = Gaps::new(self, data.dim);
        gaps.grow_complete(steps)?;
        let mut nll = 0.0;
        for s in &data.sequences {
            gaps.sequence(self.x0.as_slice(), &s.z, &mut nll)?;
        }
        Ok(nll)
    }

    /// One sequence with missing components (NaN), its own covariance at every step: what
    /// [`Self::with_gaps`] must agree with.
    #[cfg(test)]
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
            let chol = cholesky(&S).ok_or_else(|| NotDefinite { step: k + 1 })?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Sequence;

    /// The shortcut through the shared recursion gives the likelihood of the plain
    /// recursion, on sequences with single empty cells, empty steps, gaps at the start
    /// and runs of gaps; with H the identity and R diagonal, and with a dense H and a
    /// correlated R of three components over two states (the allocation-free steps must
    /// not lean on a selection H).
    #[test]
    fn gaps_rejoin_the_steady_state_without_changing_the_likelihood() {
        let f = DMatrix::from_row_slice(2, 2, &[0.9, 0.0, -0.3, 0.8]);
        let q = DMatrix::from_row_slice(2, 2, &[2.0, -0.5, -0.5, 1.0]);
        let simple = KalmanFilter {
            F: f.clone(),
            H: DMatrix::identity(2, 2),
            Q: q.clone(),
            R: DMatrix::from_row_slice(2, 2, &[3.0, 0.0, 0.0, 2.0]),
            x0: DVector::zeros(2),
            P0: DMatrix::identity(2, 2),
        };
        let dense = KalmanFilter {
            F: f,
            H: DMatrix::from_row_slice(3, 2, &[1.0, 0.5, -0.7, 2.0, 0.3, 0.3]),
            Q: q,
            R: DMatrix::from_row_slice(3, 3, &[3.0, 0.8, 0.2, 0.8, 2.0, -0.4, 0.2, -0.4, 1.5]),
            x0: DVector::from_vec(vec![0.5, -1.0]),
            P0: DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 2.0]),
        };
        for (model, m) in [(simple, 2), (dense, 3)] {
            let steps = 400;
            let mut sequences = Vec::new();
            for s in 0..3u64 {
                // A deterministic wiggle for values; which cells are empty varies per
                // sequence.
                let mut z: Vec<f64> = (0..steps * m)
                    .map(|i| ((i as f64 + s as f64) * 0.7).sin() * 3.0)
                    .collect();
                for (k, zk) in z.chunks_mut(m).enumerate() {
                    if (k as u64 + s).is_multiple_of(37) {
                        zk[k % m] = f64::NAN;
                    }
                    if (k as u64 + s).is_multiple_of(53) {
                        zk[(k + 1) % m] = f64::NAN;
                    }
                    if s == 1 && (k == 0 || (200..205).contains(&k)) {
                        zk.fill(f64::NAN);
                    }
                }
                sequences.push(Sequence {
                    steps,
                    z,
                    time: Vec::new(),
                });
            }
            let data = MeasurementRecord { dim: m, sequences };
            assert!(!data.complete());
            let fast = model.with_gaps(&data).unwrap();
            let plain: f64 = data
                .sequences
                .iter()
                .map(|s| model.sequence_general(&s.z, m).unwrap())
                .sum();
            assert!(
                (fast - plain).abs() <= 1e-9 * plain.abs(),
                "m = {m}: {fast} vs {plain}"
            );
        }
    }
}
