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

#![allow(non_snake_case)]

use std::f64::consts::PI;

use nalgebra::{
    DMatrix, DVector, Matrix2, Matrix3, Matrix3x4, Matrix4, Matrix4x3, Vector2, Vector3, Vector4,
};
use rand::RngExt;
use rand_distr::StandardNormal;
use serde::Deserialize;

use super::{
    CatalogEntry, CatalogModel, ModelContext, ModelError, ParamInfo, parse_table, positive,
};
use crate::SimRng;
use crate::filter::{Estimate, Filter, FilterError, Innovation, SystemModel, check_measurement};
use crate::linalg::wrap_angle;
use crate::measurement::Measurement;
use crate::model::TruthModel;
use crate::params::NoiseKind;

/// Earth's gravitational parameter μ, km³/s².
pub const MU: f64 = 398_600.441_8;
/// Earth's equatorial radius, km (the stations' distance from the centre).
pub const EARTH_RADIUS: f64 = 6378.137;
/// Earth's rotation rate, rad/s.
pub const EARTH_RATE: f64 = 7.292_115e-5;

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

// ---------------------------------------------------------------------------------------
// Dynamics

/// Two-body acceleration −μ r/|r|³, km/s².
fn gravity(r: &Vector2<f64>) -> Vector2<f64> {
    let r2 = r.norm_squared();
    r * (-MU / (r2 * r2.sqrt()))
}

/// Gravity gradient G = ∂g/∂r = μ (3 r r'/|r|⁵ − I/|r|³), 1/s².
fn gravity_gradient(r: &Vector2<f64>) -> Matrix2<f64> {
    let r2 = r.norm_squared();
    let r3 = r2 * r2.sqrt();
    let r5 = r3 * r2;
    r * r.transpose() * (3.0 * MU / r5) - Matrix2::identity() * (MU / r3)
}

/// ẋ = [v, g(r) + a].
fn derivative(x: &Vector4<f64>, a: &Vector2<f64>) -> Vector4<f64> {
    let g = gravity(&x.fixed_rows::<2>(0).into_owned()) + a;
    Vector4::new(x[2], x[3], g[0], g[1])
}

/// One RK4 step of length h with the extra acceleration `a` held constant.
fn rk4(x: &Vector4<f64>, a: &Vector2<f64>, h: f64) -> Vector4<f64> {
    let k1 = derivative(x, a);
    let k2 = derivative(&(x + k1 * (h / 2.0)), a);
    let k3 = derivative(&(x + k2 * (h / 2.0)), a);
    let k4 = derivative(&(x + k3 * h), a);
    x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0)
}

/// `A Φ` for `A = [[0, I], [G(r), 0]]`, without forming A.
fn variational(x: &Vector4<f64>, phi: &Matrix4<f64>) -> Matrix4<f64> {
    let G = gravity_gradient(&x.fixed_rows::<2>(0).into_owned());
    let mut d = Matrix4::zeros();
    d.fixed_rows_mut::<2>(0).copy_from(&phi.fixed_rows::<2>(2));
    d.fixed_rows_mut::<2>(2)
        .copy_from(&(G * phi.fixed_rows::<2>(0)));
    d
}

/// One RK4 step of the state and of its transition matrix (the variational equations
/// through the same stages, so Φ is the exact Jacobian of the discrete step).
fn rk4_stm(x: &Vector4<f64>, phi: &Matrix4<f64>, h: f64) -> (Vector4<f64>, Matrix4<f64>) {
    let zero = Vector2::zeros();
    let (x1, p1) = (*x, *phi);
    let k1 = derivative(&x1, &zero);
    let l1 = variational(&x1, &p1);
    let x2 = x + k1 * (h / 2.0);
    let p2 = phi + l1 * (h / 2.0);
    let k2 = derivative(&x2, &zero);
    let l2 = variational(&x2, &p2);
    let x3 = x + k2 * (h / 2.0);
    let p3 = phi + l2 * (h / 2.0);
    let k3 = derivative(&x3, &zero);
    let l3 = variational(&x3, &p3);
    let x4 = x + k3 * h;
    let p4 = phi + l3 * h;
    let k4 = derivative(&x4, &zero);
    let l4 = variational(&x4, &p4);
    (
        x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0),
        phi + (l1 + l2 * 2.0 + l3 * 2.0 + l4) * (h / 6.0),
    )
}

