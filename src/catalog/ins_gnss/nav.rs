//! Strapdown navigation in a local-level NED frame: the nominal state, the 100 Hz
//! mechanization, and the 15-state error model with its analytic Jacobians.
//!
//! Flat Earth, constant gravity `g_n = [0, 0, 9.81]` m/s² (down), no Earth rotation and no
//! transport rate: the frame is an inertial tangent plane, which is adequate for a drive of
//! a few minutes and a few kilometres with automotive MEMS sensors (the Earth rate,
//! 7.3e-5 rad/s, is below their gyro bias).
//!
//! Error definitions (truth minus estimate), 15 components in this order:
//! `δp = p_t − p̂` (3, m), `δv = v_t − v̂` (3, m/s), `ψ` with `R_t = Exp(ψ) R̂` (3, rad, the
//! small rotation from estimated to true attitude, expressed in the navigation frame),
//! `δb_a = b_a,t − b̂_a` (3, m/s²), `δb_g = b_g,t − b̂_g` (3, rad/s).
//!
//! Continuous error dynamics (Groves, *Principles of GNSS, Inertial, and Multisensor
//! Integrated Navigation Systems*, 2nd ed. 2013, §14.2, with the Earth terms dropped):
//! `δṗ = δv`, `δv̇ = −[R f̂]× ψ − R δb_a − R w_a`, `ψ̇ = −R δb_g − R w_g`,
//! `δḃ_a = w_ba`, `δḃ_g = w_bg`, where `f̂ = f̃ − b̂_a` and the `w` are white noises.

#![allow(non_snake_case)]

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

/// Gravity magnitude, m/s² (constant, pointing down the NED z axis).
pub const GRAVITY: f64 = 9.81;

/// Error-state dimension.
pub const N_ERR: usize = 15;
/// Nominal-state length in a state vector: p (3), v (3), quaternion w, x, y, z (4),
/// b_a (3), b_g (3).
pub const N_NOM: usize = 16;

/// 15 × 15 matrix of the error state.
pub type Mat15 = SMatrix<f64, N_ERR, N_ERR>;
/// 15-vector of the error state.
pub type Vec15 = SVector<f64, N_ERR>;

/// Offsets of the error-state blocks.
pub const IP: usize = 0;
/// Velocity error block offset.
pub const IV: usize = 3;
/// Attitude error block offset.
pub const IPSI: usize = 6;
/// Accelerometer bias error block offset.
pub const IBA: usize = 9;
/// Gyro bias error block offset.
pub const IBG: usize = 12;

/// Gravity vector in NED, m/s².
pub fn gravity() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, GRAVITY)
}

/// The skew-symmetric cross-product matrix `[a]×`, with `[a]× b = a × b`.
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// Right Jacobian of SO(3), `J_r(φ)`: `Exp(φ + δ) ≈ Exp(φ) Exp(J_r(φ) δ)`.
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let th2 = phi.norm_squared();
    let k = skew(phi);
    let (a, b) = if th2 < 1e-4 {
        // Taylor series, cheaper than the trigonometry: the first omitted terms are
        // θ⁶/40320 and θ⁶/362880, below 1e-16 for θ < 0.01 (a 100 Hz sample turns less).
        let th4 = th2 * th2;
        (
            0.5 - th2 / 24.0 + th4 / 720.0,
            1.0 / 6.0 - th2 / 120.0 + th4 / 5040.0,
        )
    } else {
        let th = th2.sqrt();
        ((1.0 - th.cos()) / th2, (th - th.sin()) / (th2 * th))
    };
    Matrix3::identity() - k * a + k * k * b
}

/// `Exp(φ)` as a unit quaternion; a Taylor series below 0.01 rad (first omitted terms
/// (θ/2)⁸/40320 relative, far below rounding), trigonometry above.
pub fn exp_quat(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let th2 = phi.norm_squared();
    if th2 < 1e-4 {
        let x2 = th2 / 4.0;
        let c = 1.0 - x2 / 2.0 + x2 * x2 / 24.0 - x2 * x2 * x2 / 720.0;
        let s = 0.5 * (1.0 - x2 / 6.0 + x2 * x2 / 120.0 - x2 * x2 * x2 / 5040.0);
        UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
            c,
            s * phi.x,
            s * phi.y,
            s * phi.z,
        ))
    } else {
        UnitQuaternion::from_scaled_axis(*phi)
    }
}

/// One IMU sample: specific force `f` (m/s², body axes) and angular rate `w` (rad/s, body
/// axes), both taken at the middle of the sample interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Specific force, m/s², body frame (forward, right, down).
    pub f: Vector3<f64>,
    /// Angular rate, rad/s, body frame.
    pub w: Vector3<f64>,
}

