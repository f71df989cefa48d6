//! `orbit2d`: a satellite in a near-circular low Earth orbit in the plane, tracked by an
//! EKF from a ring of ground stations that rotate with the Earth.
//!
//! Units are km and s throughout. The state is inertial, `x = [x, y, vx, vy]` (km, km/s).
//!
//! **Truth.** Two-body gravity plus a random acceleration,
//! `r̈ = −μ r/|r|³ + a_R û_R + a_T û_T`, integrated by RK4 at its own step h (the largest
//! step ≤ `truth.step` that divides the filter's dt). `û_R = r/|r|` is radial and
//! `û_T` the transverse (along-track) direction, perpendicular to `û_R` in the sense of
//! motion. `a_R` and `a_T` are white noise held constant over each RK4 step,
//! `a ~ N(0, q/h)`, whose equivalent continuous power spectral density is `q`
//! ((km/s²)²/Hz = km²/s³). Along-track is where drag and its mismodelling act, so the
//! shipped scenario makes `q_along` several times `q_radial`.
//!
//! **Filter.** An EKF whose transition is the two-body flow over dt (RK4 with
//! `filter.substeps` steps). Its Jacobian, the state transition matrix Φ, is integrated
//! alongside by the variational equations `Φ' = A Φ`, `A = [[0, I], [G(r), 0]]`,
//! `G = μ (3 r r'/|r|⁵ − I/|r|³)`, through the same RK4 stages, so it is the exact
//! derivative of the discrete map. Process noise is continuous white acceleration noise in
//! the radial/along-track frame, discretized over dt per axis
//! (`Q = [[dt³/3, dt²/2], [dt²/2, dt]] ⊗ C diag(q_radial, q_along) C'`, with `C` the
//! frame at the middle of the step), the same structure as the truth's noise up to terms of
//! order (h/dt)² and (n dt)² (n the mean motion, ≈ 1.2e-3 rad/s): below 1% here.
//!
//! **Sensors.** `stations.count` stations equally spaced on the equator (radius 6378 km),
//! rotating at ω = 7.2921e-5 rad/s. Station i measures, whenever the satellite is above its
//! elevation mask (decided on the true state): range |ρ| (km), range rate ρ·ρ̇/|ρ| (km/s)
//! and the line-of-sight angle `atan2(ρ·û_up, ρ·û_east)` (rad), the in-plane angle of the
//! satellite above the station's eastern horizon, running from 0 (east horizon) through
//! π/2 (zenith) to π (west horizon); unlike an elevation `asin(ρ·û_up/|ρ|)` it stays
//! differentiable at zenith. ρ is the satellite's position relative to the station and ρ̇
//! its velocity relative to the moving station. Each station is its own sensor (sensor
//! index = station index, 3 components), so the measurement dimension is 0, 3, 6, … from
//! step to step.
//!
//! Reference: Vallado, *Fundamentals of Astrodynamics and Applications* (4th ed., 2013),
//! §10.6 (orbit determination with the EKF) and §3.4 (site-track geometry).

mod filter;
mod settings;
mod system;
mod truth;

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

use super::{CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table};
use crate::filter::Filter;
use crate::model::TruthModel;
use crate::params::NoiseKind;

pub use filter::OrbitEkf;
pub use settings::{FilterSettings, InitialSettings, Settings, StationSettings, TruthSettings};
pub use system::{EARTH_RADIUS, EARTH_RATE, MU};
pub use system::{OrbitSystem, Stations};
pub use truth::OrbitTruth;

/// The catalog entry.
pub const ENTRY: CatalogEntry = CatalogEntry {
    name: "orbit2d",
    about: "planar LEO satellite, two-body + random radial/along-track acceleration, \
            EKF from a ring of rotating ground stations (range, range rate, LOS angle)",
    params: &PARAMS,
    build,
};