/// Radial and along-track unit vectors at `x` (along-track: the radial turned by +90° in
/// the sense of the angular momentum, counter-clockwise when it is zero).
fn frame(r: &Vector2<f64>, v: &Vector2<f64>) -> (Vector2<f64>, Vector2<f64>) {
    let n = r.norm();
    let ur = if n > 0.0 { r / n } else { Vector2::x() };
    let sense = if r[0] * v[1] - r[1] * v[0] < 0.0 {
        -1.0
    } else {
        1.0
    };
    (ur, Vector2::new(-ur[1], ur[0]) * sense)
}

// ---------------------------------------------------------------------------------------
// Stations

/// The ground-station ring: where each station is at a given time, and what it measures.
#[derive(Debug, Clone, PartialEq)]
pub struct Stations {
    /// Number of stations.
    pub count: usize,
    /// Longitude of station 0 at t = 0, rad (inertial, from the x axis).
    pub phase: f64,
    /// sin of the elevation mask (visibility: ρ·û_up ≥ sin(mask) |ρ|).
    pub sin_mask: f64,
    /// Filter step dt, s (step k is at t = k dt).
    pub dt: f64,
    /// Each station's up direction at t = 0 (so a step costs one sin/cos for all).
    base: Vec<Vector2<f64>>,
}

/// One station at one instant: position (km), velocity (km/s), local up and east.
struct Site {
    pos: Vector2<f64>,
    vel: Vector2<f64>,
    up: Vector2<f64>,
    east: Vector2<f64>,
}

impl Stations {
    /// `count` stations equally spaced from longitude `phase` (rad), elevation mask
    /// `mask` (rad), filter step `dt` (s).
    pub fn new(count: usize, phase: f64, mask: f64, dt: f64) -> Self {
        let base = (0..count)
            .map(|i| {
                let (s, c) = (phase + 2.0 * PI * i as f64 / count as f64).sin_cos();
                Vector2::new(c, s)
            })
            .collect();
        Stations {
            count,
            phase,
            sin_mask: mask.sin(),
            dt,
            base,
        }
    }

    /// The Earth's rotation since t = 0 at step k, as (cos, sin).
    fn earth(&self, k: usize) -> Vector2<f64> {
        let (s, c) = (EARTH_RATE * k as f64 * self.dt).sin_cos();
        Vector2::new(c, s)
    }

    /// Station `i` with the Earth turned by `earth` (NaN for an unknown station).
    fn site_at(&self, earth: &Vector2<f64>, i: usize) -> Site {
        let b = self
            .base
            .get(i)
            .copied()
            .unwrap_or(Vector2::new(f64::NAN, f64::NAN));
        let up = Vector2::new(
            b[0] * earth[0] - b[1] * earth[1],
            b[0] * earth[1] + b[1] * earth[0],
        );
        let east = Vector2::new(-up[1], up[0]);
        Site {
            pos: up * EARTH_RADIUS,
            vel: east * (EARTH_RADIUS * EARTH_RATE),
            up,
            east,
        }
    }

    fn site(&self, k: usize, i: usize) -> Site {
        self.site_at(&self.earth(k), i)
    }

    /// Whether station `i` sees a satellite at `x` at step `k` (elevation ≥ mask).
    pub fn visible(&self, k: usize, i: usize, x: &Vector4<f64>) -> bool {
        self.sees(&self.site(k, i), x)
    }

    fn sees(&self, site: &Site, x: &Vector4<f64>) -> bool {
        let rho = x.fixed_rows::<2>(0) - site.pos;
        rho.dot(&site.up) >= self.sin_mask * rho.norm()
    }

    /// Station `i`'s measurement [range (km), range rate (km/s), LOS angle (rad)] of `x`
    /// at step `k`, and its Jacobian (3 × 4).
    pub fn measure(&self, k: usize, i: usize, x: &Vector4<f64>) -> (Vector3<f64>, Matrix3x4<f64>) {
        Self::measure_from(&self.site(k, i), x)
    }

