//! `ins_gnss`: a strapdown INS with loosely coupled GNSS position fixes, as a 15-state
//! error-state EKF, on a simulated 90 s drive.
//!
//! - Frame: local-level NED, flat Earth, constant gravity 9.81 m/s², no Earth rotation
//!   ([`nav`] says why that is adequate here). Body frame forward–right–down.
//! - Error state (n_x = 15, the NEES dimension): `pn pe pd` (m), `vn ve vd` (m/s),
//!   `roll pitch yaw` (rad, the small rotation from estimated to true attitude about the
//!   N, E, D axes), `bax bay baz` (m/s²), `bgx bgy bgz` (rad/s).
//! - Filter step dt (0.1 s in the shipped problem); the truth hands the filter the step's
//!   IMU samples (100 Hz by default: 10 × [f_b, ω_b], a 60-vector) through
//!   [`crate::model::TruthModel::input`], and the filter mechanizes each one
//!   ([`eskf`]).
//! - Truth ([`truth`]): the car's kinematics integrated with RK4 at half the IMU interval
//!   (accelerate, straight, right turn, straight, left turn, brake, stand still; hills and
//!   body roll), IMU = true specific force and rate + random-walk biases + white noise,
//!   GNSS position fixes (sensor 0, 3-D) every `gnss_period` except during the outage.
//! - Parameters: accelerometer white noise per body axis, gyro white noise, the two bias
//!   random walks (free), GNSS horizontal and vertical variance (fixed). The truth has
//!   the filter's noise structure, so a tuned filter should recover
//!   [`CatalogModel::truth_values`].
//!
//! Identifiability over the 90 s drive: each parameter has components of its own (the
//! vertical channel for `q_accel_z`, attitude for `q_gyro`, the biases for their walks),
//! but in the tuning objective as a whole some stand in for others: a large accelerometer
//! bias walk for white accelerometer noise, gyro noise for forward accelerometer noise
//! (both feed the horizontal velocity error, the gyro through tilt × g). Least squares on
//! all of J has local minima there; [`crate::tune::LocalSearch::GaussNewton`] first solves
//! one moment equation per parameter on its own components, which has none. The shipped
//! problem's RTK-grade fixes (2 cm / 4 cm) and calibrated initial biases make every
//! parameter's mark on its components large enough to resolve to about 10% with 120 runs;
//! with metre-level GNSS and uncalibrated biases the forward accelerometer noise and the
//! bias walks resolve only to 20–25% (1σ).

pub mod eskf;
pub mod nav;
mod settings;
pub mod truth;

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::{CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table};
use crate::filter::Filter;
use crate::model::TruthModel;
use crate::params::NoiseKind;
use eskf::Eskf;
use nav::{Mat15, NoiseDensities, Nominal};
use settings::Settings;
use truth::InsTruth;

/// Names of the 15 error-state components.
pub const STATE_NAMES: [&str; 15] = [
    "pn", "pe", "pd", "vn", "ve", "vd", "roll", "pitch", "yaw", "bax", "bay", "baz", "bgx", "bgy",
    "bgz",
];

/// Names of the GNSS measurement components (NED position).
pub const MEASUREMENT_NAMES: [&str; 3] = ["gnss_n", "gnss_e", "gnss_d"];

/// The filter parameters, in θ order.
pub const PARAMS: &[ParamInfo] = &[
    ParamInfo {
        name: "q_accel_x",
        unit: "(m/s²)²/Hz",
        about: "accelerometer white noise density, body x (forward)",
        noise: NoiseKind::Process,
        components: &[3, 4],
    },
    ParamInfo {
        name: "q_accel_y",
        unit: "(m/s²)²/Hz",
        about: "accelerometer white noise density, body y (right)",
        noise: NoiseKind::Process,
        components: &[3, 4],
    },
    ParamInfo {
        name: "q_accel_z",
        unit: "(m/s²)²/Hz",
        about: "accelerometer white noise density, body z (down, the vertical channel)",
        noise: NoiseKind::Process,
        components: &[5],
    },
    ParamInfo {
        name: "q_gyro",
        unit: "(rad/s)²/Hz",
        about: "gyro white noise density (angle random walk), all axes",
        noise: NoiseKind::Process,
        components: &[6, 7, 8],
    },
    ParamInfo {
        name: "q_accel_bias",
        unit: "(m/s²)²/s",
        about: "accelerometer bias random walk, all axes",
        noise: NoiseKind::Process,
        components: &[9, 10, 11],
    },
    ParamInfo {
        name: "q_gyro_bias",
        unit: "(rad/s)²/s",
        about: "gyro bias random walk, all axes",
        noise: NoiseKind::Process,
        components: &[12, 13, 14],
    },
    ParamInfo {
        name: "r_gnss_h",
        unit: "m²",
        about: "GNSS horizontal position variance per axis (receiver datasheet)",
        noise: NoiseKind::Measurement,
        components: &[0, 1],
    },
    ParamInfo {
        name: "r_gnss_v",
        unit: "m²",
        about: "GNSS vertical position variance (receiver datasheet)",
        noise: NoiseKind::Measurement,
        components: &[2],
    },
];

