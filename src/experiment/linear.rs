//! A problem file's linear-Gaussian truth and Kalman filter as an [`Experiment`].

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use super::{Covariances, Definition, Experiment, ExperimentError, RunOptions};
use crate::filter::{Estimate, Filter, KalmanFilter, PredictResult, UpdateResult};
use crate::measurement::Measurement;
use crate::model::LinearGaussianModel;
use crate::montecarlo::{self, Engine, McConfig, expected_accumulator, models_match};
use crate::params::{CovModel, NoiseKind, Target};
use crate::stats::Accumulator;

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
/// its F and H its expected statistics have a closed form ([`expected_accumulator`]).
///
/// The filter may have other states than the truth ([`FilterModel::map`]): the truth-model
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
}

impl LinearExperiment {
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

impl Experiment for LinearExperiment {
    fn definition(&self) -> &Definition {
        &self.definition
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        let kf = self.filter_at(theta);
        let map = self.filter.map.as_ref();
        Ok(match (run.engine, map) {
            (Engine::Auto | Engine::Linear, _) => {
                montecarlo::run_linear_with_progress(&self.truth, &kf, map, mc, run.progress)
            }
            (Engine::Generic, None) => {
                montecarlo::run_generic_with_progress(&self.truth, &kf, mc, run.progress)
            }
            (Engine::Generic, Some(map)) => montecarlo::run_generic_with_progress(
                &self.truth,
                &Mapped { kf: &kf, map },
                mc,
                run.progress,
            ),
        })
    }

    fn supports(&self, _engine: Engine) -> bool {
        true
    }

    fn expected(&self, theta: &[f64], mc: &McConfig) -> Option<Accumulator> {
        let kf = self.filter_at(theta);
        if self.filter.map.is_some() || !models_match(&self.truth, &kf) {
            return None;
        }
        Some(
            expected_accumulator(&self.truth, &kf, mc)
                .unwrap_or_else(|e| montecarlo::all_stopped(mc, kf.F.nrows(), kf.H.nrows(), &e)),
        )
    }

    fn target(&self, i: usize) -> Option<Target> {
        Some(if self.filter.q.uses(i) {
            Target {
                kind: NoiseKind::Process,
                components: self.filter.q.touched(i),
            }
        } else {
            Target {
                kind: NoiseKind::Measurement,
                components: self.filter.r.touched(i),
            }
        })
    }

    fn alter(&self, change: &super::Alteration) -> Option<Box<dyn Experiment>> {
        self.altered(change)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        Some(Covariances {
            Q: self.filter.q.build(theta),
            R: self.filter.r.build(theta),
        })
    }
}

/// The Kalman filter as the generic engine sees it when it has other states than the truth:
/// its estimation error is `map · x_true − x̂` (the linear fast path applies the same map to
/// its batch of runs).
struct Mapped<'a> {
    kf: &'a KalmanFilter,
    map: &'a DMatrix<f64>,
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
}