    fn measure_from(site: &Site, x: &Vector4<f64>) -> (Vector3<f64>, Matrix3x4<f64>) {
        let rho = x.fixed_rows::<2>(0) - site.pos;
        let rho_dot = x.fixed_rows::<2>(2) - site.vel;
        let range = rho.norm();
        let l = rho / range;
        let rate = l.dot(&rho_dot);
        let (a, b) = (rho.dot(&site.up), rho.dot(&site.east));
        let angle = a.atan2(b);
        let mut H = Matrix3x4::zeros();
        // ∂|ρ|/∂r = l'; ∂(l·ρ̇)/∂r = (ρ̇ − rate l)'/|ρ|, ∂/∂v = l';
        // ∂atan2(a, b)/∂r = (b û_up − a û_east)'/|ρ|² (a² + b² = |ρ|²).
        let d_rate = (rho_dot - l * rate) / range;
        let d_angle = (site.up * b - site.east * a) / (range * range);
        H[(0, 0)] = l[0];
        H[(0, 1)] = l[1];
        H[(1, 0)] = d_rate[0];
        H[(1, 1)] = d_rate[1];
        H[(1, 2)] = l[0];
        H[(1, 3)] = l[1];
        H[(2, 0)] = d_angle[0];
        H[(2, 1)] = d_angle[1];
        (Vector3::new(range, rate, angle), H)
    }
}

fn to4(x: &DVector<f64>) -> Vector4<f64> {
    Vector4::from_fn(|i, _| x.get(i).copied().unwrap_or(f64::NAN))
}

// ---------------------------------------------------------------------------------------
// Truth

/// The simulated satellite and stations.
#[derive(Debug, Clone)]
pub struct OrbitTruth {
    /// Mean of the initial state [x, y, vx, vy] (km, km/s): a circular orbit at the
    /// configured radius, on the +x axis moving towards +y.
    pub x0: Vector4<f64>,
    /// Initial position and velocity standard deviations per axis (km, km/s).
    pub initial_std: (f64, f64),
    /// RK4 steps per filter step.
    pub substeps: usize,
    /// RK4 step, s (dt / substeps).
    pub h: f64,
    /// Standard deviation of the piecewise-constant radial and along-track accelerations,
    /// km/s² (√(q/h)).
    pub accel_std: (f64, f64),
    /// Sensor noise standard deviations [range (km), range rate (km/s), angle (rad)].
    pub sensor_std: Vector3<f64>,
    /// The stations.
    pub stations: Stations,
}

impl TruthModel for OrbitTruth {
    fn n_x(&self) -> usize {
        4
    }

    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        let (sp, sv) = self.initial_std;
        let s = [sp, sp, sv, sv];
        DVector::from_fn(4, |i, _| {
            self.x0[i] + s[i] * rng.sample::<f64, _>(StandardNormal)
        })
    }

    fn propagate(&self, _k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        let mut s = to4(x);
        for _ in 0..self.substeps {
            let (ur, ut) = frame(&s.fixed_rows::<2>(0).into(), &s.fixed_rows::<2>(2).into());
            let aR: f64 = rng.sample(StandardNormal);
            let aT: f64 = rng.sample(StandardNormal);
            let a = ur * (self.accel_std.0 * aR) + ut * (self.accel_std.1 * aT);
            s = rk4(&s, &a, self.h);
        }
        DVector::from_column_slice(s.as_slice())
    }

    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        let s = to4(x);
        let earth = self.stations.earth(k);
        for i in 0..self.stations.count {
            let site = self.stations.site_at(&earth, i);
            if !self.stations.sees(&site, &s) {
                continue;
            }
            let (z, _) = Stations::measure_from(&site, &s);
            let z = DVector::from_fn(3, |j, _| {
                z[j] + self.sensor_std[j] * rng.sample::<f64, _>(StandardNormal)
            });
            out.push(Measurement { sensor: i, z });
        }
    }
}

// ---------------------------------------------------------------------------------------
// Filter