impl ImuSample {
    /// Read sample `j` from a step input `[f (3), w (3)] × n`.
    pub fn from_input(u: &[f64], j: usize) -> ImuSample {
        let s = &u[6 * j..6 * j + 6];
        ImuSample {
            f: Vector3::new(s[0], s[1], s[2]),
            w: Vector3::new(s[3], s[4], s[5]),
        }
    }
}

/// The navigation solution: position, velocity, attitude and IMU biases.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nominal {
    /// Position, m, NED.
    pub p: Vector3<f64>,
    /// Velocity, m/s, NED.
    pub v: Vector3<f64>,
    /// Attitude, body to navigation frame.
    pub q: UnitQuaternion<f64>,
    /// Accelerometer bias, m/s², body frame.
    pub ba: Vector3<f64>,
    /// Gyro bias, rad/s, body frame.
    pub bg: Vector3<f64>,
}

impl Nominal {
    /// Read the first [`N_NOM`] entries `[p, v, q_w, q_x, q_y, q_z, b_a, b_g]`; `None` if the
    /// slice is shorter or the quaternion is not finite and nonzero.
    pub fn from_slice(x: &[f64]) -> Option<Nominal> {
        if x.len() < N_NOM {
            return None;
        }
        let v3 = |i: usize| Vector3::new(x[i], x[i + 1], x[i + 2]);
        let raw = nalgebra::Quaternion::new(x[6], x[7], x[8], x[9]);
        let n = raw.norm();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        Some(Nominal {
            p: v3(0),
            v: v3(3),
            q: UnitQuaternion::new_unchecked(raw / n),
            ba: v3(10),
            bg: v3(13),
        })
    }

    /// Write into the first [`N_NOM`] entries of `x` (which must hold at least that many).
    pub fn write(&self, x: &mut [f64]) {
        x[0..3].copy_from_slice(self.p.as_slice());
        x[3..6].copy_from_slice(self.v.as_slice());
        let q = self.q.quaternion();
        x[6] = q.w;
        x[7] = q.i;
        x[8] = q.j;
        x[9] = q.k;
        x[10..13].copy_from_slice(self.ba.as_slice());
        x[13..16].copy_from_slice(self.bg.as_slice());
    }

    /// The state `dx` describes: `p + δp`, `v + δv`, `Exp(ψ) R`, `b + δb` (the ESKF's
    /// error injection).
    pub fn inject(&self, dx: &Vec15) -> Nominal {
        let psi = dx.fixed_rows::<3>(IPSI).into_owned();
        Nominal {
            p: self.p + dx.fixed_rows::<3>(IP),
            v: self.v + dx.fixed_rows::<3>(IV),
            q: UnitQuaternion::from_scaled_axis(psi) * self.q,
            ba: self.ba + dx.fixed_rows::<3>(IBA),
            bg: self.bg + dx.fixed_rows::<3>(IBG),
        }
    }

    /// The error `truth − self` as a 15-vector (attitude as `Log(R_t R̂')`).
    pub fn error_to(&self, truth: &Nominal) -> Vec15 {
        let mut e = Vec15::zeros();
        e.fixed_rows_mut::<3>(IP).copy_from(&(truth.p - self.p));
        e.fixed_rows_mut::<3>(IV).copy_from(&(truth.v - self.v));
        e.fixed_rows_mut::<3>(IPSI)
            .copy_from(&(truth.q * self.q.inverse()).scaled_axis());
        e.fixed_rows_mut::<3>(IBA).copy_from(&(truth.ba - self.ba));
        e.fixed_rows_mut::<3>(IBG).copy_from(&(truth.bg - self.bg));
        e
    }
}

/// The error-state transition of one or several mechanization samples. Its structure is
/// closed under products (block upper triangular with identity diagonal, the bias rows
/// identity, `Φ_pv` a multiple of I), so a step's Φ is accumulated with 3 × 3 blocks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transition {
    /// `Φ_pv = pv · I`, s.
    pub pv: f64,
    /// `Φ_pψ`.
    pub ppsi: Matrix3<f64>,
    /// `Φ_pa`.
    pub pa: Matrix3<f64>,
    /// `Φ_pg`.
    pub pg: Matrix3<f64>,
    /// `Φ_vψ`.
    pub vpsi: Matrix3<f64>,
    /// `Φ_va`.
    pub va: Matrix3<f64>,
    /// `Φ_vg`.
    pub vg: Matrix3<f64>,
    /// `Φ_ψg`.
    pub psig: Matrix3<f64>,
}

impl Transition {
    /// The identity map.
    pub fn identity() -> Transition {
        let z = Matrix3::zeros();
        Transition {
            pv: 0.0,
            ppsi: z,
            pa: z,
            pg: z,
            vpsi: z,
            va: z,
            vg: z,
            psig: z,
        }
    }

