//! One channel's rows: sorted into updates and the reasons the others are set aside, then
//! judged (pushed into the analyzer with what EKF2 says beside them) or listed as not judged
//! with the reason.
//!
//! Besides idle, invalid and repeated rows, three kinds of row are not a draw of `N(0, S)`:
//! - an innovation of exactly 0 beside a variance `S > 0`: a continuous draw is never exactly
//!   0, so the row is a placeholder or a pseudo-measurement (a real v1.15 log holds baro at
//!   −0 for ten rows in flight while its test ratio is not 0; a v1.13 log's heading is 0 on
//!   23 rows); set aside and warned about;
//! - the vertical component of the gravity innovation: EKF2 fuses the direction of the
//!   measured specific force as a unit vector, and the difference of two unit vectors has a
//!   vertical part of second order in the tilt error (`ν_z ≈ −(ν_x² + ν_y²)/2`), so its NIS
//!   is near 0 whatever the tuning; never judged;
//! - the horizontal gravity components at rest: there the specific force is gravity alone,
//!   while `EKF2_GRAV_NOISE` is sized to cover the vehicle's own accelerations in flight
//!   without horizontal aiding (EKF2 fuses gravity only then); a NIS far below 1 at rest says
//!   nothing about it, so those updates are set aside and, when they are all a channel has,
//!   it is not judged.

use std::path::Path;

use super::context::{Ctx, in_air};
use super::estimator::{self, Flags, Source, Status};
use super::read::per_second;
use super::{NotJudged, Px4Channel, Px4Info, ekf2};
use crate::fieldlog::analysis::{Dropped, NisAnalyzer, SensorInfo, Update};
use crate::input::FileError;

/// Updates with one bit-identical variance beyond which the "variance" is a constant R,
/// not an innovation variance, in a log whose publisher is not confirmed. (EKF2's S moves
/// with P, but not always in float32: a real v1.15 log's gravity[2] variance is exactly 1
/// on every row, so a log known to be EKF2's is not held to this.)
const CONSTANT_VARIANCE_UPDATES: usize = 20;

/// One row of a channel, as the layouts give it.
pub(super) struct Row {
    pub time: u64,
    pub nu: f64,
    pub s: f64,
    /// The variance is from this row's filter cycle (a repeat needs both values equal).
    pub exact: bool,
    pub test_ratio: Option<f64>,
    /// Aid-source topics: (fused, rejected).
    pub fused: Option<(bool, bool)>,
    pub obs_var: Option<f64>,
}

/// What a channel measures, where that changes how its NIS reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Shape {
    /// A measurement whose innovation is a draw of `N(0, S)` when the filter is right.
    Plain,
    /// A horizontal component of the gravity (unit specific force) innovation.
    GravityTilt,
    /// The vertical component of the gravity innovation: second order in the tilt error.
    GravityVertical,
}

impl Shape {
    /// The shape of channel `base` (the name without its index), component `idx`.
    pub fn of(base: &str, idx: Option<usize>) -> Shape {
        match (base, idx) {
            ("gravity", Some(2)) => Shape::GravityVertical,
            ("gravity", _) => Shape::GravityTilt,
            _ => Shape::Plain,
        }
    }
}

/// How one channel's rows were sorted.
#[derive(Default)]
pub(super) struct Sorted {
    pub dropped: Dropped,
    pub updates: Vec<Update>,
    pub fake: usize,
    pub inactive: usize,
    /// Gravity updates at rest (on the ground, or EKF2's `vehicle_at_rest`).
    pub at_rest: usize,
    /// Repeats at times its updates would have been judged: a channel that repeats there
    /// is logged at least as fast as it is fused.
    pub judged_repeats: usize,
    /// Mean variance of the rows with an innovation of exactly 0.
    pub zero_s_sum: f64,
    /// The control-status flags set on every judged update (None: no flags in the log).
    pub flags_all: Option<u64>,
    pub ratios: Vec<f64>,
    pub gates: Vec<f64>,
    pub rejected: usize,
    pub obs_vars: Vec<f64>,
    pub s_sum: f64,
    /// Updates whose variance equals the first update's bit for bit.
    pub same_variance: usize,
    pub first_variance: Option<u64>,
}

/// Where a row that is neither idle, invalid, a placeholder nor a repeat goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Place {
    Fake,
    OnGround,
    Inactive,
    AtRest,
    Judged,
}

/// Where a row at `t` goes by EKF2's flags, the land detector and the channel's shape. With
/// `--in-air` the ground is set aside before the flags are read: what happened there is
/// not examined.
fn place(ctx: &Ctx, t: u64, source: &Source, flags: Option<&Flags>, shape: Shape) -> Place {
    let now = flags.and_then(|f| f.at(t));
    let status = match flags {
        None => Status::Unknown,
        Some(f) => estimator::judged_under(source, now, f.has_fake),
    };
    let landed = !ctx.land.is_empty() && !in_air(&ctx.land, t);
    if status == Status::Fake {
        Place::Fake
    } else if ctx.options.in_air && !in_air(&ctx.land, t) {
        Place::OnGround
    } else if status == Status::Inactive || (status == Status::Unknown && flags.is_some()) {
        Place::Inactive
    } else if shape == Shape::GravityTilt
        && (landed || now.is_some_and(|f| estimator::has(f, "vehicle_at_rest")))
    {
        Place::AtRest
    } else {
        Place::Judged
    }
}

