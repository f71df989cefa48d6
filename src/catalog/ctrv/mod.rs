//! `ctrv_radar_lidar`: a constant-turn-rate-and-velocity (CTRV) target tracked by a UKF
//! from a lidar and a radar that take turns.
//!
//! State `x = [px, py, v, yaw, yaw_rate]` (m, m, m/s, rad, rad/s); yaw is not wrapped in
//! the state (the truth and the filter both carry it continuously), and the estimation
//! error of yaw is wrapped to (−π, π].
//!
//! **Truth.** `px' = v cos yaw`, `py' = v sin yaw`, `v' = a`, `yaw' = yaw_rate`,
//! `yaw_rate' = yaw_acc`, integrated by RK4 with `substeps` steps per filter step. The
//! longitudinal acceleration `a ~ N(0, q_accel)` and the yaw acceleration
//! `yaw_acc ~ N(0, q_yaw_accel)` are drawn once per filter step and held over it: the
//! noise model the CTRV filter assumes, so the filter's noise structure is the truth's.
//!
//! **Filter.** The closed-form CTRV transition over `T = dt` with the noise
//! `w = [ν_a, ν_yawdd]` entering as in the usual discretization (Thrun, Burgard and Fox,
//! *Probabilistic Robotics*, 2005, §5.3; Schubert, Richter and Wanielik, "Comparison and
//! evaluation of advanced motion models for vehicle tracking", FUSION 2008):
//!
//! ```text
//! px  += v/ω (sin(yaw + ωT) − sin yaw)  + ½T² cos(yaw) ν_a
//! py  += v/ω (cos yaw − cos(yaw + ωT))  + ½T² sin(yaw) ν_a
//! v   += T ν_a
//! yaw += ωT + ½T² ν_yawdd
//! ω   += T ν_yawdd
//! ```
//!
//! with a Taylor branch for `|ωT| < 1e-3` (the difference quotient loses digits there).
//! The noise enters through `yaw`, so the UKF uses augmented sigma points over
//! `[x; w]` with `w ~ N(0, diag(q_accel, q_yaw_accel))`. The unscented transform uses
//! α = 1, β = 2, κ = 0: λ = 0 makes every mean weight non-negative (the common
//! `λ = 3 − n` gives a weight of −4/3 to the centre point for the 7-dimensional augmented
//! state, which can make the predicted covariance indefinite), and β = 2 is the Gaussian
//! choice.
//!
//! **Sensors.** Both at the origin, taking turns: the lidar (px, py) at odd steps, the
//! radar (range, bearing, range rate) at even steps when the target's range is within
//! `[radar.min_range, radar.max_range]` (no detection otherwise), so the measurement
//! dimension alternates 2 / 3 (or 2 / 0). Bearings are wrapped to (−π, π] in the
//! measurement, in the innovation, and in the UKF's predicted-measurement mean.

mod filter;
mod settings;
mod system;
mod truth;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix5, Vector2, Vector3, Vector5};

use super::{CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table};
use crate::filter::{Filter, Ukf};
use crate::linalg::to_dynamic;
use crate::model::TruthModel;
use crate::params::NoiseKind;
use settings::Spec;

pub use crate::linalg::wrap_angle;
pub use filter::CtrvFilter;
pub use system::CtrvSystem;
pub use system::{LIDAR, RADAR};
pub use truth::CtrvTruth;

/// The filter parameters, in θ order.
const PARAMS: &[ParamInfo] = &[
    ParamInfo {
        name: "q_accel",
        unit: "(m/s²)²",
        about: "variance of the longitudinal acceleration, held over each filter step",
        noise: NoiseKind::Process,
        components: &[2],
    },
    ParamInfo {
        name: "q_yaw_accel",
        unit: "(rad/s²)²",
        about: "variance of the yaw acceleration, held over each filter step",
        noise: NoiseKind::Process,
        components: &[3, 4],
    },
    ParamInfo {
        name: "r_lidar",
        unit: "m²",
        about: "lidar position variance (each axis)",
        noise: NoiseKind::Measurement,
        components: &[0, 1],
    },
    ParamInfo {
        name: "r_radar_range",
        unit: "m²",
        about: "radar range variance",
        noise: NoiseKind::Measurement,
        components: &[2],
    },
    ParamInfo {
        name: "r_radar_bearing",
        unit: "rad²",
        about: "radar bearing variance",
        noise: NoiseKind::Measurement,
        components: &[3],
    },
    ParamInfo {
        name: "r_radar_rate",
        unit: "(m/s)²",
        about: "radar range-rate variance",
        noise: NoiseKind::Measurement,
        components: &[4],
    },
];

