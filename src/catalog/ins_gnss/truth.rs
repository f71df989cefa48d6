//! The truth of `ins_gnss`: a car's drive integrated with RK4, its IMU and its GNSS
//! receiver.
//!
//! The vehicle moves without side slip along its body x axis at speed `u`:
//! `ṗ = u [cos θ cos ψ, cos θ sin ψ, −sin θ]`, `u̇ = a(t)`, `ψ̇ = r(t)`, `ṡ = u`, with the
//! longitudinal acceleration `a(t)` and yaw rate `r(t)` of the drive ([`DRIVE`]), pitch
//! from the road's hills `θ = θ₀ + A sin(2π s / L)` (s the distance driven) and roll from
//! the body leaning in turns `φ = φ₀ + c · u r`. The state `[p, u, ψ, s]` is integrated
//! with RK4 at its own step (0.02 s by default, see [`InsTruth::rk4_steps`]); the IMU
//! samples the middle of each of its intervals, interpolated between the RK4 grid points
//! with a cubic Hermite polynomial.
//!
//! True body rates and specific force follow from the motion:
//! `ω_b = [φ̇ − ψ̇ sin θ, θ̇ cos φ + ψ̇ sin φ cos θ, −θ̇ sin φ + ψ̇ cos φ cos θ]` and
//! `f_b = [u̇ + g sin θ, ω_z u − g sin φ cos θ, −ω_y u − g cos φ cos θ]`.
//! An IMU sample is the true value at the middle of its interval plus the bias plus white
//! noise (standard deviation `√(q / Δt_imu)`); the biases are random walks stepped once
//! per IMU sample.

#![allow(non_snake_case)]

use std::f64::consts::PI;

use nalgebra::{DVector, UnitQuaternion, Vector3};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::nav::{GRAVITY, N_NOM, Nominal};
use crate::measurement::Measurement;
use crate::model::TruthModel;
use crate::rng::SimRng;

/// One smooth manoeuvre: a raised-cosine pulse of `peak` amplitude from `start` for
/// `duration` seconds (its integral is `peak · duration / 2`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulse {
    /// Start time, s.
    pub start: f64,
    /// Duration, s.
    pub duration: f64,
    /// Peak value (m/s² for acceleration, rad/s for yaw rate).
    pub peak: f64,
}

impl Pulse {
    /// Value and time derivative at `t`.
    fn eval(&self, t: f64) -> (f64, f64) {
        let x = (t - self.start) / self.duration;
        if !(0.0..=1.0).contains(&x) {
            return (0.0, 0.0);
        }
        let w = 2.0 * PI / self.duration;
        let c = (2.0 * PI * x).cos();
        let s = (2.0 * PI * x).sin();
        (0.5 * self.peak * (1.0 - c), 0.5 * self.peak * w * s)
    }
}

/// The drive, 90 s: accelerate to 12 m/s (0–8 s), straight, a 90° right turn (20–30 s),
/// straight (a GNSS outage falls here in the shipped problem), a 90° left turn (45–55 s),
/// straight, brake to a stop (65–73 s) and stand still. After the last pulse the car
/// keeps its speed, so a longer horizon simply stands still longer.
pub const DRIVE: Drive = Drive {
    accel: &[
        Pulse {
            start: 0.0,
            duration: 8.0,
            peak: 3.0,
        },
        Pulse {
            start: 65.0,
            duration: 8.0,
            peak: -3.0,
        },
    ],
    yaw_rate: &[
        Pulse {
            start: 20.0,
            duration: 10.0,
            peak: PI / 10.0,
        },
        Pulse {
            start: 45.0,
            duration: 10.0,
            peak: -PI / 10.0,
        },
    ],
    hill_pitch: 0.03,
    hill_length: 150.0,
    roll_per_accel: 0.008,
};

/// A drive profile: longitudinal acceleration and yaw-rate pulses, road hills, body roll.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drive {
    /// Longitudinal acceleration pulses, m/s².
    pub accel: &'static [Pulse],
    /// Yaw-rate pulses, rad/s.
    pub yaw_rate: &'static [Pulse],
    /// Pitch amplitude of the hills, rad.
    pub hill_pitch: f64,
    /// Wavelength of the hills, m.
    pub hill_length: f64,
    /// Body roll per m/s² of lateral acceleration, rad/(m/s²).
    pub roll_per_accel: f64,
}