    /// `s · self`: apply `self` first, then `s`.
    pub fn then(&self, s: &Transition) -> Transition {
        Transition {
            pv: self.pv + s.pv,
            ppsi: self.ppsi + self.vpsi * s.pv + s.ppsi,
            pa: self.pa + self.va * s.pv + s.pa,
            pg: self.pg + self.vg * s.pv + s.ppsi * self.psig + s.pg,
            vpsi: self.vpsi + s.vpsi,
            va: self.va + s.va,
            vg: self.vg + s.vpsi * self.psig + s.vg,
            psig: self.psig + s.psig,
        }
    }

    /// The full 15 × 15 matrix.
    pub fn matrix(&self) -> Mat15 {
        let mut m = Mat15::identity();
        let mut set = |r: usize, c: usize, b: &Matrix3<f64>| {
            m.fixed_view_mut::<3, 3>(r, c).copy_from(b);
        };
        set(IP, IV, &(Matrix3::identity() * self.pv));
        set(IP, IPSI, &self.ppsi);
        set(IP, IBA, &self.pa);
        set(IP, IBG, &self.pg);
        set(IV, IPSI, &self.vpsi);
        set(IV, IBA, &self.va);
        set(IV, IBG, &self.vg);
        set(IPSI, IBG, &self.psig);
        m
    }
}

/// What one mechanization sample used, for the covariance propagation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleInfo {
    /// The sample's error transition.
    pub phi: Transition,
    /// Attitude at the middle of the sample interval, body to nav.
    pub r_mid: Matrix3<f64>,
    /// Corrected specific force in the navigation frame, `R_mid (f̃ − b̂_a)`, m/s².
    pub f_nav: Vector3<f64>,
}

/// Advance `nom` by one IMU sample over `dt` seconds and return the sample's exact error
/// transition (the Jacobian of this discrete map at zero error).
///
/// The sample is taken at the middle of the interval, so the scheme is second order:
/// `a = (ω̃ − b̂_g) dt`, `R_mid = R Exp(a/2)`, `acc = R_mid (f̃ − b̂_a) + g`,
/// `p ← p + v dt + acc dt²/2`, `v ← v + acc dt`, `R ← R Exp(a)`.
pub fn mechanize(nom: &mut Nominal, imu: &ImuSample, dt: f64) -> SampleInfo {
    let wc = imu.w - nom.bg;
    let fc = imu.f - nom.ba;
    let a = wc * dt;
    let half = exp_quat(&(a * 0.5));
    let r = nom.q.to_rotation_matrix().into_inner();
    let r_mid = r * half.to_rotation_matrix().into_inner();
    let y = r_mid * fc;
    let acc = y + gravity();
    let q_new = nom.q * half * half;
    let r_new = q_new.to_rotation_matrix().into_inner();

    // Jacobian. A gyro bias error δ turns a into a − δ dt, and
    // R Exp(a − δ dt) ≈ Exp(−R Exp(a) J_r(a) δ dt) R Exp(a); the same at a/2 for R_mid.
    let ys = skew(&y);
    let mid_bg = r_mid * right_jacobian(&(a * 0.5)) * (0.5 * dt);
    let dacc_psi = -ys;
    let dacc_ba = -r_mid;
    let dacc_bg = ys * mid_bg;
    let h2 = 0.5 * dt * dt;
    let phi = Transition {
        pv: dt,
        ppsi: dacc_psi * h2,
        pa: dacc_ba * h2,
        pg: dacc_bg * h2,
        vpsi: dacc_psi * dt,
        va: dacc_ba * dt,
        vg: dacc_bg * dt,
        psig: -(r_new * right_jacobian(&a)) * dt,
    };

    nom.p += nom.v * dt + acc * h2;
    nom.v += acc * dt;
    nom.q = q_new;
    SampleInfo {
        phi,
        r_mid,
        f_nav: y,
    }
}

/// The continuous error-dynamics matrix `F` (15 × 15) at `nom` with IMU reading `imu`.
pub fn continuous_f(nom: &Nominal, imu: &ImuSample) -> Mat15 {
    let r = nom.q.to_rotation_matrix().into_inner();
    let y = r * (imu.f - nom.ba);
    let mut F = Mat15::zeros();
    F.fixed_view_mut::<3, 3>(IP, IV)
        .copy_from(&Matrix3::identity());
    F.fixed_view_mut::<3, 3>(IV, IPSI).copy_from(&(-skew(&y)));
    F.fixed_view_mut::<3, 3>(IV, IBA).copy_from(&(-r));
    F.fixed_view_mut::<3, 3>(IPSI, IBG).copy_from(&(-r));
    F
}

