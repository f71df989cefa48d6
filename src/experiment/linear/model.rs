//! A problem file's linear-Gaussian truth and Kalman filter: what they are, the filter at θ,
//! the blocks no matrix couples.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use crate::experiment::definition::{Block, Definition};
use crate::filter::{Estimate, Filter, KalmanFilter, PredictResult, UpdateResult};
use crate::measurement::Measurement;
use crate::model::LinearGaussianModel;
use crate::montecarlo::SharedTrack;
use crate::params::{Coef, CovModel};

/// The filter's model with Q and R as functions of the parameters.
#[derive(Debug, Clone)]
pub struct FilterModel {
    /// State transition, n × n (n: the filter's states, n_t without a map).
    pub F: DMatrix<f64>,
    /// Measurement matrix, m × n.
    pub H: DMatrix<f64>,
    /// Initial estimate, n.
    pub x0: DVector<f64>,
    /// Initial covariance, n × n (positive definite).
    pub P0: DMatrix<f64>,
    /// Process noise as a function of the parameters.
    pub q: CovModel,
    /// Measurement noise as a function of the parameters.
    pub r: CovModel,
    /// From the truth's state (n_t) to the filter's (n), n × n_t, with the NEES taken on
    /// `e = map · x_true − x̂`; `None` when the filter has the truth's states (an identity
    /// map in the file is stored as `None`).
    pub map: Option<DMatrix<f64>>,
}

/// A linear-Gaussian truth and a Kalman filter whose Q and R are sums of parameterized
/// terms. It runs on the linear fast path, and when the filter has the truth's states and uses
/// its F and H its expected statistics have a closed form (`expected_accumulator`).
///
/// The filter may have other states than the truth (`FilterModel::map`): the truth-model
/// test of a filter that omits what the truth carries (an acceleration, a bias, a flexible
/// mode). Both engines then take the NEES on the mapped error, in the filter's dimension.
#[derive(Debug, Clone)]
pub struct LinearExperiment {
    /// Name, source, parameters, component names (n states, m measurements), Monte Carlo.
    pub definition: Definition,
    /// The truth.
    pub truth: LinearGaussianModel,
    /// The filter's model.
    pub filter: FilterModel,
    /// The truth's moments step by step, built at the first exact scoring that reads them
    /// (a filter whose model is not the truth's) and shared by the later ones: the truth
    /// does not depend on the parameters.
    pub(super) track: SharedTrack,
}

impl LinearExperiment {
    /// The experiment of `truth` and `filter`, named and sized by `definition`.
    pub fn new(definition: Definition, truth: LinearGaussianModel, filter: FilterModel) -> Self {
        LinearExperiment {
            definition,
            truth,
            filter,
            track: SharedTrack::default(),
        }
    }

    /// The Kalman filter with parameters `theta` (one value per parameter, in order).
    pub fn filter_at(&self, theta: &[f64]) -> KalmanFilter {
        KalmanFilter {
            F: self.filter.F.clone(),
            H: self.filter.H.clone(),
            Q: self.filter.q.build(theta),
            R: self.filter.r.build(theta),
            x0: self.filter.x0.clone(),
            P0: self.filter.P0.clone(),
        }
    }
}

