//! PX4 flight logs with known truth, written with [`super::ulog`] from the real PX4 message
//! layouts (field names, types and the size-sorted order the PX4 logger writes).
//!
//! Layout sources: v1.13 and v1.15 formats as found in the two real PX4 SITL logs of
//! `tests/data/px4/README.md` (their 'F' messages), the v1.11 `estimator_innovations` field set
//! (the v1.13 set without `timestamp_sample`, `hagl_rate`), `control_mode_flags` bits of
//! `estimator_status` (0 tilt, 1 yaw, 2 GPS, 4 mag heading, 7 in air, 9 baro height), and the
//! pre-v1.11 `ekf2_innovations`. The `estimator_aid_src_*` layout is the v1.15 one
//! (scalar `fused` and `innovation_rejected` also in the 2d and 3d messages; v1.13 had
//! `bool[2]`/`bool[3]` arrays there).
//!
//! Every fixture flies the same profile: first row at [`T0_US`], takeoff at
//! [`TAKEOFF_S`], landing at [`LANDING_S`] (seconds after `T0_US`).

use std::collections::BTreeMap;

use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

use super::ulog::{Param, ULogWriter};

/// Time of the first data row, µs since boot (the header's start is 0.5 s earlier).
pub const T0_US: u64 = 20_000_000;
/// Takeoff, seconds after [`T0_US`].
pub const TAKEOFF_S: f64 = 40.0;
/// Landing, seconds after [`T0_US`].
pub const LANDING_S: f64 = 170.0;
/// Length of every fixture's log, seconds.
pub const DURATION_S: f64 = 200.0;

/// `ver_sw_release` of v1.11.0 (major, minor, patch, type bytes; 0 = development).
pub const V1_11: u32 = 0x010B_0000;
/// `ver_sw_release` of v1.13.0.
pub const V1_13: u32 = 0x010D_0000;
/// `ver_sw_release` of v1.15.0.
pub const V1_15: u32 = 0x010F_0000;
/// `ver_sw_release` of v1.8.0 (LPE era).
pub const V1_8: u32 = 0x0108_0000;

/// µs since boot of `t` seconds after [`T0_US`].
pub fn us(t: f64) -> u64 {
    T0_US + (t * 1e6).round() as u64
}

/// What a channel is, and so whether a reader may advise on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A real sensor fused by EKF2: judge and advise.
    Sensor,
    /// EKF2's fake position (or height) fusion with no aiding source: never advise.
    FakeFusion,
    /// Published by another estimator (LPE): the "variance" is R, not S; never judge as NIS.
    NotEkf2,
}

/// The truth of one logged channel.
#[derive(Clone, Debug)]
pub struct ChannelTruth {
    /// EKF instance (`multi_id`).
    pub instance: u8,
    /// Topic carrying the innovation.
    pub topic: String,
    /// Field and element, e.g. `gps_hpos[0]`, `baro_vpos`, `innovation[1]`.
    pub field: String,
    /// What the channel is.
    pub kind: Kind,
    /// E[ν²/S] by construction (1 consistent, > 1 S too small, < 1 S too large); NaN when
    /// the fixture only fixes it through a filter simulation (see `r_factor`, `q_factor`).
    pub nis_mean: f64,
    /// The filter's R over the true R (1 right, 0.25 for "R ×4 too small").
    pub r_factor: f64,
    /// The EKF2 parameter setting this channel's R, if any.
    pub param: Option<&'static str>,
    /// That parameter's value in the log.
    pub param_value: Option<f64>,
    /// The true measurement noise σ, in the parameter's unit.
    pub true_sigma: Option<f64>,
    /// Rows with the channel fused (aid-source fixtures: `fused`; others: rows written with
    /// a non-zero variance, in or out of the air).
    pub fused: usize,
    /// Rows with `innovation_rejected` set (aid-source fixtures only).
    pub rejected: usize,
}

/// Everything a test needs to know about a fixture.
#[derive(Clone, Debug)]
pub struct Truth {
    /// Fixture name.
    pub name: &'static str,
    /// `ver_sw_release` written in the info section.
    pub ver_sw_release: u32,
    /// Takeoff time, µs since boot (log's time base).
    pub takeoff_us: u64,
    /// Landing time, µs since boot.
    pub landing_us: u64,
    /// Data rows written per (topic, multi_id).
    pub rows: BTreeMap<(String, u8), usize>,
    /// Parameter values in the log's parameter section (initial values).
    pub params: BTreeMap<String, f64>,
    /// Parameter changes inside the data section: (µs since boot, name, value).
    pub param_changes: Vec<(u64, String, f64)>,
    /// The channels and their truth.
    pub channels: Vec<ChannelTruth>,
    /// Events with their time (µs since boot): aiding-source changes, primary switches.
    pub events: Vec<(u64, String)>,
    /// Rate at which the innovation topics are logged, Hz.
    pub innovation_log_hz: f64,
    /// Rate of the sources, Hz (e.g. `baro` 20 from `vehicle_air_data`), where the fixture
    /// logs them faster than the innovations.
    pub source_hz: BTreeMap<String, f64>,
    /// Process noise of the simulated filter over the truth's (1 right, 1/25 too small).
    pub q_factor: f64,
    /// Which EKF instance is primary from when (µs since boot).
    pub primary: Vec<(u64, u8)>,
    /// Biased-heading fixture: the mean's share of E[ν²/S] as written, the raw (not
    /// demeaned) lag-1 autocorrelation target, and the AR(1) coefficient used.
    pub heading_bias: Option<(f64, f64, f64)>,
}

impl Truth {
    pub fn new(name: &'static str, ver: u32) -> Self {
        Truth {
            name,
            ver_sw_release: ver,
            takeoff_us: us(TAKEOFF_S),
            landing_us: us(LANDING_S),
            rows: BTreeMap::new(),
            params: BTreeMap::new(),
            param_changes: Vec::new(),
            channels: Vec::new(),
            events: Vec::new(),
            innovation_log_hz: 0.0,
            source_hz: BTreeMap::new(),
            q_factor: 1.0,
            primary: Vec::new(),
            heading_bias: None,
        }
    }

    /// The channel `field` of `topic` instance `instance`.
    pub fn channel(&self, topic: &str, instance: u8, field: &str) -> &ChannelTruth {
        self.channels
            .iter()
            .find(|c| c.topic == topic && c.instance == instance && c.field == field)
            .unwrap_or_else(|| panic!("{}: no channel {topic}/{instance}/{field}", self.name))
    }
}

pub fn rng(seed: u64) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(seed)
}

pub fn normal(r: &mut Xoshiro256PlusPlus) -> f64 {
    r.sample(StandardNormal)
}

