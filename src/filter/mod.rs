//! Filters: predict, update, the innovation and its covariance S.
//!
//! The [`Filter`] trait is what the Monte Carlo engine runs; the linear Kalman filter
//! ([`KalmanFilter`]) implements it, and so can a user's own filter.

pub mod conditioning;
mod corrected;
mod joseph;
mod kf;
mod nonlinear;
mod recursion_memo;
pub mod unscented;

mod error;

pub use corrected::{Corrected, Correction};
pub use error::{FilterError, check_measurement};
pub(crate) use joseph::SparseUpdate;
pub use joseph::{CovarianceUpdate, joseph_update};
pub use kf::KalmanFilter;
pub use nonlinear::{Ekf, Jacobian, LinearSystem, SystemModel, Ukf, numerical_jacobian};

use nalgebra::{DMatrix, DVector, SMatrix, SVector};

use crate::linalg::{store, to_dynamic, to_fixed};
use crate::measurement::Measurement;

/// A filter's estimate: mean, covariance, and the linearized error map of the current step.
#[allow(non_snake_case)]
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// State estimate x̂, n (or the filter's own state layout; see [`Filter::state_error`]).
    pub x: DVector<f64>,
    /// Error covariance the filter believes, P, n_x × n_x.
    pub P: DMatrix<f64>,
    /// The linear map `A_k` from the previous step's posterior error to this step's,
    /// n_x × n_x: `F_k` (or the statistically linearized transition) after predict, then
    /// `(I − K H) A` after each update. `None` when the filter does not track it; see
    /// [`Filter`] for what the engine does then.
    pub error_map: Option<DMatrix<f64>>,
}

impl Estimate {
    /// The estimate `(x0, P0)` at step 0, with no error map yet (predict sets it).
    pub fn new(x0: &DVector<f64>, p0: &DMatrix<f64>) -> Self {
        Estimate {
            x: x0.clone(),
            P: p0.clone(),
            error_map: None,
        }
    }

    /// Compose the error map with an update's `I − K H` (n_x × n_x): `A ← (I − K H) A`.
    pub fn compose_error_map(&mut self, ikh: &DMatrix<f64>) {
        if let Some(a) = &self.error_map {
            self.error_map = Some(ikh * a);
        }
    }
}

/// For filters that compute on fixed-size matrices (the catalog's): the estimate in and out
/// of static storage, reusing its allocations from step to step. They are inlined: as
/// calls, made several times a step, they cost the 4-state orbit EKF a few percent.
#[allow(non_snake_case)]
impl Estimate {
    /// The estimate `(x0, P0)` at step 0 from a fixed-size mean (N) and covariance (N × N).
    #[inline]
    pub fn from_fixed<const N: usize>(x0: &SVector<f64, N>, P0: &SMatrix<f64, N, N>) -> Self {
        Estimate {
            x: DVector::from_column_slice(x0.as_slice()),
            P: to_dynamic(P0),
            error_map: None,
        }
    }

    /// The mean (N) and covariance (N × N) as fixed-size copies, or
    /// [`FilterError::Unsupported`] when the estimate has another dimension.
    #[inline]
    pub fn fixed<const N: usize>(
        &self,
    ) -> Result<(SVector<f64, N>, SMatrix<f64, N, N>), FilterError> {
        match (to_fixed(&self.x), to_fixed(&self.P)) {
            (Some(x), Some(P)) => Ok((x, P)),
            _ => Err(FilterError::Unsupported {
                what: "an estimate of the filter's dimension",
            }),
        }
    }

    /// Write a fixed-size mean (N) and covariance (N × N) back, in place.
    #[inline]
    pub fn set_fixed<const N: usize>(&mut self, x: &SVector<f64, N>, P: &SMatrix<f64, N, N>) {
        store(&mut self.x, x);
        store(&mut self.P, P);
    }

    /// Set the error map to a fixed-size transition `F` (N × N), in the previous map's
    /// storage when it has that shape.
    #[inline]
    pub fn set_error_map<const N: usize>(&mut self, F: &SMatrix<f64, N, N>) {
        match &mut self.error_map {
            Some(a) => store(a, F),
            None => self.error_map = Some(to_dynamic(F)),
        }
    }

