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
    /// The covariance after the step's update.
    P: DMatrix<f64>,
}

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Nodes of the memoized covariance recursion of one evaluation, at most: some 100 MB for
/// a filter of ten states. Past it, a sequence runs its own covariance until it is back
/// on the steady state.
const MAX_NODES: usize = 100_000;

/// A step of the memoized recursion: from one covariance, with the components `rows`
/// measured.
struct Edge {
    /// The measured components (empty: a prediction only).
    rows: Vec<usize>,
    /// Their rows of H.
    H: DMatrix<f64>,
    /// The gain, n × rows.
    K: DMatrix<f64>,
    /// `S⁻¹`, rows × rows.
    S_inv: DMatrix<f64>,
    /// `log det S`.
    log_det: f64,
    /// The node after the step.
    to: usize,
}

/// A covariance of the memoized recursion and the steps taken from it so far.
struct Node {
    P: DMatrix<f64>,
    /// The step with every component measured (the common case, found without a search).
    full: Option<usize>,
    /// The others, by which components are measured.
    partial: Vec<(Vec<bool>, usize)>,
}

impl Node {
    fn new(P: DMatrix<f64>) -> Self {
        Node {
            P,
            full: None,
            partial: Vec::new(),
        }
    }
}

/// The memoized covariance recursion of one evaluation.
struct Tree {
    nodes: Vec<Node>,
    edges: Vec<Edge>,
}

impl Tree {
    fn edge(&self, node: usize, measured: &[bool]) -> Option<usize> {
        let nd = &self.nodes[node];
        if measured.iter().all(|&f| f) {
            nd.full
        } else {
            nd.partial
                .iter()
                .find(|(mask, _)| mask.as_slice() == measured)
                .map(|&(_, e)| e)
        }
    }

    fn add(&mut self, node: usize, measured: &[bool], edge: Edge) -> usize {
        self.edges.push(edge);
        let e = self.edges.len() - 1;
        let nd = &mut self.nodes[node];
        if measured.iter().all(|&f| f) {
            nd.full = Some(e);
        } else {
            nd.partial.push((measured.to_vec(), e));
        }
        e
    }
}

/// Why a likelihood could not be evaluated: a covariance lost definiteness.
#[derive(Debug, Clone, PartialEq)]
pub struct NotDefinite(pub String);

