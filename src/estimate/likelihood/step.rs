//! One step of the exact likelihood's covariance recursion on flat row-major arrays: a
//! pattern of measured components, the innovation covariance, its factor, the gain and the
//! update, in scratch space allocated once per evaluation.

#![allow(non_snake_case)]

use nalgebra::DMatrix;

use crate::estimate::NotDefinite;

pub(super) const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// A pattern of measured components, with its rows of H and R (row-major), so that a
/// step measuring it selects nothing at run time.
pub(super) struct Pattern {
    pub(super) measured: Vec<bool>,
    pub(super) rows: Vec<usize>,
    /// r × n.
    pub(super) H: Vec<f64>,
    /// r × r.
    pub(super) R: Vec<f64>,
}

/// Scratch space of one covariance step, allocated once per evaluation.
pub(super) struct Scratch {
    pub(super) FP: Vec<f64>,
    pub(super) Pp: Vec<f64>,
    pub(super) U: Vec<f64>,
    pub(super) W: Vec<f64>,
    pub(super) S: Vec<f64>,
    pub(super) Linv: Vec<f64>,
    /// The step's outputs: the covariance after it, the gain and `S⁻¹`.
    pub(super) P: Vec<f64>,
    pub(super) gain: Vec<f64>,
}

impl Scratch {
    pub(super) fn new(n: usize, m: usize) -> Self {
        Scratch {
            FP: vec![0.0; n * n],
            Pp: vec![0.0; n * n],
            U: vec![0.0; n * m],
            W: vec![0.0; n * m],
            S: vec![0.0; m * m],
            Linv: vec![0.0; m * m],
            P: vec![0.0; n * n],
            gain: vec![0.0; n * m + m * m],
        }
    }
}

/// The model row-major, for the allocation-free steps of [`KalmanFilter::with_gaps`].
pub(super) struct Flat {
    pub(super) n: usize,
    pub(super) F: Vec<f64>,
    pub(super) Q: Vec<f64>,
}

pub(super) fn row_major(A: &DMatrix<f64>) -> Vec<f64> {
    A.transpose().as_slice().to_vec()
}

impl Flat {
    /// One step of the covariance recursion from `P` (row-major n × n) measuring `pat`:
    /// the covariance after the update into `ws.P`, the gain `K` (n × r) then `S⁻¹`
    /// (r × r) into `ws.gain`; returns `log det S`. The update is `P⁻ − W W'` with
    /// `W = P⁻ H' L⁻ᵀ` (`S = L L'`), symmetric by construction; against the Joseph form
    /// it differs by rounding only, and the recursion contracts such differences.
    pub(super) fn cov_step(
        &self,
        P: &[f64],
        pat: &Pattern,
        ws: &mut Scratch,
        step: usize,
    ) -> Result<f64, NotDefinite> {
        let n = self.n;
        let r = pat.rows.len();
        self.predict_covariance(P, ws);
        if r == 0 {
            ws.P.copy_from_slice(&ws.Pp);
            return Ok(0.0);
        }
        innovation_covariance(pat, ws, n);
        let log_det = factor_innovation_covariance(ws, r).ok_or(NotDefinite { step })?;
        gain_and_update(ws, n, r);
        Ok(log_det)
    }

    /// `P⁻ = F P F' + Q` into `ws.Pp` (through `ws.FP`), formed on and above the diagonal
    /// and mirrored.
    #[inline(always)]
    pub(super) fn predict_covariance(&self, P: &[f64], ws: &mut Scratch) {
        let n = self.n;
        for i in 0..n {
            let Fi = &self.F[i * n..(i + 1) * n];
            let out = &mut ws.FP[i * n..(i + 1) * n];
            out.fill(0.0);
            for (f, Pk) in Fi.iter().zip(P.chunks_exact(n)) {
                if *f != 0.0 {
                    for (o, p) in out.iter_mut().zip(Pk) {
                        *o += f * p;
                    }
                }
            }
        }
        for i in 0..n {
            let FPi = &ws.FP[i * n..(i + 1) * n];
            for j in i..n {
                let Fj = &self.F[j * n..(j + 1) * n];
                let v = FPi.iter().zip(Fj).map(|(a, b)| a * b).sum::<f64>() + self.Q[i * n + j];
                ws.Pp[i * n + j] = v;
                ws.Pp[j * n + i] = v;
            }
        }
    }

