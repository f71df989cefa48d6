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

#![allow(non_snake_case)]

pub mod eskf;
pub mod nav;
pub mod truth;

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::Deserialize;

use super::{
    CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table, positive,
};
use crate::filter::Filter;
use crate::model::TruthModel;
use crate::params::NoiseKind;
use eskf::Eskf;
use nav::{Mat15, NoiseDensities, Nominal};
use truth::{DRIVE, InitialSigma, InsTruth, TruthNoise};

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

/// The `[model]` table (without `name`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Settings {
    /// IMU sample rate, Hz (dt · imu_rate must be a whole number of samples).
    #[serde(default = "default_imu_rate")]
    imu_rate: f64,
    /// GNSS fix period, s (a whole number of filter steps).
    #[serde(default = "default_gnss_period")]
    gnss_period: f64,
    /// GNSS outage `[start, end)`, s; omit for none.
    #[serde(default)]
    gnss_outage: Option<[f64; 2]>,
    truth: TruthSettings,
    #[serde(default)]
    initial: InitialSettings,
}

fn default_imu_rate() -> f64 {
    100.0
}

fn default_gnss_period() -> f64 {
    1.0
}

/// `[model.truth]`: the simulated sensors' noise.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthSettings {
    accel_noise: [f64; 3],
    gyro_noise: f64,
    accel_bias_rw: f64,
    gyro_bias_rw: f64,
    gnss_h: f64,
    gnss_v: f64,
}

/// `[model.initial]`: one-sigma initial errors (truth draws and the filter's P0).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct InitialSettings {
    pos_h: f64,
    pos_v: f64,
    vel: f64,
    tilt: f64,
    yaw: f64,
    accel_bias: f64,
    gyro_bias: f64,
}

impl Default for InitialSettings {
    fn default() -> Self {
        InitialSettings {
            pos_h: 2.0,
            pos_v: 3.0,
            vel: 0.02,
            tilt: 0.01,
            yaw: 0.05,
            accel_bias: 0.02,
            gyro_bias: 2e-4,
        }
    }
}

/// A whole multiple `n ≥ 1` of `unit` equal to `v` (to 1e-6 relative), at most `max`.
fn whole(field: &str, v: f64, unit: f64, max: usize) -> Result<usize, ModelError> {
    let r = v / unit;
    let n = r.round();
    if !(r.is_finite() && n >= 1.0 && (r - n).abs() <= 1e-6 * n && n <= max as f64) {
        return Err(ModelError::new(
            field,
            format!("must make a whole number (1 to {max}) of {unit} s steps, got {v}"),
        ));
    }
    Ok(n as usize)
}

fn build(table: &toml::Table, ctx: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Ok(Box::new(InsGnss::new(table, ctx)?))
}

impl InsGnss {
    /// Build from a `[model]` table (without `name`), as [`ENTRY`] does, keeping the
    /// concrete type (tests and benches reach the filter's and truth's own methods).
    pub fn new(table: &toml::Table, ctx: &ModelContext) -> Result<InsGnss, ModelError> {
        build_model(table, ctx)
    }
}

fn build_model(table: &toml::Table, ctx: &ModelContext) -> Result<InsGnss, ModelError> {
    let s: Settings = parse_table(table)?;
    let dt = positive("dt", ctx.dt)?;
    let rate = positive("imu_rate", s.imu_rate)?;
    let n_imu = whole("imu_rate", dt * rate, 1.0, 1000).map_err(|_| {
        ModelError::new(
            "imu_rate",
            format!(
                "dt · imu_rate must be a whole number of samples (1 to 1000), got {}",
                dt * rate
            ),
        )
    })?;
    let gnss_every = whole(
        "gnss_period",
        positive("gnss_period", s.gnss_period)?,
        dt,
        1 << 30,
    )?;
    let outage = match s.gnss_outage {
        None => (f64::INFINITY, f64::INFINITY),
        Some([a, b]) => {
            if !(a.is_finite() && b.is_finite() && a >= 0.0 && a <= b) {
                return Err(ModelError::new(
                    "gnss_outage",
                    format!("must be [start, end] with 0 ≤ start ≤ end, got [{a}, {b}]"),
                ));
            }
            (a, b)
        }
    };
    let t = &s.truth;
    let mut accel = Vector3::zeros();
    for (i, axis) in ["x", "y", "z"].iter().enumerate() {
        accel[i] = positive(&format!("truth.accel_noise.{axis}"), t.accel_noise[i])?;
    }
    let noise = TruthNoise {
        accel,
        gyro: positive("truth.gyro_noise", t.gyro_noise)?,
        accel_bias: positive("truth.accel_bias_rw", t.accel_bias_rw)?,
        gyro_bias: positive("truth.gyro_bias_rw", t.gyro_bias_rw)?,
        gnss_h: positive("truth.gnss_h", t.gnss_h)?,
        gnss_v: positive("truth.gnss_v", t.gnss_v)?,
    };
    let i = &s.initial;
    let init = InitialSigma {
        pos_h: positive("initial.pos_h", i.pos_h)?,
        pos_v: positive("initial.pos_v", i.pos_v)?,
        vel: positive("initial.vel", i.vel)?,
        tilt: positive("initial.tilt", i.tilt)?,
        yaw: positive("initial.yaw", i.yaw)?,
        accel_bias: positive("initial.accel_bias", i.accel_bias)?,
        gyro_bias: positive("initial.gyro_bias", i.gyro_bias)?,
    };
    // The attitude error must stay a small angle for the linearized filter.
    if init.tilt > 0.2 || init.yaw > 0.2 {
        return Err(ModelError::new(
            if init.tilt > 0.2 {
                "initial.tilt"
            } else {
                "initial.yaw"
            },
            "must be ≤ 0.2 rad (the error-state filter linearizes small attitude errors)",
        ));
    }
    Ok(InsGnss {
        truth: InsTruth {
            dt,
            n_imu,
            noise,
            init,
            gnss_every,
            outage,
            drive: DRIVE,
        },
    })
}

/// The built `ins_gnss` model.
#[derive(Debug, Clone)]
pub struct InsGnss {
    /// The truth model.
    pub truth: InsTruth,
}

impl InsGnss {
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