fn flying(t: f64) -> bool {
    (TAKEOFF_S..LANDING_S).contains(&t)
}

/// A row under construction: field name → elements.
#[derive(Default)]
pub struct Row(BTreeMap<&'static str, Vec<f64>>);

impl Row {
    pub fn set(&mut self, field: &'static str, idx: usize, v: f64) -> &mut Self {
        let e = self.0.entry(field).or_default();
        if e.len() <= idx {
            e.resize(idx + 1, 0.0);
        }
        e[idx] = v;
        self
    }
    pub fn times(&mut self, t_us: u64, sample_us: Option<u64>) -> &mut Self {
        self.set("timestamp", 0, t_us as f64);
        if let Some(s) = sample_us {
            self.set("timestamp_sample", 0, s as f64);
        }
        self
    }
    pub fn write(&self, w: &mut ULogWriter, topic: &str, multi: u8) {
        let v: Vec<(&str, &[f64])> = self.0.iter().map(|(k, v)| (*k, v.as_slice())).collect();
        w.data(topic, multi, &v);
    }
    fn write_at(&self, w: &mut ULogWriter, order_us: u64, topic: &str, multi: u8) {
        let v: Vec<(&str, &[f64])> = self.0.iter().map(|(k, v)| (*k, v.as_slice())).collect();
        w.data_at(order_us, topic, multi, &v);
    }
}

/// Split `gps_hpos[1]` into (`gps_hpos`, 1); `baro_vpos` is (`baro_vpos`, 0).
fn split(field: &'static str) -> (&'static str, usize) {
    match field.split_once('[') {
        Some((f, i)) => (f, i.trim_end_matches(']').parse().unwrap()),
        None => (field, 0),
    }
}

pub const INNOV_V111: &str = "uint64_t timestamp;float[2] gps_hvel;float gps_vvel;float[2] gps_hpos;float gps_vpos;float[2] ev_hvel;float ev_vvel;float[2] ev_hpos;float ev_vpos;float rng_vpos;float baro_vpos;float[2] aux_hvel;float aux_vvel;float[2] flow;float heading;float[3] mag_field;float[2] drag;float airspeed;float beta;float hagl;";
const INNOV_V113: &str = "uint64_t timestamp;uint64_t timestamp_sample;float[2] gps_hvel;float gps_vvel;float[2] gps_hpos;float gps_vpos;float[2] ev_hvel;float ev_vvel;float[2] ev_hpos;float ev_vpos;float rng_vpos;float baro_vpos;float[2] aux_hvel;float aux_vvel;float[2] flow;float heading;float[3] mag_field;float[2] drag;float airspeed;float beta;float hagl;float hagl_rate;uint8_t[4] _padding0;";
const INNOV_TOPICS: [&str; 3] = [
    "estimator_innovations",
    "estimator_innovation_variances",
    "estimator_innovation_test_ratios",
];
pub const STATUS_V111: &str = "uint64_t timestamp;float[24] states;float[3] vibe;float[24] covariances;float[3] output_tracking_error;uint32_t control_mode_flags;uint32_t filter_fault_flags;float pos_horiz_accuracy;float pos_vert_accuracy;float mag_test_ratio;float vel_test_ratio;float pos_test_ratio;float hgt_test_ratio;float tas_test_ratio;float hagl_test_ratio;float beta_test_ratio;float time_slip;uint16_t gps_check_fail_flags;uint16_t innovation_check_flags;uint16_t solution_status_flags;uint8_t n_states;uint8_t health_flags;uint8_t timeout_flags;bool pre_flt_fail_innov_heading;bool pre_flt_fail_innov_vel_horiz;bool pre_flt_fail_innov_vel_vert;bool pre_flt_fail_innov_height;bool pre_flt_fail_mag_field_disturbed;uint8_t[4] _padding0;";
const STATUS_FLAGS_V113: &str = "uint64_t timestamp;uint64_t timestamp_sample;uint32_t control_status_changes;uint32_t fault_status_changes;uint32_t innovation_fault_status_changes;bool cs_tilt_align;bool cs_yaw_align;bool cs_gps;bool cs_opt_flow;bool cs_mag_hdg;bool cs_mag_3d;bool cs_mag_dec;bool cs_in_air;bool cs_wind;bool cs_baro_hgt;bool cs_rng_hgt;bool cs_gps_hgt;bool cs_ev_pos;bool cs_ev_yaw;bool cs_ev_hgt;bool cs_fuse_beta;bool cs_mag_field_disturbed;bool cs_fixed_wing;bool cs_mag_fault;bool cs_fuse_aspd;bool cs_gnd_effect;bool cs_rng_stuck;bool cs_gps_yaw;bool cs_mag_aligned_in_flight;bool cs_ev_vel;bool cs_synthetic_mag_z;bool cs_vehicle_at_rest;bool cs_gps_yaw_fault;bool cs_rng_fault;bool cs_inertial_dead_reckoning;bool cs_wind_dead_reckoning;bool cs_rng_kin_consistent;bool fs_bad_mag_x;bool fs_bad_mag_y;bool fs_bad_mag_z;bool fs_bad_hdg;bool fs_bad_mag_decl;bool fs_bad_airspeed;bool fs_bad_sideslip;bool fs_bad_optflow_x;bool fs_bad_optflow_y;bool fs_bad_vel_n;bool fs_bad_vel_e;bool fs_bad_vel_d;bool fs_bad_pos_n;bool fs_bad_pos_e;bool fs_bad_pos_d;bool fs_bad_acc_bias;bool fs_bad_acc_vertical;bool fs_bad_acc_clipping;bool reject_hor_vel;bool reject_ver_vel;bool reject_hor_pos;bool reject_ver_pos;bool reject_mag_x;bool reject_mag_y;bool reject_mag_z;bool reject_yaw;bool reject_airspeed;bool reject_sideslip;bool reject_hagl;bool reject_optflow_x;bool reject_optflow_y;uint8_t[5] _padding0;";
const STATUS_FLAGS_V115: &str = "uint64_t timestamp;uint64_t timestamp_sample;uint32_t control_status_changes;uint32_t fault_status_changes;uint32_t innovation_fault_status_changes;bool cs_tilt_align;bool cs_yaw_align;bool cs_gps;bool cs_opt_flow;bool cs_mag_hdg;bool cs_mag_3d;bool cs_mag_dec;bool cs_in_air;bool cs_wind;bool cs_baro_hgt;bool cs_rng_hgt;bool cs_gps_hgt;bool cs_ev_pos;bool cs_ev_yaw;bool cs_ev_hgt;bool cs_fuse_beta;bool cs_mag_field_disturbed;bool cs_fixed_wing;bool cs_mag_fault;bool cs_fuse_aspd;bool cs_gnd_effect;bool cs_rng_stuck;bool cs_gps_yaw;bool cs_mag_aligned_in_flight;bool cs_ev_vel;bool cs_synthetic_mag_z;bool cs_vehicle_at_rest;bool cs_gps_yaw_fault;bool cs_rng_fault;bool cs_inertial_dead_reckoning;bool cs_wind_dead_reckoning;bool cs_rng_kin_consistent;bool cs_fake_pos;bool cs_fake_hgt;bool cs_gravity_vector;bool cs_mag;bool cs_ev_yaw_fault;bool cs_mag_heading_consistent;bool cs_aux_gpos;bool fs_bad_mag_x;bool fs_bad_mag_y;bool fs_bad_mag_z;bool fs_bad_hdg;bool fs_bad_mag_decl;bool fs_bad_airspeed;bool fs_bad_sideslip;bool fs_bad_optflow_x;bool fs_bad_optflow_y;bool fs_bad_vel_n;bool fs_bad_vel_e;bool fs_bad_vel_d;bool fs_bad_pos_n;bool fs_bad_pos_e;bool fs_bad_pos_d;bool fs_bad_acc_bias;bool fs_bad_acc_vertical;bool fs_bad_acc_clipping;bool reject_hor_vel;bool reject_ver_vel;bool reject_hor_pos;bool reject_ver_pos;bool reject_yaw;bool reject_airspeed;bool reject_sideslip;bool reject_hagl;bool reject_optflow_x;bool reject_optflow_y;uint8_t _padding0;";
const SELECTOR_V113: &str = "uint64_t timestamp;uint64_t last_instance_change;uint32_t instance_changed_count;uint32_t accel_device_id;uint32_t baro_device_id;uint32_t gyro_device_id;uint32_t mag_device_id;float[9] combined_test_ratio;float[9] relative_test_ratio;float[4] accumulated_gyro_error;float[4] accumulated_accel_error;uint8_t primary_instance;uint8_t instances_available;bool[9] healthy;bool gyro_fault_detected;bool accel_fault_detected;uint8_t[7] _padding0;";
pub const LAND_V111: &str = "uint64_t timestamp;float alt_max;bool freefall;bool ground_contact;bool maybe_landed;bool landed;bool in_ground_effect;uint8_t[3] _padding0;";
const LAND_V113: &str = "uint64_t timestamp;bool freefall;bool ground_contact;bool maybe_landed;bool landed;bool in_ground_effect;bool in_descend;bool has_low_throttle;bool vertical_movement;bool horizontal_movement;bool close_to_ground_or_skipped_check;bool at_rest;uint8_t[5] _padding0;";
const LAND_V115: &str = "uint64_t timestamp;bool freefall;bool ground_contact;bool maybe_landed;bool landed;bool in_ground_effect;bool in_descend;bool has_low_throttle;bool vertical_movement;bool horizontal_movement;bool rotational_movement;bool close_to_ground_or_skipped_check;bool at_rest;uint8_t[4] _padding0;";
pub const AIR_DATA_V111: &str = "uint64_t timestamp;uint32_t baro_device_id;float baro_alt_meter;float baro_temp_celcius;float baro_pressure_pa;float rho;uint8_t[4] _padding0;";
const LEGACY_INNOV: &str = "uint64_t timestamp;float[6] vel_pos_innov;float[3] mag_innov;float heading_innov;float airspeed_innov;float beta_innov;float[2] flow_innov;float hagl_innov;float[6] vel_pos_innov_var;float[3] mag_innov_var;float heading_innov_var;float airspeed_innov_var;float beta_innov_var;float[2] flow_innov_var;float hagl_innov_var;";
const AID_1D: &str = "uint64_t timestamp;uint64_t timestamp_sample;uint64_t time_last_fuse;uint32_t device_id;float observation;float observation_variance;float innovation;float innovation_variance;float test_ratio;uint8_t estimator_instance;bool innovation_rejected;bool fused;uint8_t[5] _padding0;";
const AID_2D: &str = "uint64_t timestamp;uint64_t timestamp_sample;uint64_t time_last_fuse;uint32_t device_id;float[2] observation;float[2] observation_variance;float[2] innovation;float[2] innovation_variance;float[2] test_ratio;uint8_t estimator_instance;bool innovation_rejected;bool fused;uint8_t _padding0;";
const AID_3D: &str = "uint64_t timestamp;uint64_t timestamp_sample;uint64_t time_last_fuse;uint32_t device_id;float[3] observation;float[3] observation_variance;float[3] innovation;float[3] innovation_variance;float[3] test_ratio;uint8_t estimator_instance;bool innovation_rejected;bool fused;uint8_t[5] _padding0;";

/// EKF2 parameters every EKF2 fixture writes (PX4 defaults of the v1.11–v1.15 era).
const EKF2_PARAMS: [(&str, f64); 14] = [
    ("EKF2_GPS_P_NOISE", 0.5),
    ("EKF2_GPS_V_NOISE", 0.3),
    ("EKF2_BARO_NOISE", 3.5),
    ("EKF2_HEAD_NOISE", 0.3),
    ("EKF2_MAG_NOISE", 0.05),
    ("EKF2_ACC_NOISE", 0.35),
    ("EKF2_GYR_NOISE", 0.015),
    ("EKF2_ABIAS_NOISE", 0.003),
    ("EKF2_GBIAS_NOISE", 0.001),
    ("EKF2_BARO_GATE", 5.0),
    ("EKF2_GPS_P_GATE", 5.0),
    ("EKF2_GPS_V_GATE", 5.0),
    ("EKF2_HDG_GATE", 2.6),
    ("EKF2_RNG_NOISE", 0.1),
];

/// The header, info and parameters of an EKF2 log; `over` replaces defaults.
pub fn ekf2_log(truth: &mut Truth, est_group: i32, over: &[(&str, f64)]) -> ULogWriter {
    let mut w = ULogWriter::new(T0_US - 500_000);
    w.info_str("sys_name", "PX4")
        .info_str("ver_hw", "AUTOTUNE_FIXTURE")
        .info_u32("ver_sw_release", truth.ver_sw_release);
    w.param("SYS_MC_EST_GROUP", Param::Int(est_group));
    truth
        .params
        .insert("SYS_MC_EST_GROUP".into(), f64::from(est_group));
    for (name, default) in EKF2_PARAMS {
        let v = over
            .iter()
            .find(|(n, _)| *n == name)
            .map_or(default, |(_, v)| *v);
        w.param(name, Param::Float(v as f32));
        truth.params.insert(name.into(), f64::from(v as f32));
    }
    w
}

/// `vehicle_land_detected` at 1 Hz plus a row at takeoff and at landing.
fn land_detected(w: &mut ULogWriter, spec: &str, multi_fields: bool) {
    w.format("vehicle_land_detected", spec);
    let mut times: Vec<f64> = (0..DURATION_S as usize).map(|k| k as f64 + 0.5).collect();
    times.extend([TAKEOFF_S, LANDING_S]);
    times.sort_by(f64::total_cmp);
    for t in times {
        let landed = f64::from(u8::from(!flying(t)));
        let mut r = Row::default();
        r.times(us(t), None)
            .set("landed", 0, landed)
            .set("maybe_landed", 0, landed)
            .set("ground_contact", 0, landed);
        if multi_fields {
            r.set("at_rest", 0, landed);
        }
        r.write(w, "vehicle_land_detected", 0);
    }
}

/// One channel of an innovation-topic fixture: field, S, and how ν is drawn.
struct Chan {
    field: &'static str,
    s: f64,
    gate: f64,
    kind: Kind,
    /// E[ν²] / S.
    ratio: f64,
    param: Option<&'static str>,
}

/// Write the three innovation topics of `instance` at `hz` with white ν ~ N(0, ratio·S);
/// `heading` overrides the `heading` channel's normalised innovations (ν/√S) row by row.
#[allow(clippy::too_many_arguments)]
fn innovation_rows(
    w: &mut ULogWriter,
    truth: &mut Truth,
    r: &mut Xoshiro256PlusPlus,
    instance: u8,
    hz: f64,
    with_sample: bool,
    with_ratios: bool,
    chans: &[Chan],
    heading: Option<&[f64]>,
) {
    let n = (DURATION_S * hz) as usize;
    let mut fused = vec![0usize; chans.len()];
    for k in 0..n {
        let t = k as f64 / hz;
        let t_us = us(t);
        let sample = with_sample.then(|| t_us - 3_000);
        let (mut iv, mut sv, mut tr) = (Row::default(), Row::default(), Row::default());
        iv.times(t_us, sample);
        sv.times(t_us, sample);
        tr.times(t_us, sample);
        for (j, c) in chans.iter().enumerate() {
            let (f, i) = split(c.field);
            let z = match (c.field, heading) {
                ("heading", Some(h)) => h[k],
                _ => c.ratio.sqrt() * normal(r),
            };
            let nu = z * c.s.sqrt();
            iv.set(f, i, nu);
            sv.set(f, i, c.s);
            // PX4 puts a vector's (largest) test ratio in its first element.
            let ratio = nu * nu / (c.gate * c.gate * c.s);
            let prev = tr.0.get(f).and_then(|v| v.first()).copied().unwrap_or(0.0);
            tr.set(f, 0, prev.max(ratio));
            fused[j] += 1;
        }
        iv.write(w, INNOV_TOPICS[0], instance);
        sv.write(w, INNOV_TOPICS[1], instance);
        if with_ratios {
            tr.write(w, INNOV_TOPICS[2], instance);
        }
    }
    for (j, c) in chans.iter().enumerate() {
        truth.channels.push(ChannelTruth {
            instance,
            topic: INNOV_TOPICS[0].into(),
            field: c.field.into(),
            kind: c.kind,
            nis_mean: c.ratio,
            r_factor: 1.0,
            param: c.param,
            param_value: c.param.and_then(|p| truth.params.get(p).copied()),
            true_sigma: None,
            fused: fused[j],
            rejected: 0,
        });
    }
}

fn chan(field: &'static str, s: f64, gate: f64, ratio: f64, param: Option<&'static str>) -> Chan {
    Chan {
        field,
        s,
        gate,
        kind: Kind::Sensor,
        ratio,
        param,
    }
}

/// (a) A v1.11 bench-style flight without GPS: EKF2 fuses fake position into the
/// `gps_hpos` fields (gate 100, millimetre innovations; the GPS bit of
/// `control_mode_flags` never set), baro is underconfident (logged S = 3 × the true
/// innovation variance), heading consistent. Innovation topics at 5 Hz (samples of the
/// 100 Hz EKF's fusions), `vehicle_air_data` at 20 Hz (the baro's rate); no
/// `timestamp_sample` anywhere.
pub fn fake_position_v111(seed: u64) -> (Vec<u8>, Truth) {
    let mut truth = Truth::new("fake_position_v111", V1_11);
    let mut r = rng(seed);
    let mut w = ekf2_log(&mut truth, 2, &[]);
    for t in INNOV_TOPICS {
        w.format(t, INNOV_V111);
    }
    w.format("estimator_status", STATUS_V111);
    w.format("vehicle_air_data", AIR_DATA_V111);
    land_detected(&mut w, LAND_V111, false);
    truth.innovation_log_hz = 5.0;
    truth.source_hz.insert("baro".into(), 20.0);
    // Fake position: R = 0.5² m² in EKF2, the innovations are millimetres.
    let fake_s = 0.25 + 1e-4;
    let fake_ratio = 0.002f64.powi(2) / fake_s;
    let baro_s = 3.5f64.powi(2) + 0.1;
    let head_s = 0.3f64.powi(2) + 0.001;
    let mut chans = vec![
        chan("gps_hpos[0]", fake_s, 100.0, fake_ratio, None),
        chan("gps_hpos[1]", fake_s, 100.0, fake_ratio, None),
        chan("baro_vpos", baro_s, 5.0, 1.0 / 3.0, Some("EKF2_BARO_NOISE")),
        chan("heading", head_s, 2.6, 1.0, Some("EKF2_HEAD_NOISE")),
    ];
    chans[0].kind = Kind::FakeFusion;
    chans[1].kind = Kind::FakeFusion;
    innovation_rows(
        &mut w, &mut truth, &mut r, 0, 5.0, false, true, &chans, None,
    );
    for k in 0..DURATION_S as usize {
        let t = k as f64;
        // tilt, yaw, mag heading, baro height; in air while flying; never GPS (bit 2).
        let mut flags = (1u32 << 0) | (1 << 1) | (1 << 4) | (1 << 9);
        if flying(t) {
            flags |= 1 << 7;
        }
        let mut s = Row::default();
        s.times(us(t), None)
            .set("control_mode_flags", 0, f64::from(flags))
            .set("n_states", 0, 24.0);
        s.write(&mut w, "estimator_status", 0);
    }
    for k in 0..(DURATION_S * 20.0) as usize {
        let t = k as f64 / 20.0;
        let alt = if flying(t) { 10.0 } else { 0.0 } + 488.0 + normal(&mut r);
        let mut a = Row::default();
        a.times(us(t) + 1_000, None)
            .set("baro_device_id", 0, 6_620_172.0)
            .set("baro_alt_meter", 0, alt)
            .set("baro_temp_celcius", 0, 25.0)
            .set("baro_pressure_pa", 0, 95_500.0)
            .set("rho", 0, 1.13);
        a.write(&mut w, "vehicle_air_data", 0);
    }
    truth.rows = w.rows_written();
    (w.finish(), truth)
}

/// (b) A pre-v1.11 `ekf2_innovations` published by LPE (`SYS_MC_EST_GROUP` = 1): every
/// `timestamp` is 0, only `hagl` is non-zero and its "variance" is LPE's constant R
/// (0.0009 = `LPE_LDR_Z`²), with innovations whose variance is a quarter of that. No
/// `ekf2_timestamps` topic. Rows at 5 Hz, logged in time order though stamped 0.
pub fn lpe_legacy(seed: u64) -> (Vec<u8>, Truth) {
    let mut truth = Truth::new("lpe_legacy", V1_8);
    let mut r = rng(seed);
    let mut w = ULogWriter::new(T0_US - 500_000);
    w.info_str("sys_name", "PX4")
        .info_str("ver_hw", "AUTOTUNE_FIXTURE")
        .info_u32("ver_sw_release", V1_8);
    for (name, v) in [
        ("SYS_MC_EST_GROUP", Param::Int(1)),
        ("LPE_FUSION", Param::Int(145)),
    ] {
        w.param(name, v);
    }
    w.param("LPE_LDR_Z", Param::Float(0.03));
    w.param("EKF2_BARO_NOISE", Param::Float(2.0));
    truth.params.insert("SYS_MC_EST_GROUP".into(), 1.0);
    truth.params.insert("LPE_FUSION".into(), 145.0);
    truth.params.insert("LPE_LDR_Z".into(), f64::from(0.03f32));
    truth.params.insert("EKF2_BARO_NOISE".into(), 2.0);
    w.format("ekf2_innovations", LEGACY_INNOV);
    land_detected(&mut w, LAND_V111, false);
    w.log_string(us(0.1), b'6', "[lpe] fusing: lidar");
    truth.innovation_log_hz = 5.0;
    let hz = 5.0;
    let n = (DURATION_S * hz) as usize;
    for k in 0..n {
        let t = k as f64 / hz;
        let mut row = Row::default();
        row.set("timestamp", 0, 0.0)
            .set("hagl_innov", 0, 0.015 * normal(&mut r))
            .set("hagl_innov_var", 0, 0.0009);
        row.write_at(&mut w, us(t), "ekf2_innovations", 0);
    }
    truth.channels.push(ChannelTruth {
        instance: 0,
        topic: "ekf2_innovations".into(),
        field: "hagl_innov".into(),
        kind: Kind::NotEkf2,
        nis_mean: 0.015f64.powi(2) / 0.0009,
        r_factor: 1.0,
        param: None,
        param_value: None,
        true_sigma: None,
        fused: n,
        rejected: 0,
    });
    truth.rows = w.rows_written();
    (w.finish(), truth)
}

/// `estimator_status_flags` (layout `spec`) of `instance` at 1 Hz; `gps_from` is when GPS
/// fusion starts (before it, fake position when `fake_before_gps`).
fn status_flags(
    w: &mut ULogWriter,
    spec: &str,
    instance: u8,
    gps_from: f64,
    fake_before_gps: bool,
) {
    w.format("estimator_status_flags", spec);
    for k in 0..DURATION_S as usize {
        let t = k as f64 + 0.25;
        let gps = f64::from(u8::from(t >= gps_from));
        let mut s = Row::default();
        s.times(us(t), Some(us(t) - 2_000))
            .set("cs_tilt_align", 0, 1.0)
            .set("cs_yaw_align", 0, 1.0)
            .set("cs_gps", 0, gps)
            .set("cs_mag_hdg", 0, 1.0)
            .set("cs_baro_hgt", 0, 1.0)
            .set("cs_in_air", 0, f64::from(u8::from(flying(t))));
        if fake_before_gps {
            s.set("cs_fake_pos", 0, 1.0 - gps);
        }
        s.write(w, "estimator_status_flags", instance);
    }
}

/// Heading's normalised innovation of the biased fixture: `mean` plus AR(1) noise of
/// coefficient `phi`, rescaled so the written sequence has exactly that mean and a
/// variance of `var` (its sample moments, not only their expectations).
fn biased_sequence(
    r: &mut Xoshiro256PlusPlus,
    n: usize,
    mean: f64,
    var: f64,
    phi: f64,
) -> Vec<f64> {
    let mut x = Vec::with_capacity(n);
    let mut prev = normal(r) / (1.0 - phi * phi).sqrt();
    for _ in 0..n {
        prev = phi * prev + normal(r);
        x.push(prev);
    }
    let m = x.iter().sum::<f64>() / n as f64;
    let sd = (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n as f64).sqrt();
    x.iter().map(|v| mean + (v - m) / sd * var.sqrt()).collect()
}

/// (c) v1.13 layout: heading innovation = constant bias + AR(1) noise (φ = 0.98), with
/// ν/√S having mean² = 80 % of its mean square (0.3, so the NIS average is 0.3 and a naive
/// reader says "underconfident"); its raw (not demeaned) lag-1 autocorrelation is about
/// 0.8 + 0.2·ρ̂ ≈ 0.99 (ρ̂ the demeaned sample
/// autocorrelation of the AR part, about 0.97). GPS and baro consistent. Rows at 5 Hz.
pub fn biased_heading(seed: u64) -> (Vec<u8>, Truth) {
    let mut truth = Truth::new("biased_heading", V1_13);
    let mut r = rng(seed);
    let mut w = ekf2_log(&mut truth, 2, &[]);
    for t in INNOV_TOPICS {
        w.format(t, INNOV_V113);
    }
    status_flags(&mut w, STATUS_FLAGS_V113, 0, 0.0, false);
    land_detected(&mut w, LAND_V113, true);
    truth.innovation_log_hz = 5.0;
    let (share, nis, phi): (f64, f64, f64) = (0.8, 0.3, 0.98);
    let n = (DURATION_S * 5.0) as usize;
    let heading = biased_sequence(&mut r, n, (share * nis).sqrt(), (1.0 - share) * nis, phi);
    truth.heading_bias = Some((share, share + (1.0 - share) * phi, phi));
    let chans = [
        chan("gps_hvel[0]", 0.1, 5.0, 1.0, Some("EKF2_GPS_V_NOISE")),
        chan("gps_hvel[1]", 0.1, 5.0, 1.0, Some("EKF2_GPS_V_NOISE")),
        chan("gps_vvel", 0.1, 5.0, 1.0, Some("EKF2_GPS_V_NOISE")),
        chan("gps_hpos[0]", 0.27, 5.0, 1.0, Some("EKF2_GPS_P_NOISE")),
        chan("gps_hpos[1]", 0.27, 5.0, 1.0, Some("EKF2_GPS_P_NOISE")),
        chan("baro_vpos", 12.35, 5.0, 1.0, Some("EKF2_BARO_NOISE")),
        chan("heading", 0.091, 2.6, nis, Some("EKF2_HEAD_NOISE")),
    ];
    innovation_rows(
        &mut w,
        &mut truth,
        &mut r,
        0,
        5.0,
        true,
        true,
        &chans,
        Some(&heading),
    );
    truth.rows = w.rows_written();
    (w.finish(), truth)
}

/// The sensors of the Kalman-filter fixtures: (field, axis 0 N / 1 E / 2 D, measures
/// velocity, parameter).
const KF_SENSORS: [(&str, usize, bool, &str); 7] = [
    ("gps_hpos[0]", 0, false, "EKF2_GPS_P_NOISE"),
    ("gps_hvel[0]", 0, true, "EKF2_GPS_V_NOISE"),
    ("gps_hpos[1]", 1, false, "EKF2_GPS_P_NOISE"),
    ("gps_hvel[1]", 1, true, "EKF2_GPS_V_NOISE"),
    ("gps_vpos", 2, false, "EKF2_GPS_P_NOISE"),
    ("gps_vvel", 2, true, "EKF2_GPS_V_NOISE"),
    ("baro_vpos", 2, false, "EKF2_BARO_NOISE"),
];
/// True white-acceleration PSD of the Kalman-filter fixtures, m²/s³.
pub const KF_Q_TRUE: f64 = 0.1;
/// Filter step and logging period of the Kalman-filter fixtures, s.
pub const KF_DT: f64 = 0.2;

/// A real Kalman filter: three decoupled axes of [position, velocity] driven by white
/// acceleration of PSD `KF_Q_TRUE`; the filter's PSD is `q_factor` times that (and is
/// what `EKF2_ACC_NOISE`² states). Each step (`KF_DT`) fuses, one scalar at a time in
/// `KF_SENSORS` order, GPS position, GPS velocity and (down) baro; the filter's R comes
/// from the parameters written in the log, the truth's from `true_sigma` (position,
/// velocity, baro). Every fusion's ν and S is logged at 5 Hz; 10 s of filter run before
/// the first row so the logged part is in steady state.
fn kf_fixture(
    name: &'static str,
    seed: u64,
    true_sigma: [f64; 3],
    filter_sigma: [f64; 3],
    q_factor: f64,
) -> (Vec<u8>, Truth) {
    let mut truth = Truth::new(name, V1_13);
    truth.q_factor = q_factor;
    let mut r = rng(seed);
    let q_filter = KF_Q_TRUE * q_factor;
    let mut w = ekf2_log(
        &mut truth,
        2,
        &[
            ("EKF2_GPS_P_NOISE", filter_sigma[0]),
            ("EKF2_GPS_V_NOISE", filter_sigma[1]),
            ("EKF2_BARO_NOISE", filter_sigma[2]),
            ("EKF2_ACC_NOISE", q_filter.sqrt()),
        ],
    );
    for t in INNOV_TOPICS {
        w.format(t, INNOV_V113);
    }
    status_flags(&mut w, STATUS_FLAGS_V113, 0, 0.0, false);
    land_detected(&mut w, LAND_V113, true);
    truth.innovation_log_hz = 1.0 / KF_DT;
    let sigma_of = |field: &str, s: &[f64; 3]| match field {
        "baro_vpos" => s[2],
        f if f.contains("vel") => s[1],
        _ => s[0],
    };
    // The logged R is the parameter rounded to f32, as EKF2 would read it.
    let filter_sigma = filter_sigma.map(|s| f64::from(s as f32));
    let dt = KF_DT;
    let f = nalgebra::Matrix2::new(1.0, dt, 0.0, 1.0);
    let qm = |q: f64| {
        nalgebra::Matrix2::new(
            q * dt.powi(3) / 3.0,
            q * dt * dt / 2.0,
            q * dt * dt / 2.0,
            q * dt,
        )
    };
    let (q_true, q_filt) = (qm(KF_Q_TRUE), qm(q_filter));
    let l_true = q_true.cholesky().expect("Q is positive definite").l();
    let mut x = [nalgebra::Vector2::zeros(); 3];
    let mut xh = [nalgebra::Vector2::zeros(); 3];
    let mut p = [nalgebra::Matrix2::identity() * 10.0; 3];
    let burn = (10.0 / dt) as usize;
    let n = (DURATION_S / dt) as usize;
    for k in 0..burn + n {
        let t = (k as f64 - burn as f64) * dt;
        let (mut iv, mut sv, mut tr) = (Row::default(), Row::default(), Row::default());
        for a in 0..3 {
            let wv = nalgebra::Vector2::new(normal(&mut r), normal(&mut r));
            x[a] = f * x[a] + l_true * wv;
            xh[a] = f * xh[a];
            p[a] = f * p[a] * f.transpose() + q_filt;
        }
        for (field, a, vel, _) in KF_SENSORS {
            let h = if vel {
                nalgebra::RowVector2::new(0.0, 1.0)
            } else {
                nalgebra::RowVector2::new(1.0, 0.0)
            };
            let z = (h * x[a])[0] + sigma_of(field, &true_sigma) * normal(&mut r);
            let rf = sigma_of(field, &filter_sigma).powi(2);
            let s = (h * p[a] * h.transpose())[0] + rf;
            let nu = z - (h * xh[a])[0];
            let gain = p[a] * h.transpose() / s;
            xh[a] += gain * nu;
            // Joseph form keeps P symmetric and positive over thousands of steps.
            let ikh = nalgebra::Matrix2::identity() - gain * h;
            p[a] = ikh * p[a] * ikh.transpose() + gain * gain.transpose() * rf;
            let (fld, i) = split(field);
            iv.set(fld, i, nu);
            sv.set(fld, i, s);
            let ratio = nu * nu / (25.0 * s);
            let prev =
                tr.0.get(fld)
                    .and_then(|v| v.first())
                    .copied()
                    .unwrap_or(0.0);
            tr.set(fld, 0, prev.max(ratio));
        }
        if k < burn {
            continue;
        }
        let t_us = us(t);
        for (row, topic) in [
            (iv, INNOV_TOPICS[0]),
            (sv, INNOV_TOPICS[1]),
            (tr, INNOV_TOPICS[2]),
        ] {
            let mut row = row;
            row.times(t_us, Some(t_us - 3_000));
            row.write(&mut w, topic, 0);
        }
    }
    for (field, _, _, param) in KF_SENSORS {
        let ts = sigma_of(field, &true_sigma);
        let fs = sigma_of(field, &filter_sigma);
        truth.channels.push(ChannelTruth {
            instance: 0,
            topic: INNOV_TOPICS[0].into(),
            field: field.into(),
            kind: Kind::Sensor,
            nis_mean: f64::NAN,
            r_factor: (fs / ts).powi(2),
            param: Some(param),
            param_value: Some(fs),
            true_sigma: Some(ts),
            fused: n,
            rejected: 0,
        });
    }
    truth.rows = w.rows_written();
    (w.finish(), truth)
}

/// True σ of GPS position (m), GPS velocity (m/s) and baro (m) in the filter fixtures.
pub const KF_TRUE_SIGMA: [f64; 3] = [0.5, 0.3, 3.5];

/// (d) Every sensor's R is 4 times too small (the log's EKF2_*_NOISE are half the true
/// σ), Q right: the gain is too high, innovations are negatively lag-1 correlated.
pub fn all_r_too_small(seed: u64) -> (Vec<u8>, Truth) {
    kf_fixture(
        "all_r_too_small",
        seed,
        KF_TRUE_SIGMA,
        KF_TRUE_SIGMA.map(|s| s / 2.0),
        1.0,
    )
}

/// (d) The filter's Q is 25 times too small, every R right: the gain is too low,
/// innovations are positively lag-1 correlated.
pub fn all_q_too_small(seed: u64) -> (Vec<u8>, Truth) {
    kf_fixture(
        "all_q_too_small",
        seed,
        KF_TRUE_SIGMA,
        KF_TRUE_SIGMA,
        1.0 / 25.0,
    )
}

/// (d) True baro σ 2.0 m while the log's `EKF2_BARO_NOISE` is 3.5 m; everything else
/// right. A correct suggestion for `EKF2_BARO_NOISE` is about 2.0.
pub fn known_baro_noise(seed: u64) -> (Vec<u8>, Truth) {
    let t = KF_TRUE_SIGMA;
    kf_fixture("known_baro_noise", seed, [t[0], t[1], 2.0], t, 1.0)
}

/// One aid source of [`aid_src_v114`].
struct Aid {
    topic: &'static str,
    spec: &'static str,
    dim: usize,
    /// Observation variance R, per axis.
    r: f64,
    /// Innovation variance the EKF would compute (R + HPHᵀ) when right.
    s: f64,
    gate: f64,
    kind: Kind,
    param: Option<&'static str>,
}

/// Time GPS fusion starts in [`aid_src_v114`] (seconds after `T0_US`); fake position is
/// fused before it.
pub const AID_GPS_START_S: f64 = 30.0;
/// Rows of `estimator_aid_src_baro_hgt` instance 0 with a gross outlier (8 √S), all rejected.
pub const AID_BARO_OUTLIER_ROWS: [usize; 5] = [50, 120, 200, 260, 330];

/// (e) v1.14+ aid-source topics (v1.15 layout: scalar `fused`, `innovation_rejected`) for
/// two EKF instances (`multi_id` and `estimator_instance` 0, 1) at 2 Hz: baro height (1d),
/// GNSS position (2d) and velocity (3d) from [`AID_GPS_START_S`], mag heading (1d), fake
/// position (2d, rows throughout, `fused` only before GPS starts). A row is rejected (not
/// fused) when a test ratio ν²/(gate²·S) exceeds 1. Instance 1's GNSS position logs S four
/// times too small (NIS mean 4); instance 0's baro has gross outliers at
/// [`AID_BARO_OUTLIER_ROWS`]. `estimator_status_flags` (cs_fake_pos, cs_gps, ...) per
/// instance, `estimator_selector_status` with instance 0 primary.
pub fn aid_src_v114(seed: u64) -> (Vec<u8>, Truth) {
    let mut truth = Truth::new("aid_src_v114", V1_15);
    let mut r = rng(seed);
    let mut w = ekf2_log(&mut truth, 2, &[]);
    let hz = 2.0;
    truth.innovation_log_hz = hz;
    let aids = [
        Aid {
            topic: "estimator_aid_src_baro_hgt",
            spec: AID_1D,
            dim: 1,
            r: 12.25,
            s: 12.35,
            gate: 5.0,
            kind: Kind::Sensor,
            param: Some("EKF2_BARO_NOISE"),
        },
        Aid {
            topic: "estimator_aid_src_gnss_pos",
            spec: AID_2D,
            dim: 2,
            r: 0.25,
            s: 0.27,
            gate: 5.0,
            kind: Kind::Sensor,
            param: Some("EKF2_GPS_P_NOISE"),
        },
        Aid {
            topic: "estimator_aid_src_gnss_vel",
            spec: AID_3D,
            dim: 3,
            r: 0.09,
            s: 0.1,
            gate: 5.0,
            kind: Kind::Sensor,
            param: Some("EKF2_GPS_V_NOISE"),
        },
        Aid {
            topic: "estimator_aid_src_mag_heading",
            spec: AID_1D,
            dim: 1,
            r: 0.09,
            s: 0.091,
            gate: 2.6,
            kind: Kind::Sensor,
            param: Some("EKF2_HEAD_NOISE"),
        },
        Aid {
            topic: "estimator_aid_src_fake_pos",
            spec: AID_2D,
            dim: 2,
            r: 0.25,
            s: 0.2501,
            gate: 3.0,
            kind: Kind::FakeFusion,
            param: None,
        },
    ];
    for a in &aids {
        w.format(a.topic, a.spec);
    }
    land_detected(&mut w, LAND_V115, true);
    truth.events.push((
        us(AID_GPS_START_S),
        "GPS fusion starts, fake position stops".into(),
    ));
    let n = (DURATION_S * hz) as usize;
    for inst in 0..2u8 {
        status_flags(&mut w, STATUS_FLAGS_V115, inst, AID_GPS_START_S, true);
        for a in &aids {
            let gnss = a.topic.contains("gnss");
            let miscal = inst == 1 && a.topic == "estimator_aid_src_gnss_pos";
            // The logged S; the true innovation variance is a.s whatever is logged.
            let s_logged = if miscal { a.s / 4.0 } else { a.s };
            let (mut fused, mut rejected, mut rows, mut last_fuse) = (0, 0, 0, 0u64);
            for k in 0..n {
                let t = k as f64 / hz;
                if gnss && t < AID_GPS_START_S {
                    continue;
                }
                rows += 1;
                let t_us = us(t) + 5_000 * u64::from(inst);
                let active = match a.kind {
                    Kind::FakeFusion => t < AID_GPS_START_S,
                    _ => true,
                };
                let mut nu = vec![0.0; a.dim];
                let mut ratio = vec![0.0; a.dim];
                for d in 0..a.dim {
                    nu[d] = if a.kind == Kind::FakeFusion {
                        0.002 * normal(&mut r)
                    } else {
                        a.s.sqrt() * normal(&mut r)
                    };
                    if inst == 0
                        && a.topic.ends_with("baro_hgt")
                        && AID_BARO_OUTLIER_ROWS.contains(&k)
                    {
                        nu[d] = 8.0 * a.s.sqrt();
                    }
                    ratio[d] = nu[d] * nu[d] / (a.gate * a.gate * s_logged);
                }
                let reject = active && ratio.iter().any(|x| *x > 1.0);
                let is_fused = active && !reject;
                fused += usize::from(is_fused);
                rejected += usize::from(reject);
                if is_fused {
                    last_fuse = t_us;
                }
                let mut row = Row::default();
                row.times(t_us, Some(t_us - 4_000))
                    .set("time_last_fuse", 0, last_fuse as f64)
                    .set("device_id", 0, 6_620_172.0)
                    .set("estimator_instance", 0, f64::from(inst))
                    .set("innovation_rejected", 0, f64::from(u8::from(reject)))
                    .set("fused", 0, f64::from(u8::from(is_fused)));
                for d in 0..a.dim {
                    row.set("observation", d, 10.0 * d as f64 + nu[d])
                        .set("observation_variance", d, a.r)
                        .set("innovation", d, nu[d])
                        .set("innovation_variance", d, s_logged)
                        .set("test_ratio", d, ratio[d]);
                }
                row.write(&mut w, a.topic, inst);
            }
            let _ = rows;
            for d in 0..a.dim {
                truth.channels.push(ChannelTruth {
                    instance: inst,
                    topic: a.topic.into(),
                    field: if a.dim == 1 {
                        "innovation".into()
                    } else {
                        format!("innovation[{d}]")
                    },
                    kind: a.kind,
                    nis_mean: match a.kind {
                        Kind::FakeFusion => 0.002f64.powi(2) / a.s,
                        _ => a.s / s_logged,
                    },
                    r_factor: 1.0,
                    param: a.param,
                    param_value: a.param.and_then(|p| truth.params.get(p).copied()),
                    true_sigma: None,
                    fused,
                    rejected,
                });
            }
        }
    }
    w.format("estimator_selector_status", SELECTOR_V113);
    for k in 0..DURATION_S as usize {
        let mut s = Row::default();
        s.times(us(k as f64 + 0.75), None)
            .set("primary_instance", 0, 0.0)
            .set("instances_available", 0, 2.0)
            .set("healthy", 0, 1.0)
            .set("healthy", 1, 1.0);
        s.write(&mut w, "estimator_selector_status", 0);
    }
    truth.primary.push((us(0.75), 0));
    truth.rows = w.rows_written();
    (w.finish(), truth)
}

/// When [`primary_switch`]'s primary instance changes from 0 to 1, seconds after `T0_US`.
pub const PRIMARY_SWITCH_S: f64 = 120.0;

/// (f) Two EKF2 instances (v1.13 `estimator_innovations` / `_variances`, `multi_id` 0 and
/// 1, both consistent, 2 Hz) and `estimator_selector_status` whose `primary_instance`
/// switches 0 → 1 at [`PRIMARY_SWITCH_S`] (a row at the switch, 1 Hz otherwise).
pub fn primary_switch(seed: u64) -> (Vec<u8>, Truth) {
    let mut truth = Truth::new("primary_switch", V1_13);
    let mut r = rng(seed);
    let mut w = ekf2_log(&mut truth, 2, &[]);
    for t in &INNOV_TOPICS[..2] {
        w.format(t, INNOV_V113);
    }
    land_detected(&mut w, LAND_V113, true);
    truth.innovation_log_hz = 2.0;
    let chans = [
        chan("gps_hvel[0]", 0.1, 5.0, 1.0, Some("EKF2_GPS_V_NOISE")),
        chan("gps_hvel[1]", 0.1, 5.0, 1.0, Some("EKF2_GPS_V_NOISE")),
        chan("gps_hpos[0]", 0.27, 5.0, 1.0, Some("EKF2_GPS_P_NOISE")),
        chan("gps_hpos[1]", 0.27, 5.0, 1.0, Some("EKF2_GPS_P_NOISE")),
        chan("baro_vpos", 12.35, 5.0, 1.0, Some("EKF2_BARO_NOISE")),
        chan("heading", 0.091, 2.6, 1.0, Some("EKF2_HEAD_NOISE")),
    ];
    for inst in 0..2 {
        status_flags(&mut w, STATUS_FLAGS_V113, inst, 0.0, false);
        innovation_rows(
            &mut w, &mut truth, &mut r, inst, 2.0, true, false, &chans, None,
        );
    }
    // A parameter changed in flight (the selector's error threshold; no channel's R).
    let change_us = us(PRIMARY_SWITCH_S - 10.0);
    w.param_change(change_us, "EKF2_SEL_ERR_RED", Param::Float(0.1));
    truth
        .param_changes
        .push((change_us, "EKF2_SEL_ERR_RED".into(), f64::from(0.1f32)));
    w.format("estimator_selector_status", SELECTOR_V113);
    let mut times: Vec<f64> = (0..DURATION_S as usize).map(|k| k as f64 + 0.75).collect();
    times.push(PRIMARY_SWITCH_S);
    times.sort_by(f64::total_cmp);
    for t in times {
        let switched = t >= PRIMARY_SWITCH_S;
        let mut s = Row::default();
        s.times(us(t), None)
            .set(
                "last_instance_change",
                0,
                if switched {
                    us(PRIMARY_SWITCH_S) as f64
                } else {
                    0.0
                },
            )
            .set("instance_changed_count", 0, f64::from(u8::from(switched)))
            .set("primary_instance", 0, f64::from(u8::from(switched)))
            .set("instances_available", 0, 2.0)
            .set("healthy", 0, 1.0)
            .set("healthy", 1, 1.0);
        s.write(&mut w, "estimator_selector_status", 0);
    }
    truth.primary = vec![(us(0.75), 0), (us(PRIMARY_SWITCH_S), 1)];
    truth
        .events
        .push((us(PRIMARY_SWITCH_S), "primary EKF instance 0 -> 1".into()));
    truth.rows = w.rows_written();
    (w.finish(), truth)
}