    /// The mean's step with gain `K` (n × r) and `S⁻¹` (r × r) of pattern `pat`, from `x`
    /// through `xp` (both n; `nu`, `w` scratch of m): `−log L` of the step.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn mean_step(
        &self,
        x: &mut [f64],
        xp: &mut [f64],
        nu: &mut [f64],
        w: &mut [f64],
        zk: &[f64],
        pat: &Pattern,
        gain: &[f64],
        log_det: f64,
    ) -> f64 {
        let n = self.n;
        let r = pat.rows.len();
        for (p, Fi) in xp.iter_mut().zip(self.F.chunks_exact(n)) {
            *p = Fi.iter().zip(x.iter()).map(|(a, b)| a * b).sum();
        }
        if r == 0 {
            x.copy_from_slice(xp);
            return 0.0;
        }
        let (K, S_inv) = gain.split_at(n * r);
        for ((v, &j), Ha) in nu.iter_mut().zip(&pat.rows).zip(pat.H.chunks_exact(n)) {
            *v = zk[j] - Ha.iter().zip(xp.iter()).map(|(a, b)| a * b).sum::<f64>();
        }
        let nu = &nu[..r];
        for (wa, Sa) in w.iter_mut().zip(S_inv.chunks_exact(r)) {
            *wa = Sa.iter().zip(nu).map(|(a, b)| a * b).sum();
        }
        let q: f64 = nu.iter().zip(w.iter()).map(|(a, b)| a * b).sum();
        for ((xi, pi), Ki) in x.iter_mut().zip(xp.iter()).zip(K.chunks_exact(r)) {
            *xi = pi + Ki.iter().zip(nu).map(|(a, b)| a * b).sum::<f64>();
        }
        0.5 * (log_det + q + r as f64 * LN_2PI)
    }
}

/// `U = P⁻ H'` (n × r) and `S = H U + R` of pattern `pat` into `ws`.
#[inline(always)]
fn innovation_covariance(pat: &Pattern, ws: &mut Scratch, n: usize) {
    let r = pat.rows.len();
    for i in 0..n {
        let Ppi = &ws.Pp[i * n..(i + 1) * n];
        for (a, Ha) in pat.H.chunks_exact(n).enumerate() {
            ws.U[i * r + a] = Ppi.iter().zip(Ha).map(|(x, y)| x * y).sum();
        }
    }
    for (a, Ha) in pat.H.chunks_exact(n).enumerate() {
        for b in 0..=a {
            let v = (0..n).map(|k| Ha[k] * ws.U[k * r + b]).sum::<f64>() + pat.R[a * r + b];
            ws.S[a * r + b] = v;
            ws.S[b * r + a] = v;
        }
    }
}

/// `S = L L'` in place (lower triangle of `ws.S`, r × r), then `L⁻¹` into `ws.Linv`:
/// `log det S`, or `None` when S is not positive definite.
#[inline(always)]
fn factor_innovation_covariance(ws: &mut Scratch, r: usize) -> Option<f64> {
    let mut log_det = 0.0;
    for j in 0..r {
        let mut d = ws.S[j * r + j];
        for c in 0..j {
            d -= ws.S[j * r + c] * ws.S[j * r + c];
        }
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let l = d.sqrt();
        log_det += 2.0 * l.ln();
        ws.S[j * r + j] = l;
        for i in j + 1..r {
            let mut v = ws.S[i * r + j];
            for c in 0..j {
                v -= ws.S[i * r + c] * ws.S[j * r + c];
            }
            ws.S[i * r + j] = v / l;
        }
    }
    ws.Linv[..r * r].fill(0.0);
    for j in 0..r {
        ws.Linv[j * r + j] = 1.0 / ws.S[j * r + j];
        for i in j + 1..r {
            let mut v = 0.0;
            for c in j..i {
                v -= ws.S[i * r + c] * ws.Linv[c * r + j];
            }
            ws.Linv[i * r + j] = v / ws.S[i * r + i];
        }
    }
    Some(log_det)
}

/// `W = U L⁻ᵀ`, the gain `K = W L⁻¹` and `S⁻¹ = L⁻ᵀ L⁻¹` into `ws.gain`, and the
/// covariance after the update `P⁻ − W W'` into `ws.P`.
#[inline(always)]
fn gain_and_update(ws: &mut Scratch, n: usize, r: usize) {
    for i in 0..n {
        for a in 0..r {
            ws.W[i * r + a] = (0..=a).map(|c| ws.U[i * r + c] * ws.Linv[a * r + c]).sum();
        }
    }
    let (K, S_inv) = ws.gain.split_at_mut(n * r);
    for i in 0..n {
        for b in 0..r {
            K[i * r + b] = (b..r).map(|a| ws.W[i * r + a] * ws.Linv[a * r + b]).sum();
        }
    }
    for a in 0..r {
        for b in 0..=a {
            let v: f64 = (a..r)
                .map(|c| ws.Linv[c * r + a] * ws.Linv[c * r + b])
                .sum();
            S_inv[a * r + b] = v;
            S_inv[b * r + a] = v;
        }
    }
    for i in 0..n {
        for j in i..n {
            let ww: f64 = (0..r).map(|a| ws.W[i * r + a] * ws.W[j * r + a]).sum();
            let v = ws.Pp[i * n + j] - ww;
            ws.P[i * n + j] = v;
            ws.P[j * n + i] = v;
        }
    }
}
