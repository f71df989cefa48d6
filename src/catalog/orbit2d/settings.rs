//! The `[model]` table of `orbit2d`: its serde schema with every default, and the check
//! that names the first bad field.

use serde::Deserialize;

use super::EARTH_RADIUS;
use crate::catalog::{ModelContext, ModelError, positive};

/// The `[model]` table of a problem file (without `name`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Settings {
    /// Radius of the nominal circular orbit the initial state is drawn around, km.
    pub radius: f64,
    /// The truth's dynamics and noise.
    pub truth: TruthSettings,
    /// The ground stations and their sensor noise.
    pub stations: StationSettings,
    /// The initial state's spread (truth draws x0 from it; the filter starts with it).
    pub initial: InitialSettings,
    /// The filter's own numerics.
    pub filter: FilterSettings,
}

/// `[model.truth]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TruthSettings {
    /// Largest RK4 step, s; the truth uses dt / ceil(dt / step).
    pub step: f64,
    /// PSD of the radial random acceleration, km²/s³.
    pub q_radial: f64,
    /// PSD of the along-track random acceleration, km²/s³.
    pub q_along: f64,
}

/// `[model.stations]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StationSettings {
    /// Number of stations, equally spaced on the equator.
    pub count: usize,
    /// Longitude of station 0 east of the satellite's initial position at t = 0, degrees.
    pub phase_deg: f64,
    /// Elevation mask, degrees: a station measures when the satellite is at least this
    /// high above its horizon.
    pub mask_deg: f64,
    /// Range noise standard deviation, km.
    pub range_std: f64,
    /// Range-rate noise standard deviation, km/s.
    pub range_rate_std: f64,
    /// Line-of-sight angle noise standard deviation, rad.
    pub angle_std: f64,
}

/// `[model.initial]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InitialSettings {
    /// Position standard deviation per axis, km.
    pub pos_std: f64,
    /// Velocity standard deviation per axis, km/s.
    pub vel_std: f64,
}

/// `[model.filter]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterSettings {
    /// RK4 steps per filter step dt for the mean and the state transition matrix.
    pub substeps: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            radius: 6678.0,
            truth: TruthSettings::default(),
            stations: StationSettings::default(),
            initial: InitialSettings::default(),
            filter: FilterSettings::default(),
        }
    }
}

impl Default for TruthSettings {
    fn default() -> Self {
        TruthSettings {
            step: 1.0,
            q_radial: 2e-12,
            q_along: 1e-11,
        }
    }
}

impl Default for StationSettings {
    fn default() -> Self {
        StationSettings {
            count: 12,
            phase_deg: 15.0,
            mask_deg: 10.0,
            range_std: 0.01,
            range_rate_std: 1e-6,
            angle_std: 1e-3,
        }
    }
}

impl Default for InitialSettings {
    fn default() -> Self {
        InitialSettings {
            pos_std: 0.1,
            vel_std: 1e-4,
        }
    }
}

impl Default for FilterSettings {
    fn default() -> Self {
        FilterSettings { substeps: 2 }
    }
}

/// Station count above which the problem is refused (one sensor per station).
const MAX_STATIONS: usize = 1000;
/// Largest number of RK4 steps per filter step, truth or filter.
const MAX_SUBSTEPS: usize = 10_000;

impl Settings {
    /// Check every field, naming the first bad one.
    pub fn validate(&self, ctx: &ModelContext) -> Result<(), ModelError> {
        positive("dt", ctx.dt)?;
        positive("radius", self.radius)?;
        if self.radius <= EARTH_RADIUS {
            return Err(ModelError::new(
                "radius",
                format!(
                    "{} km is inside the Earth (radius {EARTH_RADIUS} km)",
                    self.radius
                ),
            ));
        }
        positive("truth.step", self.truth.step)?;
        if ctx.dt / self.truth.step > MAX_SUBSTEPS as f64 {
            return Err(ModelError::new(
                "truth.step",
                format!(
                    "{} s is more than {MAX_SUBSTEPS} steps per dt = {} s",
                    self.truth.step, ctx.dt
                ),
            ));
        }
        positive("truth.q_radial", self.truth.q_radial)?;
        positive("truth.q_along", self.truth.q_along)?;
        let s = &self.stations;
        if s.count == 0 || s.count > MAX_STATIONS {
            return Err(ModelError::new(
                "stations.count",
                format!("must be 1..={MAX_STATIONS}, got {}", s.count),
            ));
        }
        if !s.phase_deg.is_finite() {
            return Err(ModelError::new(
                "stations.phase_deg",
                format!("must be finite, got {}", s.phase_deg),
            ));
        }
        if !(s.mask_deg.is_finite() && (0.0..90.0).contains(&s.mask_deg)) {
            return Err(ModelError::new(
                "stations.mask_deg",
                format!("must be in [0, 90), got {}", s.mask_deg),
            ));
        }
        positive("stations.range_std", s.range_std)?;
        positive("stations.range_rate_std", s.range_rate_std)?;
        positive("stations.angle_std", s.angle_std)?;
        positive("initial.pos_std", self.initial.pos_std)?;
        positive("initial.vel_std", self.initial.vel_std)?;
        if self.filter.substeps == 0 || self.filter.substeps > MAX_SUBSTEPS {
            return Err(ModelError::new(
                "filter.substeps",
                format!("must be 1..={MAX_SUBSTEPS}, got {}", self.filter.substeps),
            ));
        }
        Ok(())
    }
}