impl LinearFilterModel {
    /// `−log L` of `data` under this filter.
    pub fn neg_log_likelihood(&self, data: &Measurements) -> Result<f64, NotDefinite> {
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
            out.push(Step {
                K,
                S_inv,
                log_det,
                P: P.clone(),
            });
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

    /// A record with missing components (NaN). The covariance recursion does not depend on
    /// the values, only on which components are missing since the start or since the
    /// steady state, so its steps are memoized on that history: a tree whose nodes are
    /// covariances and whose edges are the steps from them with one pattern of measured
    /// components. A step whose covariance is back on the steady state (within 1e-12
    /// relative, some tens of steps after a gap) returns to the steady node, so a gap of
    /// a pattern seen before costs one pass of the means, like a complete record. Without
    /// it, a record with 1% empty cells ran the whole covariance recursion at every step
    /// of every evaluation (8–12× a complete record).
    fn with_gaps(&self, data: &Measurements) -> Result<f64, NotDefinite> {
        const ROOT: usize = 0;
        const STEADY: usize = 1;
        let steps = data.sequences.iter().map(|s| s.steps).max().unwrap_or(0);
        let rec = self.recursion(steps)?;
        let Some(last) = rec.last() else {
            return Ok(0.0);
        };
        let settled = rec.len() < steps;
        let tol = 1e-12 * last.P.abs().max().max(f64::MIN_POSITIVE);
        let (n, m) = (self.F.nrows(), data.dim);
        let mut tree = Tree {
            nodes: vec![Node::new(self.P0.clone()), Node::new(last.P.clone())],
            edges: Vec::new(),
        };
        let mut nll = 0.0;
        let mut x = DVector::<f64>::zeros(n);
        let mut xp = DVector::<f64>::zeros(n);
        let mut nu = DVector::<f64>::zeros(m);
        let mut w = DVector::<f64>::zeros(m);
        let mut measured = vec![true; m];
        for s in &data.sequences {
            x.copy_from(&self.x0);
            // Where the sequence's covariance is: a node of the tree, or its own once the
            // tree is full.
            let mut at = Ok(ROOT);
            for (k, zk) in s.z.chunks(m).enumerate() {
                for (f, v) in measured.iter_mut().zip(zk) {
                    *f = v.is_finite();
                }
                let node = match at {
                    Ok(node) => node,
                    Err(ref mut P) => {
                        nll += self.own_step(&mut x, P, zk, k + 1)?;
                        if settled && (&*P - &last.P).abs().max() <= tol {
                            at = Ok(STEADY);
                        }
                        continue;
                    }
                };
                let edge = match tree.edge(node, &measured) {
                    Some(e) => e,
                    None if tree.nodes.len() >= MAX_NODES => {
                        let mut P = tree.nodes[node].P.clone();
                        nll += self.own_step(&mut x, &mut P, zk, k + 1)?;
                        at = Err(P);
                        continue;
                    }
                    None => {
                        let (mut edge, P) = self.edge(&tree.nodes[node].P, &measured, k + 1)?;
                        let full_from_steady = node == STEADY && measured.iter().all(|&f| f);
                        let back = full_from_steady || (&P - &last.P).abs().max() <= tol;
                        edge.to = if settled && back {
                            STEADY
                        } else {
                            tree.nodes.push(Node::new(P));
                            tree.nodes.len() - 1
                        };
                        tree.add(node, &measured, edge)
                    }
                };
                let e = &tree.edges[edge];
                xp.gemv(1.0, &self.F, &x, 0.0);
                if e.rows.is_empty() {
                    x.copy_from(&xp);
                } else if e.rows.len() == m {
                    nu.copy_from_slice(zk);
                    nu.gemv(-1.0, &e.H, &xp, 1.0);
                    w.gemv(1.0, &e.S_inv, &nu, 0.0);
                    nll += 0.5 * (e.log_det + nu.dot(&w) + m as f64 * LN_2PI);
                    x.copy_from(&xp);
                    x.gemv(1.0, &e.K, &nu, 1.0);
                } else {
                    let r = e.rows.len();
                    let mut nu = DVector::from_iterator(r, e.rows.iter().map(|&j| zk[j]));
                    nu.gemv(-1.0, &e.H, &xp, 1.0);
                    let w = &e.S_inv * &nu;
                    nll += 0.5 * (e.log_det + nu.dot(&w) + r as f64 * LN_2PI);
                    x.copy_from(&xp);
                    x.gemv(1.0, &e.K, &nu, 1.0);
                }
                at = Ok(e.to);
            }
        }
        Ok(nll)
    }

    /// The step from covariance `P` measuring the components `measured`: its edge (with
    /// `to` unset) and the covariance after it.
    fn edge(
        &self,
        P: &DMatrix<f64>,
        measured: &[bool],
        step: usize,
    ) -> Result<(Edge, DMatrix<f64>), NotDefinite> {
        let n = self.F.nrows();
        let Pp = &self.F * P * self.F.transpose() + &self.Q;
        let rows: Vec<usize> = (0..measured.len()).filter(|&j| measured[j]).collect();
        if rows.is_empty() {
            let e = Edge {
                rows,
                H: DMatrix::zeros(0, n),
                K: DMatrix::zeros(n, 0),
                S_inv: DMatrix::zeros(0, 0),
                log_det: 0.0,
                to: 0,
            };
            return Ok((e, Pp));
        }
        let H = self.H.select_rows(&rows);
        let R = self.R.select_rows(&rows).select_columns(&rows);
        let S = &H * &Pp * H.transpose() + &R;
        let chol = cholesky(&S)
            .ok_or_else(|| NotDefinite(format!("S is not positive definite at step {step}")))?;
        let S_inv = chol.inverse();
        let log_det = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
        let K = &Pp * H.transpose() * &S_inv;
        let ikh = DMatrix::<f64>::identity(n, n) - &K * &H;
        let next = &ikh * &Pp * ikh.transpose() + &K * &R * K.transpose();
        let e = Edge {
            rows,
            H,
            K,
            S_inv,
            log_det,
            to: 0,
        };
        Ok((e, next))
    }

    /// One step of the filter with its own covariance `P` (updated in place with the mean
    /// `x`), measuring the finite components of `zk`; `−log L` of the step.
    fn own_step(
        &self,
        x: &mut DVector<f64>,
        P: &mut DMatrix<f64>,
        zk: &[f64],
        step: usize,
    ) -> Result<f64, NotDefinite> {
        let n = self.F.nrows();
        let m = zk.len();
        *x = &self.F * &*x;
        *P = &self.F * &*P * self.F.transpose() + &self.Q;
        let rows: Vec<usize> = (0..m).filter(|&j| zk[j].is_finite()).collect();
        if rows.is_empty() {
            return Ok(0.0);
        }
        let (H, R) = if rows.len() == m {
            (self.H.clone(), self.R.clone())
        } else {
            (
                self.H.select_rows(&rows),
                self.R.select_rows(&rows).select_columns(&rows),
            )
        };
        let S = &H * &*P * H.transpose() + &R;
        let chol = cholesky(&S)
            .ok_or_else(|| NotDefinite(format!("S is not positive definite at step {step}")))?;
        let nu = DVector::from_iterator(rows.len(), rows.iter().map(|&j| zk[j])) - &H * &*x;
        let log_det = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
        let w = chol.solve(&nu);
        let K = &*P * H.transpose() * chol.inverse();
        *x += &K * &nu;
        let ikh = DMatrix::<f64>::identity(n, n) - &K * &H;
        *P = &ikh * &*P * ikh.transpose() + &K * &R * K.transpose();
        Ok(0.5 * (log_det + nu.dot(&w) + rows.len() as f64 * LN_2PI))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Sequence;

    /// The shortcut through the shared recursion gives the likelihood of the plain
    /// recursion, on sequences with single empty cells, empty steps, gaps at the start
    /// and runs of gaps.
    #[test]
    fn gaps_rejoin_the_steady_state_without_changing_the_likelihood() {
        let f = DMatrix::from_row_slice(2, 2, &[0.9, 0.0, -0.3, 0.8]);
        let model = LinearFilterModel {
            F: f,
            H: DMatrix::identity(2, 2),
            Q: DMatrix::from_row_slice(2, 2, &[2.0, -0.5, -0.5, 1.0]),
            R: DMatrix::from_row_slice(2, 2, &[3.0, 0.0, 0.0, 2.0]),
            x0: DVector::zeros(2),
            P0: DMatrix::identity(2, 2),
        };
        let steps = 400;
        let mut sequences = Vec::new();
        for s in 0..3u64 {
            // A deterministic wiggle for values; which cells are empty varies per sequence.
            let mut z: Vec<f64> = (0..steps * 2)
                .map(|i| ((i as f64 + s as f64) * 0.7).sin() * 3.0)
                .collect();
            for (k, zk) in z.chunks_mut(2).enumerate() {
                if (k as u64 + s) % 37 == 0 {
                    zk[k % 2] = f64::NAN;
                }
                if s == 1 && (k == 0 || (200..205).contains(&k)) {
                    zk.fill(f64::NAN);
                }
            }
            sequences.push(Sequence { steps, z });
        }
        let data = Measurements { dim: 2, sequences };
        assert!(!data.complete());
        let fast = model.with_gaps(&data).unwrap();
        let plain: f64 = data
            .sequences
            .iter()
            .map(|s| model.sequence_general(&s.z, 2).unwrap())
            .sum();
        assert!(
            (fast - plain).abs() <= 1e-9 * plain.abs(),
            "{fast} vs {plain}"
        );
    }
}
