//! The linear-Gaussian state-space model, shared by the truth that simulates such a system
//! ([`crate::model::LinearGaussianModel`]) and the Kalman filter that estimates one
//! ([`crate::filter::KalmanFilter`]: a filter is defined by the model it believes).

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

/// `x_k = F x_{k−1} + w_k, w_k ~ N(0, Q)`, `z_k = H x_k + v_k, v_k ~ N(0, R)`,
/// `x_0 ~ N(x0, P0)`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearGaussian {
    /// State transition over one step, n × n.
    pub F: DMatrix<f64>,
    /// Measurement matrix, m × n.
    pub H: DMatrix<f64>,
    /// Process noise covariance per step, n × n (units of the state squared).
    pub Q: DMatrix<f64>,
    /// Measurement noise covariance, m × m (units of the measurement squared).
    pub R: DMatrix<f64>,
    /// Mean of the initial state (a filter: its initial estimate), n.
    pub x0: DVector<f64>,
    /// Covariance of the initial state, n × n (a filter's must be positive definite).
    pub P0: DMatrix<f64>,
}
