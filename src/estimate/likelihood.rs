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

/// One step of the covariance recursion: the gain, `S⁻¹` and `log det S`.
struct Step {
    K: DMatrix<f64>,
    S_inv: DMatrix<f64>,
    log_det: f64,
}

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Nodes of the memoized covariance recursion of one evaluation, at most: some 100 MB for
/// a filter of ten states. Past it, a sequence runs its own covariance until it is back
/// on the steady state.
const MAX_NODES: usize = 100_000;

/// No edge yet.
const NONE: u32 = u32::MAX;

/// A pattern of measured components, with its rows of H and R (row-major), so that a
/// step measuring it selects nothing at run time.
struct Pattern {
    measured: Vec<bool>,
    rows: Vec<usize>,
    /// r × n.
    H: Vec<f64>,
    /// r × r.
    R: Vec<f64>,
}

/// A step of the memoized recursion: from one covariance, with one pattern measured. Its
/// gain (n × r) and `S⁻¹` (r × r) live in [`Tree::gains`] from `at`.
#[derive(Clone, Copy)]
struct Edge {
    pattern: u32,
    to: u32,
    log_det: f64,
    at: usize,
}

/// The memoized covariance recursion of one evaluation, in flat arenas so that adding a
/// node allocates nothing once they have grown.
struct Tree {
    n: usize,
    /// Node i's covariance is `covs[i n² ..]`, row-major.
    covs: Vec<f64>,
    /// The edge of each node with every component measured (the common case).
    full: Vec<u32>,
    /// The others, per node: (pattern, edge); almost always empty (no allocation).
    partial: Vec<Vec<(u32, u32)>>,
    edges: Vec<Edge>,
    gains: Vec<f64>,
}

impl Tree {
    fn nodes(&self) -> usize {
        self.full.len()
    }

    fn cov(&self, node: usize) -> &[f64] {
        let nn = self.n * self.n;
        &self.covs[node * nn..(node + 1) * nn]
    }

    fn push_node(&mut self, P: &[f64]) -> usize {
        self.covs.extend_from_slice(P);
        self.full.push(NONE);
        self.partial.push(Vec::new());
        self.full.len() - 1
    }

    fn edge(&self, node: usize, pattern: u32) -> Option<usize> {
        let e = if pattern == 0 {
            self.full[node]
        } else {
            self.partial[node]
                .iter()
                .find(|&&(p, _)| p == pattern)
                .map_or(NONE, |&(_, e)| e)
        };
        (e != NONE).then_some(e as usize)
    }

    fn add(&mut self, node: usize, edge: Edge) -> usize {
        let e = self.edges.len() as u32;
        self.edges.push(edge);
        if edge.pattern == 0 {
            self.full[node] = e;
        } else {
            self.partial[node].push((edge.pattern, e));
        }
        e as usize
    }
}

/// Scratch space of one covariance step, allocated once per evaluation.
struct Scratch {
    FP: Vec<f64>,
    Pp: Vec<f64>,
    U: Vec<f64>,
    W: Vec<f64>,
    S: Vec<f64>,
    Linv: Vec<f64>,
    /// The step's outputs: the covariance after it, the gain and `S⁻¹`.
    P: Vec<f64>,
    gain: Vec<f64>,
}

