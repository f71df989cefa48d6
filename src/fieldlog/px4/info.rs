//! What the PX4 reader learns about a log's estimators besides the innovations: who
//! published them, which aiding sources were active when, which instance was primary, the
//! EKF's own test ratios and rejections, and the EKF2 parameters the log recorded.

use std::collections::BTreeMap;

use serde::Serialize;

/// The estimator side of a PX4 log.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Px4Info {
    /// PX4 release from the `ver_sw_release` info field, e.g. `v1.11.3` (None when absent).
    pub version: Option<String>,
    /// Which estimator published the innovation topics, e.g. `EKF2`.
    pub publisher: String,
    /// How that is known, one line (a parameter's value, the topics present).
    pub publisher_evidence: String,
    /// The log's own time origin: the ULog header's timestamp, µs since boot. Every time in
    /// the report is seconds after it.
    pub time_origin_us: u64,
    /// Estimator parameters as the log recorded them at its start (`EKF2_*`, `SYS_*EST*`),
    /// name → value.
    pub params: BTreeMap<String, f64>,
    /// Parameters changed during the log: (time s, name, new value).
    pub param_changes: Vec<(f64, String, f64)>,
    /// The estimator instances whose innovations were read.
    pub instances: Vec<Px4Instance>,
    /// Takeoffs, landings, aiding sources starting and stopping, primary switches, in time
    /// order.
    pub events: Vec<Px4Event>,
    /// Channels the log carries that were read but not judged, and why.
    pub not_judged: Vec<NotJudged>,
    /// What the EKF itself says about each judged channel.
    pub channels: Vec<Px4Channel>,
    /// What the rows themselves put in doubt (innovations of exactly 0 beside a positive
    /// variance, ...), one line each; the report lists them with its own warnings.
    pub warnings: Vec<String>,
}

/// One estimator instance of the log.
#[derive(Debug, Clone, Serialize)]
pub struct Px4Instance {
    /// Instance number (the topics' multi_id), as in `ekf0`.
    pub index: u8,
    /// The topics its innovations came from.
    pub topics: String,
    /// Rows of its innovation topics read.
    pub rows: usize,
    /// How often the innovation topic was logged, rows per second.
    pub logged_hz: f64,
    /// Seconds it was the primary instance (`estimator_selector_status`; None when the log
    /// does not say).
    pub primary_s: Option<f64>,
}

/// Something that happened during the log, for the report's time axis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Px4Event {
    /// Seconds after the log's time origin.
    pub time: f64,
    /// What, in words ("takeoff", "landing", "ekf0: GPS on", "primary: ekf1").
    pub what: String,
    /// The kind, for the plots' markers.
    pub kind: EventKind,
}

/// The kinds of [`Px4Event`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// The land detector says airborne.
    Takeoff,
    /// The land detector says landed.
    Landing,
    /// An aiding source starts or stops being fused.
    Aiding,
    /// Another estimator instance becomes primary.
    Primary,
}

/// A channel the reader did not judge.
#[derive(Debug, Clone, Serialize)]
pub struct NotJudged {
    /// Channel name as a judged one would be (`ekf0.gps_hpos[0]`).
    pub name: String,
    /// Why, one line (e.g. "fake-position fusion: no horizontal aiding source was active").
    pub reason: String,
    /// Rows it had updates on.
    pub updates: usize,
}

/// What the EKF reports about one judged channel beside its innovations.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Px4Channel {
    /// The sensor's name in the report (`ekf0.baro_vpos`).
    pub name: String,
    /// The aiding source, in words ("barometric height", "GPS horizontal position").
    pub source: String,
    /// Seconds the source was active over the log (None: the log has no status flags).
    pub active_s: Option<f64>,
    /// Updates dropped because the source was not active at their time.
    pub inactive: usize,
    /// Updates dropped as fake-position fusion (no horizontal aiding at their time).
    pub fake: usize,
    /// Gravity updates set aside because the vehicle was at rest (on the ground, or EKF2's
    /// `vehicle_at_rest`): there the accelerometer measures gravity alone.
    pub at_rest: usize,
    /// The EKF's own test ratio `ν²/(gate² S)`, averaged over the judged updates.
    pub test_ratio_mean: Option<f64>,
    /// The innovation gate the test ratios imply, `√(ν²/(S · ratio))` (median), in σ.
    pub gate: Option<f64>,
    /// Judged updates the EKF rejected (test ratio > 1, or `innovation_rejected`).
    pub rejected: Option<usize>,
    /// Judged updates per second of active time.
    pub update_hz: f64,
    /// How often the source's own data were logged, per second (None: not in the log).
    pub source_hz: Option<f64>,
    /// The judged updates are samples of the fusions (the topic is logged more slowly than
    /// the source is fused), not every fusion.
    pub sampled: bool,
    /// Mean innovation variance S over the judged updates, in the measurement's units².
    pub mean_s: f64,
    /// Mean observation variance R the EKF used (the aid-source topics log it), units².
    pub mean_r: Option<f64>,
    /// The EKF2 parameter setting this channel's measurement noise, when known.
    pub noise_param: Option<String>,
    /// The measurement's unit (that parameter's), e.g. `m`.
    pub unit: Option<String>,
}
