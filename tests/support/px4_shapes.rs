//! Issue 37: PX4 logs of the shapes the field-log statements were false on, written with
//! [`super::ulog`] from the real message layouts of two logs of PX4's own parser test data
//! (pyulog `test/`): `sample_log_small.ulg` (v1.11, a 1.2 s hop, topics at 5 Hz, the
//! magnetometer at ~50 Hz and airspeed at ~90 Hz while neither is fused) and
//! `sample_appended_multiple.ulg` (v1.6, `ekf2_innovations` with `output_tracking_error`,
//! `EKF2_HGT_MODE` = 0, `estimator_status.control_mode_flags` with baro height and
//! magnetic heading, no GPS).

use super::px4_fixtures::{
    self as fx, AIR_DATA_V111, INNOV_V111, LAND_V111, Row, STATUS_V111, Truth, ekf2_log, normal,
    rng, us,
};
use super::ulog::{Param, ULogWriter};

/// Length of the short-hop fixture, s.
pub const HOP_LOG_S: f64 = 40.0;
/// Takeoff and landing of the short-hop fixture, s after `T0_US`: 6 innovation rows at
/// 5 Hz fall in the air (20.0 … 21.0 s).
pub const HOP_AIR_S: (f64, f64) = (20.0, 21.2);

const MAGNETOMETER_V111: &str = "uint64_t timestamp;float[3] magnetometer_ga;uint8_t[4] _padding0;";
const AIRSPEED_V111: &str = "uint64_t timestamp;float indicated_airspeed_m_s;float true_airspeed_m_s;float air_temperature_celsius;float confidence;";

/// `control_mode_flags` bits: tilt and yaw aligned, magnetic heading, baro height; in air.
const FLAGS_MAG_BARO: u32 = (1 << 0) | (1 << 1) | (1 << 4) | (1 << 9);
const IN_AIR_BIT: u32 = 1 << 7;

/// Rows of `topic` at `hz` over `[0, end)` s, each from `row(t)`.
fn rows_at(w: &mut ULogWriter, topic: &str, hz: f64, end: f64, row: impl Fn(f64) -> Row) {
    let n = (end * hz) as usize;
    for k in 0..n {
        row(k as f64 / hz).write(w, topic, 0);
    }
}

/// Rows of [`short_hop_v111`] whose baro innovation is logged as exactly −0 beside its
/// usual S (as a real v1.15 log holds baro for ten rows in flight).
pub const HOP_BARO_ZERO_ROWS: [usize; 5] = [7, 47, 87, 127, 167];

fn baro_nu(k: usize, z: f64) -> f64 {
    if HOP_BARO_ZERO_ROWS.contains(&k) {
        -0.0
    } else {
        0.045 * 12.35f64.sqrt() * z
    }
}

/// A v1.11 bench hop without GPS, in `sample_log_small.ulg`'s shape: `gps_hpos` is fake
/// position, baro is far underconfident (ν/√S ≈ 0.045 N(0,1): NIS ≈ 0.002) and white,
/// heading is a constant offset of −0.5σ with a little noise (the mean carries 99 % of
/// E[ν²/S]), baro is −0 on [`HOP_BARO_ZERO_ROWS`], `mag_field` and `airspeed` are never fused (all rows 0/0) while
/// `vehicle_magnetometer` (50 Hz) and `airspeed` (90 Hz) are logged faster than the 5 Hz
/// innovation topics; baro data at 20 Hz. The vehicle flies from 20.0 to 21.2 s.
pub fn short_hop_v111(seed: u64) -> Vec<u8> {
    let mut truth = Truth::new("short_hop_v111", fx::V1_11);
    let mut r = rng(seed);
    let mut w = ekf2_log(&mut truth, 2, &[]);
    for t in ["estimator_innovations", "estimator_innovation_variances"] {
        w.format(t, INNOV_V111);
    }
    for (topic, spec) in [
        ("estimator_status", STATUS_V111),
        ("vehicle_air_data", AIR_DATA_V111),
        ("vehicle_magnetometer", MAGNETOMETER_V111),
        ("airspeed", AIRSPEED_V111),
        ("vehicle_land_detected", LAND_V111),
    ] {
        w.format(topic, spec);
    }
    let flying = |t: f64| (HOP_AIR_S.0..HOP_AIR_S.1).contains(&t);
    let (baro_s, head_s, fake_s): (f64, f64, f64) = (12.35, 0.091, 0.2501);
    let n = (HOP_LOG_S * 5.0) as usize;
    for k in 0..n {
        let t = k as f64 / 5.0;
        let (mut iv, mut sv) = (Row::default(), Row::default());
        iv.times(us(t), None);
        sv.times(us(t), None);
        for (field, i, s, nu) in [
            ("gps_hpos", 0, fake_s, 0.002 * normal(&mut r)),
            ("gps_hpos", 1, fake_s, 0.002 * normal(&mut r)),
            ("baro_vpos", 0, baro_s, baro_nu(k, normal(&mut r))),
            (
                "heading",
                0,
                head_s,
                (-0.5 + 0.05 * normal(&mut r)) * head_s.sqrt(),
            ),
        ] {
            iv.set(field, i, nu);
            sv.set(field, i, s);
        }
        iv.write(&mut w, "estimator_innovations", 0);
        sv.write(&mut w, "estimator_innovation_variances", 0);
    }
    rows_at(&mut w, "estimator_status", 1.0, HOP_LOG_S, |t| {
        let mut s = Row::default();
        let air = if flying(t) { IN_AIR_BIT } else { 0 };
        s.times(us(t), None)
            .set("control_mode_flags", 0, f64::from(FLAGS_MAG_BARO | air))
            .set("n_states", 0, 24.0);
        s
    });
    for (topic, hz, field, v) in [
        ("vehicle_air_data", 20.0, "baro_alt_meter", 488.0),
        ("vehicle_magnetometer", 50.0, "magnetometer_ga", 0.2),
        ("airspeed", 90.0, "true_airspeed_m_s", 0.1),
    ] {
        rows_at(&mut w, topic, hz, HOP_LOG_S, |t| {
            let mut a = Row::default();
            a.times(us(t) + 1_000, None).set(field, 0, v);
            a
        });
    }
    let mut times: Vec<f64> = (0..HOP_LOG_S as usize).map(|k| k as f64 + 0.5).collect();
    times.extend([HOP_AIR_S.0, HOP_AIR_S.1]);
    times.sort_by(f64::total_cmp);
    for t in times {
        let landed = f64::from(u8::from(!flying(t)));
        let mut l = Row::default();
        l.times(us(t), None)
            .set("landed", 0, landed)
            .set("maybe_landed", 0, landed)
            .set("ground_contact", 0, landed);
        l.write(&mut w, "vehicle_land_detected", 0);
    }
    w.finish()
}

