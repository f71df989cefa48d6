//! The `[model]` table of `ins_gnss`: its serde schema, defaults, and the check that names
//! the first bad field and turns the table into the truth it describes.

use nalgebra::Vector3;
use serde::Deserialize;

use super::truth::{DRIVE, InitialSigma, InsTruth, TruthNoise};
use crate::catalog::{ModelContext, ModelError, positive};

/// The `[model]` table (without `name`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Settings {
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

impl Settings {
    /// Check every field, naming the first bad one, and build the truth the settings
    /// describe.
    pub(super) fn truth(&self, ctx: &ModelContext) -> Result<InsTruth, ModelError> {
        let dt = positive("dt", ctx.dt)?;
        let rate = positive("imu_rate", self.imu_rate)?;
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
            positive("gnss_period", self.gnss_period)?,
            dt,
            1 << 30,
        )?;
        let outage = match self.gnss_outage {
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
        let t = &self.truth;
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
        let i = &self.initial;
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
        Ok(InsTruth {
            dt,
            n_imu,
            noise,
            init,
            gnss_every,
            outage,
            drive: DRIVE,
        })
    }
}
