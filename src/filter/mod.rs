//! Filters: predict, update, the innovation and its covariance S.
//!
//! The [`Filter`] trait is what the Monte Carlo engine runs; the linear Kalman filter
//! ([`KalmanFilter`]) implements it, and so can a user's own filter.

mod kf;
mod nonlinear;

pub use kf::{CovarianceUpdate, KalmanFilter, joseph_update};
pub use nonlinear::{Ekf, LinearSystem, SystemModel, Ukf, numerical_jacobian};

use nalgebra::{DMatrix, DVector};

use crate::measurement::Measurement;

/// A filter's estimate: mean, covariance, and the linearized error map of the current step.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// State estimate x̂, n.
    pub x: DVector<f64>,
    /// Error covariance the filter believes, P, n × n.
    pub P: DMatrix<f64>,
    /// The linear map `A_k` from the previous step's posterior error to this step's
    /// (`F` after predict, then `(I − K H) F` after an update), n × n. The engine uses it to
    /// predict how strongly NEES is correlated over time under consistency.
    pub error_map: DMatrix<f64>,
}

impl Estimate {
    /// The estimate `(x0, P0)` at step 0, with the identity as error map.
    pub fn new(x0: &DVector<f64>, p0: &DMatrix<f64>) -> Self {
        let n = x0.len();
        Estimate {
            x: x0.clone(),
            P: p0.clone(),
            error_map: DMatrix::identity(n, n),
        }
    }
}

/// The result of one measurement update.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Innovation {
    /// Innovation ν = z − ẑ, in measurement units, length n_z of this measurement.
    pub nu: DVector<f64>,
    /// Innovation covariance S, n_z × n_z.
    pub S: DMatrix<f64>,
    /// Normalized innovation squared ν' S⁻¹ ν (dimensionless).
    pub nis: f64,
}

/// Why a filter could not continue.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// A covariance that must be positive definite is not.
    #[error("{which} is not positive definite at step {step}")]
    NotPositiveDefinite {
        /// "S" (innovation covariance) or "P" (state covariance).
        which: &'static str,
        /// Time step.
        step: usize,
    },
    /// The filter needs something its model does not provide.
    #[error("the model does not provide {what}")]
    Unsupported {
        /// What is missing.
        what: &'static str,
    },
    /// A measurement from a sensor the filter does not know, or of the wrong dimension.
    #[error("measurement from sensor {sensor} has dimension {got}, expected {expected}")]
    BadMeasurement {
        /// Sensor index.
        sensor: usize,
        /// Its dimension.
        got: usize,
        /// The sensor's dimension (0 if unknown).
        expected: usize,
    },
}

/// Check that `meas` has the dimension `expected` of its sensor (`None`: the filter has no
/// such sensor); otherwise the [`FilterError::BadMeasurement`] naming both.
pub fn check_measurement(expected: Option<usize>, meas: &Measurement) -> Result<(), FilterError> {
    match expected {
        Some(d) if d == meas.z.len() => Ok(()),
        _ => Err(FilterError::BadMeasurement {
            sensor: meas.sensor,
            got: meas.z.len(),
            expected: expected.unwrap_or(0),
        }),
    }
}

/// A recursive estimator the engine can test.
pub trait Filter: Sync {
    /// State dimension n_x.
    fn n_x(&self) -> usize;

    /// Dimension of each sensor's measurement, indexed by [`Measurement::sensor`].
    fn sensor_dims(&self) -> Vec<usize>;

    /// The estimate at step 0, before any measurement.
    fn initial(&self) -> Estimate;

    /// Propagate the estimate from step `k − 1` to step `k`.
    fn predict(&self, k: usize, est: &mut Estimate) -> Result<(), FilterError>;

    /// Propagate the estimate from step `k − 1` to step `k` driven by the control input `u`
    /// (whatever [`crate::model::TruthModel::input`] produced, e.g. IMU samples). The
    /// default refuses: a filter that takes inputs overrides it.
    fn predict_with_input(
        &self,
        _k: usize,
        _est: &mut Estimate,
        _u: &DVector<f64>,
    ) -> Result<(), FilterError> {
        Err(FilterError::Unsupported {
            what: "control inputs",
        })
    }

    /// Incorporate one measurement taken at step `k`.
    fn update(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
    ) -> Result<Innovation, FilterError>;

    /// The estimation error `x_true − x̂` (override to wrap angles or map a
    /// higher-fidelity truth state onto the filter's state).
    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        truth - estimate
    }
}

/// A boxed filter is a filter (catalog models hand out `Box<dyn Filter>`).
impl<F: Filter + ?Sized> Filter for Box<F> {
    fn n_x(&self) -> usize {
        (**self).n_x()
    }

    fn sensor_dims(&self) -> Vec<usize> {
        (**self).sensor_dims()
    }

    fn initial(&self) -> Estimate {
        (**self).initial()
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> Result<(), FilterError> {
        (**self).predict(k, est)
    }

    fn predict_with_input(
        &self,
        k: usize,
        est: &mut Estimate,
        u: &DVector<f64>,
    ) -> Result<(), FilterError> {
        (**self).predict_with_input(k, est, u)
    }

    fn update(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
    ) -> Result<Innovation, FilterError> {
        (**self).update(k, est, meas)
    }

    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        (**self).state_error(truth, estimate)
    }
}
