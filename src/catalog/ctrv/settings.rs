//! The `[model]` table of `ctrv_radar_lidar`: its serde schema, defaults, and the check
//! that names the first bad field.

use serde::Deserialize;

use crate::catalog::{ModelContext, ModelError, positive};

fn default_substeps() -> usize {
    10
}

/// `[model]` minus `name`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Spec {
    /// RK4 steps of the truth per filter step.
    #[serde(default = "default_substeps")]
    pub(super) substeps: usize,
    pub(super) truth: TruthSpec,
    #[serde(default)]
    pub(super) initial: InitialSpec,
    #[serde(default)]
    pub(super) radar: RadarSpec,
    #[serde(default)]
    pub(super) ukf: UkfSpec,
}

fn default_r_lidar() -> f64 {
    0.0225
}
fn default_r_radar_range() -> f64 {
    0.09
}
fn default_r_radar_bearing() -> f64 {
    0.0009
}
fn default_r_radar_rate() -> f64 {
    0.09
}

/// `[model.truth]`: the truth's noise, as variances in the parameters' units.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TruthSpec {
    pub(super) q_accel: f64,
    pub(super) q_yaw_accel: f64,
    #[serde(default = "default_r_lidar")]
    pub(super) r_lidar: f64,
    #[serde(default = "default_r_radar_range")]
    pub(super) r_radar_range: f64,
    #[serde(default = "default_r_radar_bearing")]
    pub(super) r_radar_bearing: f64,
    #[serde(default = "default_r_radar_rate")]
    pub(super) r_radar_rate: f64,
}

/// `[model.initial]`: the initial state's mean and standard deviations (the truth draws
/// from it, the filter starts at its mean with its covariance).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct InitialSpec {
    pub(super) mean: [f64; 5],
    pub(super) std: [f64; 5],
}

impl Default for InitialSpec {
    fn default() -> Self {
        // Heading east at 5 m/s, turning left at 0.25 rad/s on a 20 m circle centred at
        // (−30, 0): the target crosses the negative x axis (radar bearing ±π) at about 6 s
        // and 19 s and completes about one lap in 25 s.
        InitialSpec {
            mean: [-30.0, -20.0, 5.0, 0.0, 0.25],
            std: [0.3, 0.3, 0.5, 0.1, 0.05],
        }
    }
}

/// `[model.radar]`: where the radar detects the target.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RadarSpec {
    #[serde(default = "default_min_range")]
    pub(super) min_range: f64,
    #[serde(default = "default_max_range")]
    pub(super) max_range: f64,
}

fn default_min_range() -> f64 {
    1.0
}
fn default_max_range() -> f64 {
    f64::INFINITY
}

impl Default for RadarSpec {
    fn default() -> Self {
        RadarSpec {
            min_range: default_min_range(),
            max_range: default_max_range(),
        }
    }
}

/// `[model.ukf]`: sigma-point scaling.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct UkfSpec {
    #[serde(default = "default_alpha")]
    pub(super) alpha: f64,
    #[serde(default = "default_beta")]
    pub(super) beta: f64,
    #[serde(default)]
    pub(super) kappa: f64,
}

fn default_alpha() -> f64 {
    1.0
}
fn default_beta() -> f64 {
    2.0
}

impl Default for UkfSpec {
    fn default() -> Self {
        UkfSpec {
            alpha: 1.0,
            beta: 2.0,
            kappa: 0.0,
        }
    }
}

fn finite(field: &str, v: f64) -> Result<f64, ModelError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ModelError::new(field, format!("must be finite, got {v}")))
    }
}

impl Spec {
    /// Check every field, naming the first bad one; returns the truth's
    /// variances in θ order (q_accel, q_yaw_accel, r_lidar, r_radar_range,
    /// r_radar_bearing, r_radar_rate).
    pub(super) fn validate(&self, ctx: &ModelContext) -> Result<[f64; 6], ModelError> {
        positive("dt", ctx.dt)?;
        if self.substeps == 0 || self.substeps > 10_000 {
            return Err(ModelError::new(
                "substeps",
                format!("must be in 1..=10000, got {}", self.substeps),
            ));
        }
        let t = &self.truth;
        let tv = [
            positive("truth.q_accel", t.q_accel)?,
            positive("truth.q_yaw_accel", t.q_yaw_accel)?,
            positive("truth.r_lidar", t.r_lidar)?,
            positive("truth.r_radar_range", t.r_radar_range)?,
            positive("truth.r_radar_bearing", t.r_radar_bearing)?,
            positive("truth.r_radar_rate", t.r_radar_rate)?,
        ];
        for i in 0..5 {
            finite(&format!("initial.mean[{i}]"), self.initial.mean[i])?;
            positive(&format!("initial.std[{i}]"), self.initial.std[i])?;
        }
        let rmin = self.radar.min_range;
        if !(rmin.is_finite() && rmin >= 0.0) {
            return Err(ModelError::new(
                "radar.min_range",
                format!("must be finite and >= 0, got {rmin}"),
            ));
        }
        let rmax = self.radar.max_range;
        if rmax.is_nan() || rmax <= rmin {
            return Err(ModelError::new(
                "radar.max_range",
                format!("must be > radar.min_range ({rmin}), got {rmax}"),
            ));
        }
        let u = &self.ukf;
        if !(u.alpha.is_finite() && u.alpha > 0.0 && u.alpha <= 1.0) {
            return Err(ModelError::new(
                "ukf.alpha",
                format!("must be in (0, 1], got {}", u.alpha),
            ));
        }
        finite("ukf.beta", u.beta)?;
        // n + λ = α² (n + κ) must be positive for the update (n = 5) and the augmented
        // prediction (n = 7).
        if !(u.kappa.is_finite() && u.kappa > -5.0) {
            return Err(ModelError::new(
                "ukf.kappa",
                format!("must be finite and > -5 (n + κ > 0), got {}", u.kappa),
            ));
        }
        Ok(tv)
    }
}