impl LinearExperiment {
    /// The blocks that no matrix couples, found conservatively: any nonzero entry that
    /// links two components (of the filter's F, P0, H, every Q and R term's basis whether
    /// its coefficient is a parameter or fixed, the truth's F, Q, P0, H, R, and the map from
    /// the truth's states to the filter's) puts them in one block, and a parameter joins
    /// every component its terms touch. A zero that is zero only at some parameter values
    /// never splits a block, because bases are tested, not built matrices.
    pub(super) fn decoupled_blocks(&self) -> Vec<Block> {
        let n = self.filter.F.nrows();
        let nt = self.truth.F.nrows();
        let m = self.filter.H.nrows();
        let p = self.definition.params.params.len();
        let (fs, ts, ms, ps) = (0, n, n + nt, n + nt + m);
        let mut sets = DisjointSets::new(ps + p);
        let pairs = [
            (&self.filter.F, fs, fs),
            (&self.filter.P0, fs, fs),
            (&self.filter.H, ms, fs),
            (&self.truth.F, ts, ts),
            (&self.truth.Q, ts, ts),
            (&self.truth.P0, ts, ts),
            (&self.truth.H, ms, ts),
            (&self.truth.R, ms, ms),
        ];
        for (a, row, col) in pairs {
            sets.link(a, row, col);
        }
        match &self.filter.map {
            Some(map) => sets.link(map, fs, ts),
            None => sets.link(&DMatrix::identity(n, nt), fs, ts),
        }
        for (cov, base) in [(&self.filter.q, fs), (&self.filter.r, ms)] {
            for t in &cov.terms {
                sets.link(&t.basis, base, base);
                if let Coef::Param(k) = t.coef {
                    for i in 0..t.basis.nrows() {
                        if (0..t.basis.ncols()).any(|j| t.basis[(i, j)] != 0.0) {
                            sets.union(ps + k, base + i);
                        }
                    }
                }
            }
        }
        // Blocks in the order of their first filter state or measurement; a component of
        // truth states alone (a state the filter neither maps nor observes) is no block.
        let mut roots: Vec<usize> = Vec::new();
        let mut blocks: Vec<Block> = Vec::new();
        let nodes = (0..n).map(|j| fs + j).chain((0..m).map(|i| ms + i));
        for node in nodes {
            let r = sets.find(node);
            let b = roots.iter().position(|&x| x == r).unwrap_or_else(|| {
                roots.push(r);
                blocks.push(Block {
                    params: Vec::new(),
                    states: Vec::new(),
                    measurements: Vec::new(),
                });
                roots.len() - 1
            });
            if node < ts {
                blocks[b].states.push(node - fs);
            } else {
                blocks[b].measurements.push(node - ms);
            }
        }
        for k in 0..p {
            let r = sets.find(ps + k);
            if let Some(b) = roots.iter().position(|&x| x == r) {
                blocks[b].params.push(k);
            }
        }
        blocks
    }
}

/// Union–find over component nodes, with path halving.
struct DisjointSets(Vec<usize>);

impl DisjointSets {
    fn new(n: usize) -> Self {
        DisjointSets((0..n).collect())
    }

    fn find(&mut self, mut a: usize) -> usize {
        while self.0[a] != a {
            self.0[a] = self.0[self.0[a]];
            a = self.0[a];
        }
        a
    }

    /// Links node `row + i` with node `col + j` for every nonzero entry (i, j) of `a`.
    fn link(&mut self, a: &DMatrix<f64>, row: usize, col: usize) {
        for i in 0..a.nrows() {
            for j in 0..a.ncols() {
                if a[(i, j)] != 0.0 {
                    self.union(row + i, col + j);
                }
            }
        }
    }

    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        // The smaller root wins, so the roots do not depend on the order of the unions.
        if ra != rb {
            let (lo, hi) = (ra.min(rb), ra.max(rb));
            self.0[hi] = lo;
        }
    }
}

/// The Kalman filter as the generic engine sees it when it has other states than the truth:
/// its estimation error is `map · x_true − x̂` (the linear fast path applies the same map to
/// its batch of runs).
pub(super) struct Mapped<'a> {
    pub(super) kf: &'a KalmanFilter,
    pub(super) map: &'a DMatrix<f64>,
}

impl Filter for Mapped<'_> {
    fn n_x(&self) -> usize {
        self.kf.n_x()
    }

    fn sensor_dims(&self) -> Vec<usize> {
        self.kf.sensor_dims()
    }

    fn initial(&self) -> Estimate {
        self.kf.initial()
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        self.kf.predict(k, est)
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        self.kf.update(k, est, meas)
    }

    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        self.map * truth - estimate
    }

    // Into the engine's storage: a run computes it at every step, and the default's new
    // vector was most of its cost (the same product and difference, the same bits).
    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        if out.len() != self.map.nrows() {
            *out = DVector::zeros(self.map.nrows());
        }
        out.gemv(1.0, self.map, truth, 0.0);
        *out -= estimate;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mapped_error_into_the_engines_storage_is_the_allocated_one_to_the_bit() {
        let kf = KalmanFilter {
            F: DMatrix::identity(2, 2),
            H: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            Q: DMatrix::identity(2, 2),
            R: DMatrix::identity(1, 1),
            x0: DVector::zeros(2),
            P0: DMatrix::identity(2, 2),
        };
        let map = DMatrix::from_row_slice(2, 3, &[0.3, -1.7, 0.0, 2.1e-3, 0.9, 4.4]);
        let f = Mapped { kf: &kf, map: &map };
        let truth = DVector::from_column_slice(&[1.25, -0.37, 8.1]);
        let estimate = DVector::from_column_slice(&[0.91, 7.6]);
        let want = f.state_error(&truth, &estimate);
        // Storage of the wrong size (the engine's first step), then reused.
        let mut out = DVector::zeros(5);
        for _ in 0..2 {
            f.state_error_into(&truth, &estimate, &mut out);
            let bits = |v: &DVector<f64>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&out), bits(&want));
        }
    }
}