/// The exact (nonlinear) rate of the error `dx` of a true state `nom.inject(dx)` relative to
/// `nom`, both driven by the same noise-free IMU reading: the continuous model whose
/// linearization at `dx = 0` is [`continuous_f`].
///
/// With `R_t = Exp(ψ) R`, `ψ̇ = J_l(ψ)⁻¹ R_t (ω_t − ω)` where `ω_t − ω = −δb_g`; the other
/// components are differences of the kinematics `ṗ = v`, `v̇ = R (f̃ − b_a) + g`.
pub fn error_rate(nom: &Nominal, dx: &Vec15, imu: &ImuSample) -> Vec15 {
    let t = nom.inject(dx);
    let r = nom.q.to_rotation_matrix().into_inner();
    let rt = t.q.to_rotation_matrix().into_inner();
    let psi = dx.fixed_rows::<3>(IPSI).into_owned();
    let dbg = dx.fixed_rows::<3>(IBG).into_owned();
    // J_l(ψ) = J_r(−ψ).
    let jl = right_jacobian(&(-psi));
    let body_rate_diff = rt * (-dbg);
    let psi_dot = jl
        .try_inverse()
        .map_or(Vector3::from_element(f64::NAN), |j| j * body_rate_diff);
    let mut e = Vec15::zeros();
    e.fixed_rows_mut::<3>(IP).copy_from(&(t.v - nom.v));
    e.fixed_rows_mut::<3>(IV)
        .copy_from(&(rt * (imu.f - t.ba) - r * (imu.f - nom.ba)));
    e.fixed_rows_mut::<3>(IPSI).copy_from(&psi_dot);
    e
}

/// Process noise densities of the error model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseDensities {
    /// Accelerometer white noise per body axis, (m/s²)²/Hz.
    pub accel: Vector3<f64>,
    /// Gyro white noise (all axes), (rad/s)²/Hz.
    pub gyro: f64,
    /// Accelerometer bias random walk, (m/s²)²/s.
    pub accel_bias: f64,
    /// Gyro bias random walk, (rad/s)²/s.
    pub gyro_bias: f64,
}

/// The discrete process noise `Q_k = ∫ Φ(t_k, τ) G Q_c G' Φ(t_k, τ)' dτ` over a step of
/// `dt` seconds, to third order in `dt` with `F` frozen at its step average:
/// `Q = Q_c dt + (F Q_c + Q_c F') dt²/2 + (F² Q_c + 2 F Q_c F' + Q_c F'²) dt³/6`.
///
/// `qv` is the velocity noise density in the navigation frame (the body-axis accelerometer
/// densities rotated along the step), `r` the step's mean attitude and `y` the mean
/// specific force in the navigation frame. Exact for the position–velocity double
/// integrator; the neglected terms are `O(dt⁴)` (below 1e-4 of the kept ones at 0.1 s).
pub fn process_noise(
    qv: &Matrix3<f64>,
    r: &Matrix3<f64>,
    y: &Vector3<f64>,
    n: &NoiseDensities,
    dt: f64,
) -> Mat15 {
    let Y = -skew(y);
    let Ra = -r;
    let i3 = Matrix3::identity();
    let (qg, qa, qb) = (n.gyro, n.accel_bias, n.gyro_bias);
    let (d1, d2, d3) = (dt, dt * dt / 2.0, dt * dt * dt / 6.0);
    let mut Q = Mat15::zeros();
    let mut add = |r0: usize, c0: usize, b: Matrix3<f64>| {
        let mut v = Q.fixed_view_mut::<3, 3>(r0, c0);
        v += b;
        if r0 != c0 {
            let mut w = Q.fixed_view_mut::<3, 3>(c0, r0);
            w += b.transpose();
        }
    };
    // Q_c dt.
    add(IV, IV, qv * d1);
    add(IPSI, IPSI, i3 * (qg * d1));
    add(IBA, IBA, i3 * (qa * d1));
    add(IBG, IBG, i3 * (qb * d1));
    // (F Q_c + Q_c F') dt²/2: F Q_c has blocks (p,v) Q_v, (v,ψ) q_g Y, (v,a) q_a R_a,
    // (ψ,g) q_b R_a.
    add(IP, IV, qv * d2);
    add(IV, IPSI, Y * (qg * d2));
    add(IV, IBA, Ra * (qa * d2));
    add(IPSI, IBG, Ra * (qb * d2));
    // 2 F Q_c F' dt³/6: block diagonal.
    add(IP, IP, qv * (2.0 * d3));
    add(IV, IV, (Y * Y.transpose() * qg + i3 * qa) * (2.0 * d3));
    add(IPSI, IPSI, i3 * (qb * 2.0 * d3));
    // (F² Q_c + Q_c F'²) dt³/6: F² Q_c has blocks (p,ψ) q_g Y, (p,a) q_a R_a,
    // (v,g) q_b Y R_a.
    add(IP, IPSI, Y * (qg * d3));
    add(IP, IBA, Ra * (qa * d3));
    add(IV, IBG, Y * Ra * (qb * d3));
    Q
}