/// The filter's deterministic model: two-body flow over dt and the stations' measurement
/// functions, with analytic Jacobians (usable with the library's generic [`crate::filter::Ekf`]
/// and [`crate::filter::Ukf`]; [`OrbitEkf`] is the fixed-size EKF the catalog runs).
#[derive(Debug, Clone)]
pub struct OrbitSystem {
    /// Filter step, s.
    pub dt: f64,
    /// RK4 steps per filter step.
    pub substeps: usize,
    /// The stations.
    pub stations: Stations,
}

impl OrbitSystem {
    /// The state after one filter step and the state transition matrix Φ = ∂f/∂x (4 × 4).
    pub fn flow(&self, x: &Vector4<f64>) -> (Vector4<f64>, Matrix4<f64>) {
        let h = self.dt / self.substeps as f64;
        let mut s = *x;
        let mut phi = Matrix4::identity();
        for _ in 0..self.substeps {
            (s, phi) = rk4_stm(&s, &phi, h);
        }
        (s, phi)
    }

    /// The state after one filter step, without Φ.
    pub fn flow_state(&self, x: &Vector4<f64>) -> Vector4<f64> {
        let h = self.dt / self.substeps as f64;
        let mut s = *x;
        for _ in 0..self.substeps {
            s = rk4(&s, &Vector2::zeros(), h);
        }
        s
    }
}

impl SystemModel for OrbitSystem {
    fn n_x(&self) -> usize {
        4
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![3; self.stations.count]
    }

    fn transition(&self, _k: usize, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_column_slice(self.flow_state(&to4(x)).as_slice())
    }

    fn transition_jacobian(&self, _k: usize, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        let (_, phi) = self.flow(&to4(x));
        Some(DMatrix::from_column_slice(4, 4, phi.as_slice()))
    }

    fn measurement(&self, k: usize, sensor: usize, x: &DVector<f64>) -> DVector<f64> {
        let (z, _) = self.stations.measure(k, sensor, &to4(x));
        DVector::from_column_slice(z.as_slice())
    }

    fn measurement_jacobian(
        &self,
        k: usize,
        sensor: usize,
        x: &DVector<f64>,
    ) -> Option<DMatrix<f64>> {
        let (_, H) = self.stations.measure(k, sensor, &to4(x));
        Some(DMatrix::from_fn(3, 4, |i, j| H[(i, j)]))
    }

    fn residual(&self, _sensor: usize, z: &DVector<f64>, z_hat: &DVector<f64>) -> DVector<f64> {
        let mut d = z - z_hat;
        if d.len() == 3 {
            d[2] = wrap_angle(d[2]);
        }
        d
    }
}

/// The catalog's EKF for `orbit2d`, with fixed-size matrices inside and process noise
/// in the rotating radial/along-track frame (which a constant-Q [`crate::filter::Ekf`]
/// cannot express).
#[derive(Debug, Clone)]
pub struct OrbitEkf {
    /// Dynamics and sensors.
    pub system: OrbitSystem,
    /// PSDs of the radial and along-track acceleration noise, km²/s³.
    pub q: (f64, f64),
    /// Measurement noise covariance of every station (3 × 3, diagonal: km², (km/s)², rad²).
    pub R: Matrix3<f64>,
    /// Initial estimate, [km, km, km/s, km/s].
    pub x0: Vector4<f64>,
    /// Initial covariance, 4 × 4.
    pub P0: Matrix4<f64>,
}

impl OrbitEkf {
    /// Process noise over one step for a move from `x` to `x1`, with the radial/along-track
    /// frame taken at the middle of the step.
    pub fn process_noise(&self, x: &Vector4<f64>, x1: &Vector4<f64>) -> Matrix4<f64> {
        let mid = (x + x1) * 0.5;
        let (ur, ut) = frame(
            &mid.fixed_rows::<2>(0).into(),
            &mid.fixed_rows::<2>(2).into(),
        );
        let qa = ur * ur.transpose() * self.q.0 + ut * ut.transpose() * self.q.1;
        let dt = self.system.dt;
        let mut Q = Matrix4::zeros();
        Q.fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&(qa * (dt * dt * dt / 3.0)));
        Q.fixed_view_mut::<2, 2>(0, 2)
            .copy_from(&(qa * (dt * dt / 2.0)));
        Q.fixed_view_mut::<2, 2>(2, 0)
            .copy_from(&(qa * (dt * dt / 2.0)));
        Q.fixed_view_mut::<2, 2>(2, 2).copy_from(&(qa * dt));
        Q
    }
}