impl Scratch {
    fn new(n: usize, m: usize) -> Self {
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
struct Flat {
    n: usize,
    F: Vec<f64>,
    Q: Vec<f64>,
}

fn row_major(A: &DMatrix<f64>) -> Vec<f64> {
    A.transpose().as_slice().to_vec()
}

impl Flat {
    /// One step of the covariance recursion from `P` (row-major n × n) measuring `pat`:
    /// the covariance after the update into `ws.P`, the gain `K` (n × r) then `S⁻¹`
    /// (r × r) into `ws.gain`; returns `log det S`. The update is `P⁻ − W W'` with
    /// `W = P⁻ H' L⁻ᵀ` (`S = L L'`), symmetric by construction; against the Joseph form
    /// it differs by rounding only, and the recursion contracts such differences.
    fn cov_step(
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
    fn predict_covariance(&self, P: &[f64], ws: &mut Scratch) {
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
    fn mean_step(
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

/// The root of a [`Tree`]: the initial covariance.
const ROOT: usize = 0;

/// One evaluation of [`KalmanFilter::with_gaps`]: the model row-major, the patterns of
/// measured components seen so far, the memoized covariance recursion and its steady node,
/// and the scratch space of the steps.
struct Gaps {
    flat: Flat,
    m: usize,
    /// H (m × n) and R (m × m), row-major.
    H: Vec<f64>,
    R: Vec<f64>,
    /// Pattern 0 measures every component.
    patterns: Vec<Pattern>,
    ws: Scratch,
    tree: Tree,
    /// The node where the complete record's recursion settled, and how close a covariance
    /// must come to it to be back on it.
    steady: Option<usize>,
    tol: f64,
    /// A sequence's own covariance, once the tree is full.
    own: Vec<f64>,
    /// The mean's state, prediction, and scratch of m.
    x: Vec<f64>,
    xp: Vec<f64>,
    nu: Vec<f64>,
    w: Vec<f64>,
}

impl Gaps {
    fn new(f: &KalmanFilter, m: usize) -> Gaps {
        let n = f.F.nrows();
        let mut tree = Tree {
            n,
            covs: Vec::new(),
            full: Vec::new(),
            partial: Vec::new(),
            edges: Vec::new(),
            gains: Vec::new(),
        };
        tree.push_node(&row_major(&f.P0));
        let mut gaps = Gaps {
            flat: Flat {
                n,
                F: row_major(&f.F),
                Q: row_major(&f.Q),
            },
            m,
            H: row_major(&f.H),
            R: row_major(&f.R),
            patterns: Vec::new(),
            ws: Scratch::new(n, m),
            tree,
            steady: None,
            tol: 0.0,
            own: vec![0.0; n * n],
            x: vec![0.0; n],
            xp: vec![0.0; n],
            nu: vec![0.0; m],
            w: vec![0.0; m],
        };
        let all = gaps.pattern(vec![true; m]);
        gaps.patterns.push(all);
        gaps
    }

    /// The rows of H and the block of R that `measured` keeps.
    fn pattern(&self, measured: Vec<bool>) -> Pattern {
        let (n, m) = (self.flat.n, self.m);
        let rows: Vec<usize> = (0..m).filter(|&j| measured[j]).collect();
        let H = rows
            .iter()
            .flat_map(|&j| self.H[j * n..(j + 1) * n].iter().copied())
            .collect();
        let R = rows
            .iter()
            .flat_map(|&a| rows.iter().map(move |&b| (a, b)))
            .map(|(a, b)| self.R[a * m + b])
            .collect();
        Pattern {
            measured,
            rows,
            H,
            R,
        }
    }

    /// The index of the pattern of the finite entries of `zk`, added when new.
    fn pattern_of(&mut self, zk: &[f64]) -> usize {
        if zk.iter().all(|v| v.is_finite()) {
            return 0;
        }
        let same = |p: &Pattern| p.measured.iter().zip(zk).all(|(&f, v)| f == v.is_finite());
        match self.patterns.iter().position(same) {
            Some(p) => p,
            None => {
                let p = self.pattern(zk.iter().map(|v| v.is_finite()).collect());
                self.patterns.push(p);
                self.patterns.len() - 1
            }
        }
    }

    /// The complete record's recursion from the start, to its steady state (at most
    /// `steps` steps, and as many as the tree holds).
    fn grow_complete(&mut self, steps: usize) -> Result<(), NotDefinite> {
        let (n, m) = (self.flat.n, self.m);
        let mut node = ROOT;
        for k in 1..=steps.min(MAX_NODES - 1) {
            let log_det =
                self.flat
                    .cov_step(self.tree.cov(node), &self.patterns[0], &mut self.ws, k)?;
            let change = max_abs_diff(&self.ws.P, self.tree.cov(node));
            let scale = self
                .ws
                .P
                .iter()
                .fold(f64::MIN_POSITIVE, |a, v| a.max(v.abs()));
            let at = self.tree.gains.len();
            self.tree
                .gains
                .extend_from_slice(&self.ws.gain[..n * m + m * m]);
            let to = self.tree.push_node(&self.ws.P);
            self.tree.add(
                node,
                Edge {
                    pattern: 0,
                    to: to as u32,
                    log_det,
                    at,
                },
            );
            node = to;
            if change <= 1e-14 * scale && k > 2 {
                self.steady = Some(node);
                break;
            }
        }
        self.tol = self.steady.map_or(0.0, |s| {
            1e-12
                * self
                    .tree
                    .cov(s)
                    .iter()
                    .fold(f64::MIN_POSITIVE, |a, v| a.max(v.abs()))
        });
        Ok(())
    }

    /// Add one sequence's `−log L` (its measurements `z`, T × m row-major, from the
    /// initial estimate `x0`) to `nll`.
    fn sequence(&mut self, x0: &[f64], z: &[f64], nll: &mut f64) -> Result<(), NotDefinite> {
        let n = self.flat.n;
        self.x.copy_from_slice(x0);
        // Where the sequence's covariance is: a node of the tree, or `own`.
        let mut at = Some(ROOT);
        for (k, zk) in z.chunks(self.m).enumerate() {
            let p = self.pattern_of(zk);
            let pat = &self.patterns[p];
            let p = p as u32;
            if let Some(node) = at
                && self.tree.edge(node, p).is_none()
                && self.tree.nodes() >= MAX_NODES
            {
                self.own.copy_from_slice(self.tree.cov(node));
                at = None;
            }
            let Some(node) = at else {
                let log_det = self.flat.cov_step(&self.own, pat, &mut self.ws, k + 1)?;
                self.own.copy_from_slice(&self.ws.P);
                let r = pat.rows.len();
                let gain = &self.ws.gain[..n * r + r * r];
                *nll += self.flat.mean_step(
                    &mut self.x,
                    &mut self.xp,
                    &mut self.nu,
                    &mut self.w,
                    zk,
                    pat,
                    gain,
                    log_det,
                );
                if let Some(sn) = self.steady
                    && max_abs_diff(&self.own, self.tree.cov(sn)) <= self.tol
                {
                    at = Some(sn);
                }
                continue;
            };
            let e = match self.tree.edge(node, p) {
                Some(e) => e,
                None => self.new_edge(node, p, k + 1)?,
            };
            let e = self.tree.edges[e];
            let pat = &self.patterns[p as usize];
            let r = pat.rows.len();
            let gain = &self.tree.gains[e.at..e.at + n * r + r * r];
            *nll += self.flat.mean_step(
                &mut self.x,
                &mut self.xp,
                &mut self.nu,
                &mut self.w,
                zk,
                pat,
                gain,
                e.log_det,
            );
            at = Some(e.to as usize);
        }
        Ok(())
    }

    /// The covariance step from `node` measuring pattern `p` at step `k`, memoized: back to
    /// the steady node when it lands on it, a new node otherwise.
    fn new_edge(&mut self, node: usize, p: u32, k: usize) -> Result<usize, NotDefinite> {
        let n = self.flat.n;
        let pat = &self.patterns[p as usize];
        let log_det = self
            .flat
            .cov_step(self.tree.cov(node), pat, &mut self.ws, k)?;
        let back = self.steady.is_some_and(|sn| {
            (node == sn && p == 0) || max_abs_diff(&self.ws.P, self.tree.cov(sn)) <= self.tol
        });
        let to = match self.steady {
            Some(sn) if back => sn,
            _ => self.tree.push_node(&self.ws.P),
        };
        let r = pat.rows.len();
        let at = self.tree.gains.len();
        self.tree
            .gains
            .extend_from_slice(&self.ws.gain[..n * r + r * r]);
        let edge = Edge {
            pattern: p,
            to: to as u32,
            log_det,
            at,
        };
        Ok(self.tree.add(node, edge))
    }
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0, |acc, (x, y)| acc.max((x - y).abs()))
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