    /// [`Estimate::compose_error_map`] for a fixed-size filter's `I − K H` (N × N), in place;
    /// a map of another shape is left as it is (the engine then treats it as missing).
    #[inline]
    pub fn compose_error_map_fixed<const N: usize>(&mut self, IKH: &SMatrix<f64, N, N>) {
        if let Some(a) = &mut self.error_map
            && let Some(m) = to_fixed::<N, N, _, _, _>(a)
        {
            store(a, &(IKH * m));
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

impl Innovation {
    /// An innovation of no dimension: storage for [`Filter::update_into`] to fill.
    pub fn empty() -> Self {
        Innovation {
            nu: DVector::zeros(0),
            S: DMatrix::zeros(0, 0),
            nis: 0.0,
        }
    }

    /// Set from a fixed-size innovation ν (M, measurement units), its covariance S (M × M)
    /// and its NIS, in the existing storage when it has that shape.
    #[allow(non_snake_case)]
    #[inline]
    pub fn set_fixed<const M: usize>(
        &mut self,
        nu: &SVector<f64, M>,
        S: &SMatrix<f64, M, M>,
        nis: f64,
    ) {
        store(&mut self.nu, nu);
        store(&mut self.S, S);
        self.nis = nis;
    }
}

/// [`Filter::update`] for a filter that implements [`Filter::update_into`]: the innovation
/// in new storage. A filter's `update` is then this one call.
pub fn update_by_into<F: Filter + ?Sized>(
    filter: &F,
    k: usize,
    est: &mut Estimate,
    meas: &Measurement,
) -> UpdateResult {
    let mut out = Innovation::empty();
    filter.update_into(k, est, meas, &mut out)?;
    Ok(out)
}

/// What a prediction returns.
pub type PredictResult = Result<(), FilterError>;

/// What an update returns: the innovation, or why the filter could not continue.
pub type UpdateResult = Result<Innovation, FilterError>;

/// A recursive estimator the engine can test.
///
/// # Duties
///
/// At each step k the engine calls [`Filter::predict`] (or [`Filter::predict_with_input`]),
/// then [`Filter::update`] once per measurement, then takes the NEES of
/// [`Filter::state_error`] against `P`. A filter must:
///
/// 1. keep `Estimate::P` symmetric positive definite, or return
///    [`FilterError::NotPositiveDefinite`] (the run then counts as diverged, never NaN);
/// 2. return each update's innovation ν, its covariance S and the NIS `ν' S⁻¹ ν`;
/// 3. check the measurement's sensor and dimension (`check_measurement`);
/// 4. set `Estimate::error_map` to the map from the previous posterior error to the
///    current one: the transition `F_k` in predict (for a UKF, its statistical
///    linearization), composed with `I − K H` in every update
///    (`Estimate::compose_error_map`). Under consistency the errors obey
///    `e_k = A_k e_{k−1} + noise`, and the engine uses `A_k` to predict how strongly NEES
///    is correlated over time: the time-averaged NEES gate is only as narrow as that
///    prediction is right.
///
/// A filter that cannot supply the error map leaves it `None` (as `Estimate::new` does).
/// The engine then falls back to the variance of the per-run NEES sums measured across the
/// runs, with a Student-t quantile for its estimation and never narrower than the textbook
/// interval; the report says so. It needs at least two runs and is a little wider than the
/// filter's own prediction, never a silently wider interval from a wrong map.
///
/// ```
/// use autotune::{
///     Estimate, Filter, FilterError, Innovation, Measurement, PredictResult, UpdateResult,
///     check_measurement,
/// };
/// use nalgebra::{DMatrix, DVector};
///
/// /// A scalar random walk `x_k = x_{k−1} + w`, measured directly: a Kalman filter written
/// /// out by hand, with every duty.
/// struct Walk { q: f64, r: f64 }
///
/// impl Filter for Walk {
///     fn sensor_dims(&self) -> Vec<usize> { vec![1] }
///     fn initial(&self) -> Estimate {
///         Estimate::new(&DVector::zeros(1), &DMatrix::identity(1, 1))
///     }
///     fn predict(&self, _k: usize, est: &mut Estimate) -> PredictResult {
///         est.P[(0, 0)] += self.q;
///         est.error_map = Some(DMatrix::identity(1, 1)); // F = 1
///         Ok(())
///     }
///     fn update(&self, k: usize, est: &mut Estimate, m: &Measurement) -> UpdateResult {
///         check_measurement((m.sensor == 0).then_some(1), m)?;
///         let s = est.P[(0, 0)] + self.r;
///         if !(s > 0.0) {
///             return Err(FilterError::NotPositiveDefinite { which: "S", step: k });
///         }
///         let gain = est.P[(0, 0)] / s;
///         let nu = m.z[0] - est.x[0];
///         est.x[0] += gain * nu;
///         est.P[(0, 0)] *= 1.0 - gain;
///         est.compose_error_map(&DMatrix::from_element(1, 1, 1.0 - gain));
///         Ok(Innovation {
///             nu: DVector::from_element(1, nu),
///             S: DMatrix::from_element(1, 1, s),
///             nis: nu * nu / s,
///         })
///     }
/// }
///
/// let f = Walk { q: 0.1, r: 1.0 };
/// let mut est = f.initial();
/// f.predict(1, &mut est).unwrap();
/// let inn = f.update(1, &mut est, &Measurement { sensor: 0, z: DVector::from_element(1, 0.5) }).unwrap();
/// assert!((inn.nis - 0.25 / 2.1).abs() < 1e-12);
/// assert!((est.error_map.unwrap()[(0, 0)] - 1.0 / 2.1).abs() < 1e-12);
/// assert_eq!(f.n_x(), 1, "n_x defaults to the initial covariance's dimension");
/// ```
pub trait Filter: Sync {
    /// Dimension n_x of the (error) state the NEES is taken in: by default, that of the
    /// initial covariance.
    fn n_x(&self) -> usize {
        self.initial().P.nrows()
    }

    /// Dimension of each sensor's measurement, indexed by [`Measurement::sensor`].
    fn sensor_dims(&self) -> Vec<usize>;

    /// The estimate at step 0, before any measurement.
    fn initial(&self) -> Estimate;

    /// Propagate the estimate from step `k − 1` to step `k`.
    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult;

    /// Propagate the estimate from step `k − 1` to step `k` driven by the control input `u`
    /// (whatever [`crate::model::TruthModel::input`] produced, e.g. IMU samples). The
    /// default refuses: a filter that takes inputs overrides it.
    fn predict_with_input(
        &self,
        _k: usize,
        _est: &mut Estimate,
        _u: &DVector<f64>,
    ) -> PredictResult {
        Err(FilterError::Unsupported {
            what: "control inputs",
        })
    }

    /// Incorporate one measurement taken at step `k`.
    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult;

    /// The length of the filter's own step (s), where it has one it can also depart from
    /// ([`Filter::predict_over`]); `None` by default.
    fn step_length(&self) -> Option<f64> {
        None
    }

    /// Propagate the estimate to step `k` over `dt` seconds instead of the filter's own
    /// step (a record with irregular times). The default refuses: a filter whose model is
    /// built for its step length overrides it.
    fn predict_over(&self, _k: usize, _est: &mut Estimate, _dt: f64) -> PredictResult {
        Err(FilterError::Unsupported {
            what: "steps of their own length",
        })
    }

    /// The estimation error `x_true − x̂` (override to wrap angles or map a
    /// higher-fidelity truth state onto the filter's state).
    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        truth - estimate
    }

    /// [`Filter::update`] with the innovation written into `out`, whose storage the Monte
    /// Carlo engine keeps from step to step. The default calls `update`; a filter that
    /// computes on fixed-size matrices overrides it to allocate nothing per step
    /// ([`Innovation::set_fixed`]). Both must give the same numbers.
    fn update_into(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
        out: &mut Innovation,
    ) -> Result<(), FilterError> {
        *out = self.update(k, est, meas)?;
        Ok(())
    }

    /// [`Filter::state_error`] written into `out` (n_x), whose storage the engine keeps
    /// from step to step; the default calls `state_error`. Both must give the same numbers.
    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        *out = self.state_error(truth, estimate);
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

    fn predict(&self, k: usize, est: &mut Estimate) -> PredictResult {
        (**self).predict(k, est)
    }

    fn predict_with_input(&self, k: usize, est: &mut Estimate, u: &DVector<f64>) -> PredictResult {
        (**self).predict_with_input(k, est, u)
    }

    fn update(&self, k: usize, est: &mut Estimate, meas: &Measurement) -> UpdateResult {
        (**self).update(k, est, meas)
    }

    fn step_length(&self) -> Option<f64> {
        (**self).step_length()
    }

    fn predict_over(&self, k: usize, est: &mut Estimate, dt: f64) -> PredictResult {
        (**self).predict_over(k, est, dt)
    }

    fn state_error(&self, truth: &DVector<f64>, estimate: &DVector<f64>) -> DVector<f64> {
        (**self).state_error(truth, estimate)
    }

    fn update_into(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
        out: &mut Innovation,
    ) -> Result<(), FilterError> {
        (**self).update_into(k, est, meas, out)
    }

    fn state_error_into(
        &self,
        truth: &DVector<f64>,
        estimate: &DVector<f64>,
        out: &mut DVector<f64>,
    ) {
        (**self).state_error_into(truth, estimate, out)
    }
}