/// The filter's parameters, in θ order.
const PARAMS: [ParamInfo; 5] = [
    ParamInfo {
        name: "q_radial",
        unit: "km²/s³",
        about: "PSD of the radial random acceleration ((km/s²)²/Hz)",
        noise: NoiseKind::Process,
        components: &[0, 1, 2, 3],
    },
    ParamInfo {
        name: "q_along",
        unit: "km²/s³",
        about: "PSD of the along-track random acceleration ((km/s²)²/Hz)",
        noise: NoiseKind::Process,
        components: &[0, 1, 2, 3],
    },
    // Measurement components are given for station 0 only: the station count is set at run
    // time and these lists are static.
    ParamInfo {
        name: "r_range",
        unit: "km²",
        about: "range noise variance of every station",
        noise: NoiseKind::Measurement,
        components: &[0],
    },
    ParamInfo {
        name: "r_range_rate",
        unit: "(km/s)²",
        about: "range-rate noise variance of every station",
        noise: NoiseKind::Measurement,
        components: &[1],
    },
    ParamInfo {
        name: "r_angle",
        unit: "rad²",
        about: "line-of-sight angle noise variance of every station",
        noise: NoiseKind::Measurement,
        components: &[2],
    },
];

/// `orbit2d` built from a problem file: truth, filter factory and names.
#[derive(Debug, Clone)]
pub struct Orbit2d {
    /// The validated settings.
    pub settings: Settings,
    /// The truth model.
    pub truth: OrbitTruth,
    /// The filter's deterministic model (shared by every θ).
    pub system: OrbitSystem,
}

impl Orbit2d {
    /// Build from a `[model]` table (without `name`), validating every field.
    pub fn from_table(table: &toml::Table, ctx: &ModelContext) -> Result<Self, ModelError> {
        let settings: Settings = parse_table(table)?;
        Self::new(settings, ctx)
    }

    /// Build from settings, validating every field.
    pub fn new(settings: Settings, ctx: &ModelContext) -> Result<Self, ModelError> {
        settings.validate(ctx)?;
        let st = &settings.stations;
        let stations = Stations::new(
            st.count,
            st.phase_deg.to_radians(),
            st.mask_deg.to_radians(),
            ctx.dt,
        );
        let substeps = ((ctx.dt / settings.truth.step).ceil() as usize).max(1);
        let h = ctx.dt / substeps as f64;
        let truth = OrbitTruth {
            x0: Vector4::new(settings.radius, 0.0, 0.0, (MU / settings.radius).sqrt()),
            initial_std: (settings.initial.pos_std, settings.initial.vel_std),
            substeps,
            h,
            accel_std: (
                (settings.truth.q_radial / h).sqrt(),
                (settings.truth.q_along / h).sqrt(),
            ),
            sensor_std: Vector3::new(st.range_std, st.range_rate_std, st.angle_std),
            stations: stations.clone(),
        };
        let system = OrbitSystem {
            dt: ctx.dt,
            substeps: settings.filter.substeps,
            stations,
        };
        Ok(Orbit2d {
            settings,
            truth,
            system,
        })
    }

    /// The EKF at θ = [q_radial, q_along, r_range, r_range_rate, r_angle] (missing values
    /// are NaN, and a NaN filter diverges instead of panicking).
    pub fn ekf(&self, theta: &[f64]) -> OrbitEkf {
        let th = |i: usize| theta.get(i).copied().unwrap_or(f64::NAN);
        let (sp, sv) = self.truth.initial_std;
        OrbitEkf {
            system: self.system.clone(),
            q: (th(0), th(1)),
            R: Matrix3::from_diagonal(&Vector3::new(th(2), th(3), th(4))),
            x0: self.truth.x0,
            P0: Matrix4::from_diagonal(&Vector4::new(sp * sp, sp * sp, sv * sv, sv * sv)),
        }
    }
}

impl CatalogModel for Orbit2d {
    fn state_names(&self) -> Vec<String> {
        ["x", "y", "vx", "vy"].map(String::from).to_vec()
    }

    fn measurement_names(&self) -> Vec<String> {
        (0..self.system.stations.count)
            .flat_map(|i| ["range", "rate", "angle"].map(|m| format!("st{i}_{m}")))
            .collect()
    }

    fn truth(&self) -> &dyn TruthModel {
        &self.truth
    }

    fn filter(&self, theta: &[f64]) -> Box<dyn Filter> {
        Box::new(self.ekf(theta))
    }

    fn truth_values(&self) -> Vec<f64> {
        let s = &self.settings;
        vec![
            s.truth.q_radial,
            s.truth.q_along,
            s.stations.range_std.powi(2),
            s.stations.range_rate_std.powi(2),
            s.stations.angle_std.powi(2),
        ]
    }
}

fn build(table: &toml::Table, ctx: &ModelContext) -> Result<Box<dyn CatalogModel>, ModelError> {
    Ok(Box::new(Orbit2d::from_table(table, ctx)?))
}