/// Sort a channel's rows into updates and the reasons the others were dropped.
pub(super) fn sort_rows(
    ctx: &Ctx,
    rows: &[Row],
    source: &Source,
    flags: Option<&Flags>,
    shape: Shape,
) -> Sorted {
    let mut out = Sorted::default();
    let mut prev: Option<(u64, u64)> = None;
    for row in rows {
        let bits = (row.nu.to_bits(), row.s.to_bits());
        let last = prev.replace(bits);
        let repeat = row.fused.is_none()
            && last.is_some_and(|(n, v)| n == bits.0 && (v == bits.1 || !row.exact));
        if row.fused == Some((false, false)) || (row.nu == 0.0 && row.s == 0.0) {
            out.dropped.idle += 1;
        } else if !row.nu.is_finite() || !row.s.is_finite() || row.s <= 0.0 {
            out.dropped.invalid += 1;
        } else if row.nu == 0.0 {
            out.dropped.zero_innovation += 1;
            out.zero_s_sum += row.s;
        } else if repeat {
            out.dropped.repeats += 1;
            if place(ctx, row.time, source, flags, shape) == Place::Judged {
                out.judged_repeats += 1;
            }
        } else {
            match place(ctx, row.time, source, flags, shape) {
                Place::Fake => out.fake += 1,
                Place::OnGround => out.dropped.on_ground += 1,
                Place::Inactive => out.inactive += 1,
                Place::AtRest => out.at_rest += 1,
                Place::Judged => {
                    if let Some(f) = flags.and_then(|f| f.at(row.time)) {
                        out.flags_all = Some(out.flags_all.map_or(f, |a| a & f));
                    }
                    push_update(ctx, row, &mut out);
                }
            }
        }
    }
    out
}

/// A judged update, with what EKF2 logged beside it.
fn push_update(ctx: &Ctx, row: &Row, out: &mut Sorted) {
    if let Some(r) = row.test_ratio.filter(|r| r.is_finite() && *r >= 0.0) {
        out.ratios.push(r);
        if r > 0.0 {
            out.gates.push((row.nu * row.nu / (row.s * r)).sqrt());
        }
        if row.fused.is_none() && r > 1.0 {
            out.rejected += 1;
        }
    }
    if let Some((_, true)) = row.fused {
        out.rejected += 1;
    }
    if let Some(v) = row.obs_var.filter(|v| v.is_finite() && *v > 0.0) {
        out.obs_vars.push(v);
    }
    let first = *out.first_variance.get_or_insert(row.s.to_bits());
    if first == row.s.to_bits() {
        out.same_variance += 1;
    }
    out.s_sum += row.s;
    out.updates.push(Update {
        time: ctx.secs(row.time),
        nis: row.nu * row.nu / row.s,
        dof: 1,
        u: Some(vec![row.nu / row.s.sqrt()]),
        sd: Some(vec![row.s.sqrt()]),
    });
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// One channel to judge: its instance, name (`gps_hpos[1]`), base name (`gps_hpos`), source
/// and the rate its topic was logged at.
pub(super) struct ChannelId<'a> {
    pub inst: u8,
    pub name: &'a str,
    pub base: &'a str,
    pub source: &'a Source,
    pub shape: Shape,
    pub logged_hz: f64,
}

/// Push one channel's sorted rows into the analyzer (or note why it is not judged).
pub(super) fn judge_channel(
    ctx: &Ctx,
    path: &Path,
    an: &mut NisAnalyzer,
    info: &mut Px4Info,
    id: &ChannelId,
    mut sorted: Sorted,
) -> Result<(), FileError> {
    let full = format!("ekf{}.{}", id.inst, id.name);
    let n = sorted.updates.len();
    if let Some(w) = zero_warning(&full, &sorted) {
        info.warnings.push(w);
    }
    if let Some((reason, updates)) = not_judged(ctx, &sorted, id) {
        info.not_judged.push(NotJudged {
            name: full,
            reason,
            updates,
        });
        return Ok(());
    }
    let i = an
        .sensor(SensorInfo {
            name: full.clone(),
            components: vec![full.clone()],
            group: format!("ekf{}", id.inst),
        })
        .map_err(|e| FileError::new(path, "", e.to_string()))?;
    let (first, last) = (
        sorted.updates.first().map(|u| u.time),
        sorted.updates.last().map(|u| u.time),
    );
    for up in std::mem::take(&mut sorted.updates) {
        an.push(i, up)
            .map_err(|e| FileError::new(path, "", e.to_string()))?;
    }
    an.drop_rows(i, sorted.dropped);
    let span = match (first, last) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    let update_hz = per_second(n, span).unwrap_or(0.0);
    info.channels
        .push(channel_view(ctx, id, full, &mut sorted, n, update_hz));
    Ok(())
}

