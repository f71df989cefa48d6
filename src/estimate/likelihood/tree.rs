//! The memoized covariance recursion of one evaluation ([`Tree`]): a node per covariance,
//! an edge per pattern measured from it, in flat arenas.

/// Nodes of the memoized covariance recursion of one evaluation, at most: some 100 MB for
/// a filter of ten states. Past it, a sequence runs its own covariance until it is back
/// on the steady state.
pub(super) const MAX_NODES: usize = 100_000;

/// No edge yet.
pub(super) const NONE: u32 = u32::MAX;

/// A step of the memoized recursion: from one covariance, with one pattern measured. Its
/// gain (n × r) and `S⁻¹` (r × r) live in [`Tree::gains`] from `at`.
#[derive(Clone, Copy)]
pub(super) struct Edge {
    pub(super) pattern: u32,
    pub(super) to: u32,
    pub(super) log_det: f64,
    pub(super) at: usize,
}

/// The memoized covariance recursion of one evaluation, in flat arenas so that adding a
/// node allocates nothing once they have grown.
pub(super) struct Tree {
    pub(super) n: usize,
    /// Node i's covariance is `covs[i n² ..]`, row-major.
    pub(super) covs: Vec<f64>,
    /// The edge of each node with every component measured (the common case).
    pub(super) full: Vec<u32>,
    /// The others, per node: (pattern, edge); almost always empty (no allocation).
    pub(super) partial: Vec<Vec<(u32, u32)>>,
    pub(super) edges: Vec<Edge>,
    pub(super) gains: Vec<f64>,
}

impl Tree {
    pub(super) fn nodes(&self) -> usize {
        self.full.len()
    }

    pub(super) fn cov(&self, node: usize) -> &[f64] {
        let nn = self.n * self.n;
        &self.covs[node * nn..(node + 1) * nn]
    }

    pub(super) fn push_node(&mut self, P: &[f64]) -> usize {
        self.covs.extend_from_slice(P);
        self.full.push(NONE);
        self.partial.push(Vec::new());
        self.full.len() - 1
    }

    pub(super) fn edge(&self, node: usize, pattern: u32) -> Option<usize> {
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

    pub(super) fn add(&mut self, node: usize, edge: Edge) -> usize {
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
