//! The orbit as the filter sees it and as the truth integrates it: two-body dynamics with
//! RK4 and the variational equations, the radial/along-track frame, and the ring of ground
//! stations with their measurement functions.

#![allow(non_snake_case)]

use std::f64::consts::PI;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3x4, Matrix4, Vector2, Vector3, Vector4};

use crate::filter::{Jacobian, SystemModel};
use crate::linalg::wrap_angle;

/// Earth's gravitational parameter μ, km³/s².
pub const MU: f64 = 398_600.441_8;
/// Earth's equatorial radius, km (the stations' distance from the centre).
pub const EARTH_RADIUS: f64 = 6378.137;
/// Earth's rotation rate, rad/s.
pub const EARTH_RATE: f64 = 7.292_115e-5;

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
pub(super) fn rk4(x: &Vector4<f64>, a: &Vector2<f64>, h: f64) -> Vector4<f64> {
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
pub(super) fn frame(r: &Vector2<f64>, v: &Vector2<f64>) -> (Vector2<f64>, Vector2<f64>) {
    let n = r.norm();
    let ur = if n > 0.0 { r / n } else { Vector2::x() };
    let sense = if r[0] * v[1] - r[1] * v[0] < 0.0 {
        -1.0
    } else {
        1.0
    };
    (ur, Vector2::new(-ur[1], ur[0]) * sense)
}

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
pub(super) struct Site {
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
    pub(super) fn earth(&self, k: usize) -> Vector2<f64> {
        let (s, c) = (EARTH_RATE * k as f64 * self.dt).sin_cos();
        Vector2::new(c, s)
    }

    /// Station `i` with the Earth turned by `earth` (NaN for an unknown station).
    pub(super) fn site_at(&self, earth: &Vector2<f64>, i: usize) -> Site {
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

    pub(super) fn sees(&self, site: &Site, x: &Vector4<f64>) -> bool {
        let rho = x.fixed_rows::<2>(0) - site.pos;
        rho.dot(&site.up) >= self.sin_mask * rho.norm()
    }

    /// Station `i`'s measurement [range (km), range rate (km/s), LOS angle (rad)] of `x`
    /// at step `k`, and its Jacobian (3 × 4).
    // Inlined into the filter's update and the truth's measure (other modules), as it was
    // when they shared one: it runs for every station at every step.
    #[inline]
    pub fn measure(&self, k: usize, i: usize, x: &Vector4<f64>) -> (Vector3<f64>, Matrix3x4<f64>) {
        Self::measure_from(&self.site(k, i), x)
    }

    #[inline]
    pub(super) fn measure_from(site: &Site, x: &Vector4<f64>) -> (Vector3<f64>, Matrix3x4<f64>) {
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

pub(super) fn to4(x: &DVector<f64>) -> Vector4<f64> {
    Vector4::from_fn(|i, _| x.get(i).copied().unwrap_or(f64::NAN))
}

/// The filter's deterministic model: two-body flow over dt and the stations' measurement
/// functions, with analytic Jacobians (usable with the library's generic [`crate::filter::Ekf`]
/// and [`crate::filter::Ukf`]; [`super::OrbitEkf`] is the fixed-size EKF the catalog runs).
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

    fn transition_jacobian(&self, _k: usize, x: &DVector<f64>) -> Jacobian {
        let (_, phi) = self.flow(&to4(x));
        Some(DMatrix::from_column_slice(4, 4, phi.as_slice()))
    }

    fn measurement(&self, k: usize, sensor: usize, x: &DVector<f64>) -> DVector<f64> {
        let (z, _) = self.stations.measure(k, sensor, &to4(x));
        DVector::from_column_slice(z.as_slice())
    }

    fn measurement_jacobian(&self, k: usize, sensor: usize, x: &DVector<f64>) -> Jacobian {
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