/// What EKF2 says beside a judged channel's updates.
fn channel_view(
    ctx: &Ctx,
    id: &ChannelId,
    full: String,
    sorted: &mut Sorted,
    n: usize,
    update_hz: f64,
) -> Px4Channel {
    let source_hz = estimator::rate_key(id.base).and_then(|k| ctx.rates.get(k).copied());
    // Judged updates, the topic logged more slowly than the source's own data come, and
    // (almost) no repeat where updates were judged: each logged row is the latest of
    // several fusions. A channel with no judged update was sampled of nothing.
    let sampled = n > 0
        && source_hz.is_some_and(|s| id.logged_hz > 0.0 && id.logged_hz < 0.9 * s)
        && sorted.judged_repeats * 20 <= n;
    let fused = ekf2::fused_source(id.source, sorted.flags_all, &ctx.read.params);
    let param = ekf2::noise_param(id.name, fused);
    // EKF2 logs one test ratio for a horizontal pair, in its first element: a channel whose
    // ratios are all exactly 0 has none of its own.
    if sorted.ratios.iter().all(|r| *r == 0.0) {
        sorted.ratios.clear();
        sorted.gates.clear();
    }
    let ratios = &sorted.ratios;
    Px4Channel {
        name: full,
        source: words_of(id.source).to_string(),
        active_s: None,
        inactive: sorted.inactive,
        fake: sorted.fake,
        at_rest: sorted.at_rest,
        test_ratio_mean: (!ratios.is_empty())
            .then(|| ratios.iter().sum::<f64>() / ratios.len() as f64),
        gate: median(&mut sorted.gates),
        rejected: (!ratios.is_empty() || sorted.rejected > 0).then_some(sorted.rejected),
        update_hz,
        source_hz,
        sampled,
        mean_s: if n > 0 {
            sorted.s_sum / n as f64
        } else {
            f64::NAN
        },
        mean_r: (!sorted.obs_vars.is_empty())
            .then(|| sorted.obs_vars.iter().sum::<f64>() / sorted.obs_vars.len() as f64),
        noise_param: param.map(|(p, _)| p.to_string()),
        unit: param.map(|(_, u)| u.to_string()),
    }
}

/// The warning for rows whose innovation is exactly 0 beside a positive variance.
fn zero_warning(name: &str, sorted: &Sorted) -> Option<String> {
    let k = sorted.dropped.zero_innovation;
    (k > 0).then(|| {
        format!(
            "{name}: {k} row{} an innovation of exactly 0 beside a variance S > 0 (mean S {}): no draw of N(0, S) is exactly 0, so {} not a sensor's measurement (a placeholder, or a zero innovation EKF2 fuses to hold a state) and not judged",
            if k == 1 { " has" } else { "s have" },
            ekf2::sig3(sorted.zero_s_sum / k as f64),
            if k == 1 { "it is" } else { "they are" },
        )
    })
}

/// Why a channel's rows are not judged, and how many updates that leaves out: the vertical
/// gravity component, only fake-position fusions, a source never active, gravity only at
/// rest, or (where EKF2 is only assumed) a variance that never moves.
fn not_judged(ctx: &Ctx, sorted: &Sorted, id: &ChannelId) -> Option<(String, usize)> {
    let n = sorted.updates.len();
    if id.shape == Shape::GravityVertical && n + sorted.at_rest > 0 {
        return Some((
            "the vertical component of the gravity innovation (a difference of unit vectors) is second order in the tilt error, ν_z ≈ −(ν_x² + ν_y²)/2: not a draw of N(0, S), whatever the tuning".into(),
            n + sorted.at_rest,
        ));
    }
    if n == 0 && sorted.fake > 0 {
        return Some((
            "fake-position fusion: EKF2 had no horizontal aiding source, so these innovations are the filter's own, not a sensor's".into(),
            sorted.fake,
        ));
    }
    if n == 0 && sorted.at_rest > 0 {
        return Some((
            "every update came at rest (on the ground or EKF2's vehicle_at_rest), where the accelerometer measures gravity alone; EKF2_GRAV_NOISE is sized for the vehicle's own accelerations in flight without horizontal aiding, so these updates say nothing about it: no advice".into(),
            sorted.at_rest,
        ));
    }
    if n == 0 && sorted.inactive > 0 && sorted.dropped.on_ground == 0 {
        return Some((
            format!(
                "its source ({}) was never active by EKF2's status flags while it updated",
                words_of(id.source)
            ),
            sorted.inactive,
        ));
    }
    if ctx.publisher_assumed && n >= CONSTANT_VARIANCE_UPDATES && sorted.same_variance == n {
        return Some((
            format!(
                "its variance is the same {} on all {n} updates: that is a fixed R, not an innovation variance S (which moves with the filter's covariance)",
                f64::from_bits(sorted.first_variance.unwrap_or(0))
            ),
            n,
        ));
    }
    None
}

pub(super) fn words_of(source: &Source) -> &'static str {
    match source {
        Source::Sensor { words, .. } | Source::HorizontalPosition { words, .. } => words,
        Source::Always(w) => w,
    }
}