impl Drive {
    fn sum(p: &[Pulse], t: f64) -> (f64, f64) {
        p.iter().fold((0.0, 0.0), |(a, b), q| {
            let (x, y) = q.eval(t);
            (a + x, b + y)
        })
    }
}

/// Kinematic state of the RK4 integration: `[p_n, p_e, p_d, u, ψ, s]`.
type Kin = nalgebra::SVector<f64, 6>;

/// Per-run constants drawn at the start: roll and pitch offsets, rad.
#[derive(Debug, Clone, Copy)]
struct Offsets {
    roll: f64,
    pitch: f64,
}

/// Euler angles and their rates at a kinematic state.
struct Attitude {
    roll: f64,
    pitch: f64,
    yaw: f64,
    droll: f64,
    dpitch: f64,
    dyaw: f64,
    du: f64,
}

/// Truth-noise settings (validated by the builder).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthNoise {
    /// Accelerometer white noise per body axis, (m/s²)²/Hz.
    pub accel: Vector3<f64>,
    /// Gyro white noise, (rad/s)²/Hz.
    pub gyro: f64,
    /// Accelerometer bias random walk, (m/s²)²/s.
    pub accel_bias: f64,
    /// Gyro bias random walk, (rad/s)²/s.
    pub gyro_bias: f64,
    /// GNSS horizontal position variance per axis, m².
    pub gnss_h: f64,
    /// GNSS vertical position variance, m².
    pub gnss_v: f64,
}

/// One-sigma initial errors, shared by the truth's draws and the filter's P0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialSigma {
    /// Horizontal position, m.
    pub pos_h: f64,
    /// Vertical position, m.
    pub pos_v: f64,
    /// Velocity, m/s (the filter's only: the car starts at rest, which the truth keeps).
    pub vel: f64,
    /// Roll and pitch, rad.
    pub tilt: f64,
    /// Yaw, rad.
    pub yaw: f64,
    /// Accelerometer bias, m/s².
    pub accel_bias: f64,
    /// Gyro bias, rad/s.
    pub gyro_bias: f64,
}

/// Layout of the truth state vector.
pub mod layout {
    /// `[p (3), v (3), q (4: w, x, y, z), b_a (3), b_g (3)]`, the navigation state the
    /// filter's error is measured against (same layout as the filter's nominal state).
    pub const NAV: usize = 0;
    /// Speed u, m/s.
    pub const U: usize = 16;
    /// Yaw ψ, rad.
    pub const YAW: usize = 17;
    /// Distance driven s, m.
    pub const DIST: usize = 18;
    /// Roll offset φ₀ of this run, rad.
    pub const ROLL0: usize = 19;
    /// Pitch offset θ₀ of this run, rad.
    pub const PITCH0: usize = 20;
    /// Start of the IMU samples of the last step, `[f (3), w (3)]` per sample.
    pub const IMU: usize = 21;
}

/// The `ins_gnss` truth model.
///
/// State vector (see [`layout`]): navigation state (16), speed, yaw, distance, roll and
/// pitch offsets, then the step's IMU samples (6 per sample), which [`TruthModel::input`]
/// hands to the filter.
#[derive(Debug, Clone)]
pub struct InsTruth {
    /// Filter step, s.
    pub dt: f64,
    /// IMU samples per step.
    pub n_imu: usize,
    /// Truth noise.
    pub noise: TruthNoise,
    /// Initial-error sigmas.
    pub init: InitialSigma,
    /// GNSS fix every this many steps.
    pub gnss_every: usize,
    /// GNSS outage, s: no fixes for `start ≤ t < end`.
    pub outage: (f64, f64),
    /// The drive.
    pub drive: Drive,
}

impl InsTruth {
    /// Length of the truth state vector.
    pub fn len(&self) -> usize {
        layout::IMU + 6 * self.n_imu
    }

    /// Always false (the state is never empty); present for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// RK4 steps per filter step: the fewest that keep the RK4 step at most 0.02 s and
    /// put a whole number of IMU samples in each (5 at dt = 0.1 s, 100 Hz).
    pub fn rk4_steps(&self) -> usize {
        (1..=self.n_imu)
            .find(|&n| self.n_imu.is_multiple_of(n) && self.dt / n as f64 <= 0.02 + 1e-12)
            .unwrap_or(self.n_imu)
    }

    /// Whether a GNSS fix is taken at step `k`.
    pub fn gnss_at(&self, k: usize) -> bool {
        let t = k as f64 * self.dt;
        k.is_multiple_of(self.gnss_every)
            && !(t >= self.outage.0 - 1e-9 && t < self.outage.1 - 1e-9)
    }