/// `ver_sw_release` of v1.6.0.
pub const V1_6: u32 = 0x0106_0000;
const LEGACY_INNOV_V16: &str = "uint64_t timestamp;float[6] vel_pos_innov;float[3] mag_innov;float heading_innov;float airspeed_innov;float beta_innov;float[2] flow_innov;float hagl_innov;float[6] vel_pos_innov_var;float[3] mag_innov_var;float heading_innov_var;float airspeed_innov_var;float beta_innov_var;float[2] flow_innov_var;float hagl_innov_var;float[3] output_tracking_error;";
const STATUS_V16: &str = "uint64_t timestamp;float[24] states;float n_states;float[3] vibe;float[24] covariances;uint32_t control_mode_flags;float pos_horiz_accuracy;float pos_vert_accuracy;float mag_test_ratio;float vel_test_ratio;float pos_test_ratio;float hgt_test_ratio;float tas_test_ratio;float hagl_test_ratio;float time_slip;uint16_t gps_check_fail_flags;uint16_t filter_fault_flags;uint16_t innovation_check_flags;uint16_t solution_status_flags;uint8_t nan_flags;uint8_t health_flags;uint8_t timeout_flags;uint8_t[5] _padding0;";
const EKF2_TIMESTAMPS_V16: &str = "uint64_t timestamp;int16_t gps_timestamp_rel;int16_t optical_flow_timestamp_rel;int16_t distance_sensor_timestamp_rel;int16_t airspeed_timestamp_rel;int16_t vision_position_timestamp_rel;int16_t vision_attitude_timestamp_rel;uint8_t[4] _padding0;";

/// A v1.6 log in `sample_appended_multiple.ulg`'s shape: `ekf2_innovations` at 20 Hz for
/// 60 s, the height channel `vel_pos[5]` fused every row with its S 20 times the true
/// innovation variance (NIS ≈ 0.05, white), `heading` consistent, `vel_pos[3..4]` fake
/// position (no GPS), everything else 0/0. `EKF2_HGT_MODE` = `hgt_mode`; with
/// `with_flags`, `estimator_status.control_mode_flags` says baro height and magnetic
/// heading (so the flags, not the parameter, name the height source), else the log has
/// no status. `ekf2_timestamps` confirms EKF2.
pub fn legacy_v16(seed: u64, hgt_mode: i32, with_flags: bool) -> Vec<u8> {
    let mut truth = Truth::new("legacy_v16", V1_6);
    let mut r = rng(seed);
    let mut w = ekf2_log(&mut truth, 2, &[("EKF2_BARO_NOISE", 2.0)]);
    w.param("EKF2_HGT_MODE", Param::Int(hgt_mode));
    w.format("ekf2_innovations", LEGACY_INNOV_V16)
        .format("ekf2_timestamps", EKF2_TIMESTAMPS_V16);
    if with_flags {
        w.format("estimator_status", STATUS_V16);
    }
    let (hgt_s, head_s, fake_s): (f64, f64, f64) = (4.2, 0.0905, 0.2501);
    let log_s = 60.0;
    let n = (log_s * 20.0) as usize;
    for k in 0..n {
        let t = k as f64 / 20.0;
        let mut row = Row::default();
        row.times(us(t), None);
        for (i, s, nu) in [
            (3, fake_s, 0.002 * normal(&mut r)),
            (4, fake_s, 0.002 * normal(&mut r)),
            (5, hgt_s, (hgt_s / 20.0).sqrt() * normal(&mut r)),
        ] {
            row.set("vel_pos_innov", i, nu)
                .set("vel_pos_innov_var", i, s);
        }
        row.set("heading_innov", 0, head_s.sqrt() * normal(&mut r))
            .set("heading_innov_var", 0, head_s);
        row.write(&mut w, "ekf2_innovations", 0);
    }
    rows_at(&mut w, "ekf2_timestamps", 20.0, log_s, |t| {
        let mut e = Row::default();
        e.times(us(t) + 500, None);
        e
    });
    if with_flags {
        rows_at(&mut w, "estimator_status", 1.0, log_s, |t| {
            let mut s = Row::default();
            s.times(us(t), None)
                .set("control_mode_flags", 0, f64::from(FLAGS_MAG_BARO))
                .set("n_states", 0, 24.0);
            s
        });
    }
    w.finish()
}