/// The catalog entry.
pub const ENTRY: CatalogEntry = CatalogEntry {
    name: "ctrv_radar_lidar",
    about: "CTRV target (px, py, v, yaw, yaw rate), UKF with augmented noise, lidar and radar \
            alternating",
    params: PARAMS,
    build,
};

fn build(table: &toml::Table, ctx: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Ok(Box::new(CtrvModel::from_table(table, ctx)?))
}

/// The built model: truth, and the UKF at any parameter values.
#[derive(Debug, Clone)]
pub struct CtrvModel {
    /// The truth.
    pub truth: CtrvTruth,
    /// The filter's system model.
    pub system: CtrvSystem,
    /// Sigma-point scaling `(α, β, κ)`.
    pub ukf_scaling: (f64, f64, f64),
    truth_values: [f64; 6],
}

impl CtrvModel {
    /// Build from a `[model]` table without its `name` key (what [`ENTRY`]'s `build` does,
    /// returning the concrete type).
    pub fn from_table(table: &toml::Table, ctx: &ModelContext) -> Result<Self, ModelError> {
        let spec: Spec = parse_table(table)?;
        Self::from_spec(&spec, ctx)
    }

    fn from_spec(spec: &Spec, ctx: &ModelContext) -> Result<Self, ModelError> {
        let tv = spec.validate(ctx)?;
        let dt = ctx.dt;
        Ok(CtrvModel {
            truth: CtrvTruth {
                dt,
                substeps: spec.substeps,
                accel_std: [tv[0].sqrt(), tv[1].sqrt()],
                lidar_std: tv[2].sqrt(),
                radar_std: [tv[3].sqrt(), tv[4].sqrt(), tv[5].sqrt()],
                radar_range: [spec.radar.min_range, spec.radar.max_range],
                x0: spec.initial.mean,
                x0_std: spec.initial.std,
            },
            system: CtrvSystem { dt },
            ukf_scaling: (spec.ukf.alpha, spec.ukf.beta, spec.ukf.kappa),
            truth_values: tv,
        })
    }

    /// The UKF with parameter values `theta` (θ order: q_accel, q_yaw_accel, r_lidar,
    /// r_radar_range, r_radar_bearing, r_radar_rate). Missing or invalid values make the
    /// filter fail with a non-positive-definite covariance rather than panic.
    pub fn ukf(&self, theta: &[f64]) -> CtrvFilter {
        let th = |i: usize| theta.get(i).copied().unwrap_or(f64::NAN);
        CtrvFilter {
            system: self.system,
            q: [th(0), th(1)],
            R_lidar: Matrix2::from_diagonal(&Vector2::new(th(2), th(2))),
            R_radar: Matrix3::from_diagonal(&Vector3::new(th(3), th(4), th(5))),
            x0: Vector5::from(self.truth.x0),
            P0: Matrix5::from_diagonal(&Vector5::from_fn(|i, _| {
                self.truth.x0_std[i] * self.truth.x0_std[i]
            })),
            scaling: self.ukf_scaling,
        }
    }

    /// The same filter as [`CtrvModel::ukf`], as the generic [`Ukf`] with augmented process
    /// noise (slower; the reference the fixed-size filter is tested against). Its state
    /// error is not wrapped.
    pub fn reference_ukf(&self, theta: &[f64]) -> Ukf<CtrvSystem> {
        let f = self.ukf(theta);
        let mut ukf = Ukf::new(
            self.system,
            DMatrix::zeros(5, 5),
            vec![to_dynamic(&f.R_lidar), to_dynamic(&f.R_radar)],
            DVector::from_column_slice(f.x0.as_slice()),
            to_dynamic(&f.P0),
        );
        ukf.alpha = self.ukf_scaling.0;
        ukf.beta = self.ukf_scaling.1;
        ukf.kappa = self.ukf_scaling.2;
        ukf.augmented_noise = Some(DMatrix::from_diagonal(&DVector::from_row_slice(&f.q)));
        ukf
    }
}

impl CatalogModel for CtrvModel {
    fn state_names(&self) -> Vec<String> {
        ["px", "py", "v", "yaw", "yaw_rate"]
            .iter()
            .map(|s| s.to_string())
            .collect()
    }

    fn measurement_names(&self) -> Vec<String> {
        [
            "lidar_px",
            "lidar_py",
            "radar_range",
            "radar_bearing",
            "radar_rate",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    }

    fn truth(&self) -> &dyn TruthModel {
        &self.truth
    }

    fn filter(&self, theta: &[f64]) -> Box<dyn Filter> {
        Box::new(self.ukf(theta))
    }

    fn truth_values(&self) -> Vec<f64> {
        self.truth_values.to_vec()
    }
}