    fn attitude(&self, k: &Kin, t: f64, off: Offsets) -> Attitude {
        let d = &self.drive;
        let (a, _) = Drive::sum(d.accel, t);
        let (r, dr) = Drive::sum(d.yaw_rate, t);
        let u = k[3];
        let arg = 2.0 * PI * k[5] / d.hill_length;
        Attitude {
            roll: off.roll + d.roll_per_accel * u * r,
            pitch: off.pitch + d.hill_pitch * arg.sin(),
            yaw: k[4],
            droll: d.roll_per_accel * (a * r + u * dr),
            dpitch: d.hill_pitch * arg.cos() * 2.0 * PI / d.hill_length * u,
            dyaw: r,
            du: a,
        }
    }

    fn deriv(&self, k: &Kin, t: f64, off: Offsets) -> Kin {
        let d = &self.drive;
        let u = k[3];
        let pitch = off.pitch + d.hill_pitch * (2.0 * PI * k[5] / d.hill_length).sin();
        let (cp, sp) = (pitch.cos(), pitch.sin());
        let (cy, sy) = (k[4].cos(), k[4].sin());
        Kin::new(
            u * cp * cy,
            u * cp * sy,
            -u * sp,
            Drive::sum(d.accel, t).0,
            Drive::sum(d.yaw_rate, t).0,
            u,
        )
    }

    /// One RK4 step from `k` at `t`, given its derivative `k1` there.
    fn rk4(&self, k: &Kin, k1: &Kin, t: f64, h: f64, off: Offsets) -> Kin {
        let k2 = self.deriv(&(k + k1 * (h / 2.0)), t + h / 2.0, off);
        let k3 = self.deriv(&(k + k2 * (h / 2.0)), t + h / 2.0, off);
        let k4 = self.deriv(&(k + k3 * h), t + h, off);
        k + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0)
    }

    /// True specific force (m/s²) and body rate (rad/s) at a kinematic state.
    fn imu_true(&self, k: &Kin, t: f64, off: Offsets) -> (Vector3<f64>, Vector3<f64>) {
        let at = self.attitude(k, t, off);
        let (cr, sr) = (at.roll.cos(), at.roll.sin());
        let (cp, sp) = (at.pitch.cos(), at.pitch.sin());
        let w = Vector3::new(
            at.droll - at.dyaw * sp,
            at.dpitch * cr + at.dyaw * sr * cp,
            -at.dpitch * sr + at.dyaw * cr * cp,
        );
        let u = k[3];
        let f = Vector3::new(
            at.du + GRAVITY * sp,
            w.z * u - GRAVITY * sr * cp,
            -w.y * u - GRAVITY * cr * cp,
        );
        (f, w)
    }

    /// Write the navigation part (p, v, q) of `x` from the kinematic state at time `t`.
    fn write_nav(&self, x: &mut DVector<f64>, k: &Kin, t: f64, off: Offsets) {
        let at = self.attitude(k, t, off);
        let q = UnitQuaternion::from_euler_angles(at.roll, at.pitch, at.yaw);
        let v = q * Vector3::new(k[3], 0.0, 0.0);
        // The car moves along its body x axis; with roll that axis is unchanged, so v is
        // u [cθ cψ, cθ sψ, −sθ] as in the kinematics.
        let qq = q.quaternion();
        let vals = [k[0], k[1], k[2], v.x, v.y, v.z, qq.w, qq.i, qq.j, qq.k];
        x.as_mut_slice()[..10].copy_from_slice(&vals);
    }

    fn kin(x: &DVector<f64>) -> Kin {
        Kin::new(
            x[0],
            x[1],
            x[2],
            x[layout::U],
            x[layout::YAW],
            x[layout::DIST],
        )
    }

    fn offsets(x: &DVector<f64>) -> Offsets {
        Offsets {
            roll: x[layout::ROLL0],
            pitch: x[layout::PITCH0],
        }
    }
}

fn normal(rng: &mut SimRng) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

impl TruthModel for InsTruth {
    fn n_x(&self) -> usize {
        self.len()
    }