/// The catalog entry.
pub const ENTRY: CatalogEntry = CatalogEntry {
    name: "ins_gnss",
    about: "strapdown INS + GNSS position, 15-state error-state EKF on a simulated drive",
    params: PARAMS,
    build,
};

fn build(table: &toml::Table, ctx: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Ok(Box::new(InsGnss::new(table, ctx)?))
}

/// The built `ins_gnss` model.
#[derive(Debug, Clone)]
pub struct InsGnss {
    /// The truth model.
    pub truth: InsTruth,
}

impl InsGnss {
    /// Build from a `[model]` table (without `name`), as [`ENTRY`] does, keeping the
    /// concrete type (tests and benches reach the filter's and truth's own methods).
    pub fn new(table: &toml::Table, ctx: &ModelContext) -> Result<InsGnss, ModelError> {
        let settings: Settings = parse_table(table)?;
        Ok(InsGnss {
            truth: settings.truth(ctx)?,
        })
    }

    /// The filter with parameters θ (see [`PARAMS`]) as its concrete type; missing entries
    /// are NaN, which the engine reports as a diverged filter.
    pub fn eskf(&self, theta: &[f64]) -> Eskf {
        let th = |i: usize| theta.get(i).copied().unwrap_or(f64::NAN);
        let s = &self.truth.init;
        let sq = |v: f64| v * v;
        let diag = [
            sq(s.pos_h),
            sq(s.pos_h),
            sq(s.pos_v),
            sq(s.vel),
            sq(s.vel),
            sq(s.vel),
            sq(s.tilt),
            sq(s.tilt),
            sq(s.yaw),
            sq(s.accel_bias),
            sq(s.accel_bias),
            sq(s.accel_bias),
            sq(s.gyro_bias),
            sq(s.gyro_bias),
            sq(s.gyro_bias),
        ];
        Eskf {
            n_imu: self.truth.n_imu,
            dt: self.truth.dt,
            noise: NoiseDensities {
                accel: Vector3::new(th(0), th(1), th(2)),
                gyro: th(3),
                accel_bias: th(4),
                gyro_bias: th(5),
            },
            R: Matrix3::from_diagonal(&Vector3::new(th(6), th(6), th(7))),
            x0: Nominal {
                p: Vector3::zeros(),
                v: Vector3::zeros(),
                q: UnitQuaternion::identity(),
                ba: Vector3::zeros(),
                bg: Vector3::zeros(),
            },
            P0: Mat15::from_diagonal(&nalgebra::SVector::<f64, 15>::from_column_slice(&diag)),
        }
    }
}

impl CatalogModel for InsGnss {
    fn state_names(&self) -> Vec<String> {
        STATE_NAMES.iter().map(|s| s.to_string()).collect()
    }

    fn measurement_names(&self) -> Vec<String> {
        MEASUREMENT_NAMES.iter().map(|s| s.to_string()).collect()
    }

    fn truth(&self) -> &dyn TruthModel {
        &self.truth
    }

    fn filter(&self, theta: &[f64]) -> Box<dyn Filter> {
        Box::new(self.eskf(theta))
    }

    fn truth_values(&self) -> Vec<f64> {
        let n = &self.truth.noise;
        vec![
            n.accel.x,
            n.accel.y,
            n.accel.z,
            n.gyro,
            n.accel_bias,
            n.gyro_bias,
            n.gnss_h,
            n.gnss_v,
        ]
    }
}
