//! Truth models: how the true state and the sensors' measurements are simulated.
//!
//! A truth model is sampled with the caller's random stream, so the Monte Carlo engine
//! decides which stream each run gets and results are reproducible on any thread count.

use nalgebra::{DMatrix, DVector};
use rand::RngExt;
use rand_distr::StandardNormal;

use crate::measurement::Measurement;
use crate::rng::SimRng;
use crate::statespace::LinearGaussian;

/// A simulated system: the truth the filter is tested against.
///
/// Time steps are numbered `k = 1..=T`; step 0 is the initial state. At each step the
/// engine calls [`TruthModel::propagate`] and then [`TruthModel::measure`], in that order,
/// so a model's random draws must follow that order too.
pub trait TruthModel: Sync {
    /// State dimension n_x.
    fn n_x(&self) -> usize;

    /// Draw the initial true state x_0.
    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64>;

    /// Advance the true state from step `k − 1` to step `k`.
    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64>;

    /// Append the measurements available at step `k` (none, one, or several sensors) to
    /// `out`. The number of measurements and their dimensions may change from step to step.
    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>);

    /// The control input the filter's prediction from step `k − 1` to step `k` receives
    /// (e.g. the IMU samples an INS integrates over the step), drawn after
    /// [`TruthModel::propagate`] and before [`TruthModel::measure`]; `None` (the default)
    /// when the filter predicts without inputs. The engine passes it to
    /// [`crate::filter::Filter::predict_with_input`].
    fn input(&self, _k: usize, _x: &DVector<f64>, _rng: &mut SimRng) -> Option<DVector<f64>> {
        None
    }
}

/// Draw `x = mean + L ξ`, ξ ~ N(0, I_r), where `L` (n × r) is a covariance factor.
pub fn sample_gaussian(
    mean: &DVector<f64>,
    factor: &DMatrix<f64>,
    rng: &mut SimRng,
) -> DVector<f64> {
    let xi = DVector::from_fn(factor.ncols(), |_, _| rng.sample::<f64, _>(StandardNormal));
    mean + factor * xi
}

/// A linear-Gaussian truth model:
/// `x_k = F x_{k−1} + w_k, w_k ~ N(0, Q)`, `z_k = H x_k + v_k, v_k ~ N(0, R)`,
/// `x_0 ~ N(x0, P0)`, one sensor measured at every step.
///
/// It reads as its `LinearGaussian` model (`truth.F`, `truth.Q`, …) and keeps the
/// factors it samples with.
#[derive(Debug, Clone)]
pub struct LinearGaussianModel {
    /// The model.
    pub model: LinearGaussian,
    /// Factors `L L' = Q`, `R`, `P0` (n × rank), computed once.
    pub(crate) factors: Factors,
}

impl std::ops::Deref for LinearGaussianModel {
    type Target = LinearGaussian;

    fn deref(&self) -> &LinearGaussian {
        &self.model
    }
}

#[derive(Debug, Clone)]
pub(crate) struct Factors {
    pub q: DMatrix<f64>,
    pub r: DMatrix<f64>,
    pub p0: DMatrix<f64>,
}

/// Which covariance of a [`LinearGaussianModel`] is not positive semidefinite.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{which} is not positive semidefinite (smallest eigenvalue {min_eigenvalue:.3e})")]
pub struct NotPsd {
    /// "Q", "R" or "P0".
    pub which: &'static str,
    /// The offending eigenvalue.
    pub min_eigenvalue: f64,
}

impl LinearGaussianModel {
    /// Build the model, factoring its covariances. Dimensions are the caller's
    /// responsibility (the problem loader checks them with field names).
    #[allow(non_snake_case)]
    pub fn new(
        F: DMatrix<f64>,
        H: DMatrix<f64>,
        Q: DMatrix<f64>,
        R: DMatrix<f64>,
        x0: DVector<f64>,
        P0: DMatrix<f64>,
    ) -> Result<Self, NotPsd> {
        let f = |m: &DMatrix<f64>, which| {
            crate::linalg::psd_factor(m).map_err(|min_eigenvalue| NotPsd {
                which,
                min_eigenvalue,
            })
        };
        let factors = Factors {
            q: f(&Q, "Q")?,
            r: f(&R, "R")?,
            p0: f(&P0, "P0")?,
        };
        Ok(LinearGaussianModel {
            model: LinearGaussian { F, H, Q, R, x0, P0 },
            factors,
        })
    }

    /// Measurement dimension m.
    pub fn n_z(&self) -> usize {
        self.H.nrows()
    }
}

impl TruthModel for LinearGaussianModel {
    fn n_x(&self) -> usize {
        self.F.nrows()
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        sample_gaussian(&self.x0, &self.factors.p0, rng)
    }

    fn propagate(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        sample_gaussian(&(&self.F * x), &self.factors.q, rng)
    }

    fn measure(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        out.push(Measurement {
            sensor: 0,
            z: sample_gaussian(&(&self.H * x), &self.factors.r, rng),
        });
    }
}

/// A borrowed truth model is a truth model (catalog models lend `&dyn TruthModel`).
impl<T: TruthModel + ?Sized> TruthModel for &T {
    fn n_x(&self) -> usize {
        (**self).n_x()
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        (**self).initial_state(rng)
    }

    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        (**self).propagate(k, x, rng)
    }

    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        (**self).measure(k, x, rng, out)
    }

    fn input(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> Option<DVector<f64>> {
        (**self).input(k, x, rng)
    }
}