    /// The car at rest at the origin, heading north, level, with position, attitude and
    /// bias offsets drawn from the initial sigmas (its velocity is exactly zero).
    fn initial_state(&self, rng: &mut SimRng) -> DVector<f64> {
        let s = &self.init;
        let mut x = DVector::zeros(self.len());
        let p = [
            s.pos_h * normal(rng),
            s.pos_h * normal(rng),
            s.pos_v * normal(rng),
        ];
        let roll = s.tilt * normal(rng);
        let pitch = s.tilt * normal(rng);
        let yaw = s.yaw * normal(rng);
        for i in 0..3 {
            x[10 + i] = s.accel_bias * normal(rng);
        }
        for i in 0..3 {
            x[13 + i] = s.gyro_bias * normal(rng);
        }
        x[layout::YAW] = yaw;
        x[layout::ROLL0] = roll;
        x[layout::PITCH0] = pitch;
        let k = Kin::new(p[0], p[1], p[2], 0.0, yaw, 0.0);
        let off = Self::offsets(&x);
        self.write_nav(&mut x, &k, 0.0, off);
        x
    }

    fn propagate(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng) -> DVector<f64> {
        let mut out = x.clone();
        let off = Self::offsets(x);
        let mut kin = Self::kin(x);
        let dt_imu = self.dt / self.n_imu as f64;
        let t0 = (k - 1) as f64 * self.dt;
        let n = &self.noise;
        let sa = n.accel.map(|q| (q / dt_imu).sqrt());
        let sg = (n.gyro / dt_imu).sqrt();
        let sba = (n.accel_bias * dt_imu).sqrt();
        let sbg = (n.gyro_bias * dt_imu).sqrt();
        let n_rk = self.rk4_steps();
        let h = self.dt / n_rk as f64;
        let per = self.n_imu / n_rk;
        let mut f0 = self.deriv(&kin, t0, off);
        for i in 0..n_rk {
            let t = t0 + i as f64 * h;
            let next = self.rk4(&kin, &f0, t, h, off);
            let f1 = self.deriv(&next, t + h, off);
            for l in 0..per {
                // The IMU samples the middle of its interval; cubic Hermite interpolation
                // between the RK4 grid points (error h⁴/384 · |y⁗|, below 1e-9 here).
                let tau = (l as f64 + 0.5) / per as f64;
                let (t2, t3) = (tau * tau, tau * tau * tau);
                let mid = kin * (2.0 * t3 - 3.0 * t2 + 1.0)
                    + f0 * (h * (t3 - 2.0 * t2 + tau))
                    + next * (3.0 * t2 - 2.0 * t3)
                    + f1 * (h * (t3 - t2));
                let (f, w) = self.imu_true(&mid, t + tau * h, off);
                for c in 0..3 {
                    out[10 + c] += sba * normal(rng);
                    out[13 + c] += sbg * normal(rng);
                }
                let base = layout::IMU + 6 * (i * per + l);
                for c in 0..3 {
                    out[base + c] = f[c] + out[10 + c] + sa[c] * normal(rng);
                }
                for c in 0..3 {
                    out[base + 3 + c] = w[c] + out[13 + c] + sg * normal(rng);
                }
            }
            kin = next;
            f0 = f1;
        }
        out[layout::U] = kin[3];
        out[layout::YAW] = kin[4];
        out[layout::DIST] = kin[5];
        self.write_nav(&mut out, &kin, k as f64 * self.dt, off);
        out
    }

    /// The step's IMU samples, `[f (3), w (3)] × n_imu`, drawn in `propagate`.
    fn input(&self, _k: usize, x: &DVector<f64>, _rng: &mut SimRng) -> Option<DVector<f64>> {
        Some(DVector::from_column_slice(&x.as_slice()[layout::IMU..]))
    }

    /// A GNSS position fix (sensor 0, NED, m) every `gnss_every` steps outside the outage.
    fn measure(&self, k: usize, x: &DVector<f64>, rng: &mut SimRng, out: &mut Vec<Measurement>) {
        if !self.gnss_at(k) {
            return;
        }
        let (sh, sv) = (self.noise.gnss_h.sqrt(), self.noise.gnss_v.sqrt());
        let z = DVector::from_column_slice(&[
            x[0] + sh * normal(rng),
            x[1] + sh * normal(rng),
            x[2] + sv * normal(rng),
        ]);
        out.push(Measurement { sensor: 0, z });
    }
}

/// The truth's navigation state, for tests: `None` if `x` is too short.
pub fn truth_nominal(x: &DVector<f64>) -> Option<Nominal> {
    Nominal::from_slice(&x.as_slice()[..N_NOM.min(x.len())])
}
