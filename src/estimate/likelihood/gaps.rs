//! One evaluation of the likelihood of a record with gaps ([`Gaps`]): the patterns of
//! measured components seen so far, the memoized recursion and its steady node.

#![allow(non_snake_case)]

use super::step::{Flat, Pattern, Scratch, row_major};
use super::tree::{Edge, MAX_NODES, Tree};
use crate::estimate::NotDefinite;
use crate::filter::KalmanFilter;

/// The root of a [`Tree`]: the initial covariance.
pub(super) const ROOT: usize = 0;

/// One evaluation of [`KalmanFilter::with_gaps`]: the model row-major, the patterns of
/// measured components seen so far, the memoized covariance recursion and its steady node,
/// and the scratch space of the steps.
pub(super) struct Gaps {
    pub(super) flat: Flat,
    pub(super) m: usize,
    /// H (m × n) and R (m × m), row-major.
    pub(super) H: Vec<f64>,
    pub(super) R: Vec<f64>,
    /// Pattern 0 measures every component.
    pub(super) patterns: Vec<Pattern>,
    pub(super) ws: Scratch,
    pub(super) tree: Tree,
    /// The node where the complete record's recursion settled, and how close a covariance
    /// must come to it to be back on it.
    pub(super) steady: Option<usize>,
    pub(super) tol: f64,
    /// A sequence's own covariance, once the tree is full.
    pub(super) own: Vec<f64>,
    /// The mean's state, prediction, and scratch of m.
    pub(super) x: Vec<f64>,
    pub(super) xp: Vec<f64>,
    pub(super) nu: Vec<f64>,
    pub(super) w: Vec<f64>,
}

impl Gaps {
    pub(super) fn new(f: &KalmanFilter, m: usize) -> Gaps {
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
    pub(super) fn pattern(&self, measured: Vec<bool>) -> Pattern {
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
    pub(super) fn pattern_of(&mut self, zk: &[f64]) -> usize {
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
    pub(super) fn grow_complete(&mut self, steps: usize) -> Result<(), NotDefinite> {
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
    pub(super) fn sequence(
        &mut self,
        x0: &[f64],
        z: &[f64],
        nll: &mut f64,
    ) -> Result<(), NotDefinite> {
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
    pub(super) fn new_edge(&mut self, node: usize, p: u32, k: usize) -> Result<usize, NotDefinite> {
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

pub(super) fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0, |acc, (x, y)| acc.max((x - y).abs()))
}