fn symmetrize4(P: &mut Matrix4<f64>) {
    let t = P.transpose();
    *P = (*P + t) * 0.5;
}

fn to_mat4(m: &DMatrix<f64>) -> Matrix4<f64> {
    if m.nrows() == 4 && m.ncols() == 4 {
        Matrix4::from_fn(|i, j| m[(i, j)])
    } else {
        Matrix4::from_element(f64::NAN)
    }
}

fn store4(dst: &mut DMatrix<f64>, src: &Matrix4<f64>) {
    if dst.nrows() == 4 && dst.ncols() == 4 {
        dst.copy_from(src);
    } else {
        *dst = DMatrix::from_column_slice(4, 4, src.as_slice());
    }
}

fn store_vec4(dst: &mut DVector<f64>, src: &Vector4<f64>) {
    if dst.len() == 4 {
        dst.copy_from(src);
    } else {
        *dst = DVector::from_column_slice(src.as_slice());
    }
}

impl Filter for OrbitEkf {
    fn n_x(&self) -> usize {
        4
    }

    fn sensor_dims(&self) -> Vec<usize> {
        vec![3; self.system.stations.count]
    }

    fn initial(&self) -> Estimate {
        Estimate::new(
            &DVector::from_column_slice(self.x0.as_slice()),
            &DMatrix::from_column_slice(4, 4, self.P0.as_slice()),
        )
    }

    fn predict(&self, k: usize, est: &mut Estimate) -> Result<(), FilterError> {
        let x = to4(&est.x);
        let P = to_mat4(&est.P);
        let (x1, F) = self.system.flow(&x);
        let mut P1 = F * P * F.transpose() + self.process_noise(&x, &x1);
        symmetrize4(&mut P1);
        if !P1.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NotPositiveDefinite {
                which: "P",
                step: k,
            });
        }
        store_vec4(&mut est.x, &x1);
        store4(&mut est.P, &P1);
        match &mut est.error_map {
            Some(a) => store4(a, &F),
            None => est.error_map = Some(DMatrix::from_column_slice(4, 4, F.as_slice())),
        }
        Ok(())
    }

    fn update(
        &self,
        k: usize,
        est: &mut Estimate,
        meas: &Measurement,
    ) -> Result<Innovation, FilterError> {
        let count = self.system.stations.count;
        check_measurement((meas.sensor < count).then_some(3), meas)?;
        let x = to4(&est.x);
        let P = to_mat4(&est.P);
        let (z_hat, H) = self.system.stations.measure(k, meas.sensor, &x);
        let mut nu = Vector3::new(meas.z[0], meas.z[1], meas.z[2]) - z_hat;
        nu[2] = wrap_angle(nu[2]);
        let PHt: Matrix4x3<f64> = P * H.transpose();
        let mut S = H * PHt + self.R;
        S = (S + S.transpose()) * 0.5;
        let chol = S.cholesky().ok_or(FilterError::NotPositiveDefinite {
            which: "S",
            step: k,
        })?;
        // K = P H' S⁻¹, through the Cholesky factor of S (S symmetric: K' = S⁻¹ H P).
        let K: Matrix4x3<f64> = chol.solve(&PHt.transpose()).transpose();
        let IKH = Matrix4::identity() - K * H;
        let mut P1 = IKH * P * IKH.transpose() + K * self.R * K.transpose();
        symmetrize4(&mut P1);
        let nis = nu.dot(&chol.solve(&nu));
        let x1 = x + K * nu;
        store_vec4(&mut est.x, &x1);
        store4(&mut est.P, &P1);
        if let Some(a) = &mut est.error_map {
            let map = IKH * to_mat4(a);
            store4(a, &map);
        }
        Ok(Innovation {
            nu: DVector::from_column_slice(nu.as_slice()),
            S: DMatrix::from_column_slice(3, 3, S.as_slice()),
            nis,
        })
    }
}

// ---------------------------------------------------------------------------------------
// The catalog model

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
