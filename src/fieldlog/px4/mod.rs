//! PX4 ULog flight logs: the EKF2 innovations and their variances, per estimator instance,
//! judged only over what EKF2 really fused from a sensor.
//!
//! Three layouts carry the innovations. Since v1.14 each aiding source has its own topic
//! (`estimator_aid_src_*`: innovation, innovation variance, test ratio, observation variance
//! and whether the sample was `fused` or `innovation_rejected`); these are preferred where
//! present, and a row is an update when it was fused or rejected (a rejected innovation is
//! still a draw of the innovation distribution; the rejections are counted). Before, one
//! message layout per estimator instance (`estimator_innovations` beside
//! `estimator_innovation_variances` and `estimator_innovation_test_ratios`); before v1.11,
//! one topic `ekf2_innovations` with `<name>_innov` beside `<name>_innov_var`. No
//! cross-covariances are logged, so each array element is its own channel with a
//! one-degree-of-freedom NIS `ν²/S`.
//!
//! In the older layouts a logged row is a publication, not a fusion: a channel not fused
//! since the last row repeats its values, and one never fused sits at zero. So per channel,
//! in row order: a row with innovation and variance both 0 is idle; a non-finite value or a
//! variance ≤ 0 is invalid; a row whose (innovation, variance) are bit-identical to the
//! previous row's is a repeat; anything else is an update. The logger may sample the
//! innovations and variances at different cycles: each innovations row is paired with the
//! variances row of the same time (`timestamp_sample`, or `timestamp` in releases without
//! it), or else the nearest within 50 ms (noted as approximate); such a row's variance is
//! from another filter cycle, so for it the innovation alone decides whether it repeats.
//!
//! An update is then judged only while its aiding source was active by EKF2's own
//! control-status flags ([`estimator`]): a horizontal-position channel with no horizontal
//! aiding is EKF2's fake-position fusion and is reported as such, never judged. The
//! publisher is checked first: another estimator's "innovation variance" is not S.
//!
//! The file is read by [`super::ulog_walk`], which checks each message before the crate's
//! parser sees it (some damaged files panic or run away inside the crate).

mod aid_src;
mod annotate;
mod ekf2;
mod estimator;
mod info;
mod read;

pub(super) use annotate::annotate;
pub use ekf2::ParamAdvice;
pub use info::{EventKind, NotJudged, Px4Channel, Px4Event, Px4Info, Px4Instance};

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use super::analysis::{Dropped, NisAnalyzer, SensorInfo, Update};
use super::ulog_walk::Ending;
use super::{LogSource, ReadOptions};
use crate::input::FileError;
use estimator::{Flags, Source, Status};
use read::{AID_SRC, INNOVATIONS, LAND, LEGACY, Read, SELECTOR, TEST_RATIOS, Topic, VARIANCES};

/// Largest gap between an innovations row and the variances row it is paired with, µs.
const PAIR_WITHIN_US: u64 = 50_000;
/// Updates with one bit-identical variance beyond which the "variance" is a constant R,
/// not an innovation variance, in a log whose publisher is not confirmed. (EKF2's S moves
/// with P, but not always in float32: a real v1.15 log's gravity[2] variance is exactly 1
/// on every row, so a log known to be EKF2's is not held to this.)
const CONSTANT_VARIANCE_UPDATES: usize = 20;

/// Whether the vehicle is in the air at `t` (µs): the latest land-detector row at or
/// before `t` says not landed; before the first row, on the ground.
fn in_air(land: &[(u64, bool)], t: u64) -> bool {
    let i = land.partition_point(|r| r.0 <= t);
    i > 0 && !land[i - 1].1
}

/// One channel of the older layouts: its name, the column of its innovation and of its
/// variance, and its base name and index.
struct Channel {
    name: String,
    innov: usize,
    var: usize,
    base: String,
    idx: Option<usize>,
}

/// The column of each name (the first, should a name repeat).
fn columns(names: &[String]) -> HashMap<&str, usize> {
    let mut at = HashMap::with_capacity(names.len());
    for (i, n) in names.iter().enumerate() {
        at.entry(n.as_str()).or_insert(i);
    }
    at
}

/// `gps_hpos[1]` → (`gps_hpos`, Some(1)).
fn split_index(name: &str) -> (String, Option<usize>) {
    match name.find('[') {
        Some(p) => (
            name[..p].to_string(),
            name[p + 1..].trim_end_matches(']').parse().ok(),
        ),
        None => (name.to_string(), None),
    }
}

/// Channels of the legacy topic: `<base>_innov[j]` beside `<base>_innov_var[j]`.
fn legacy_channels(names: &[String]) -> Vec<Channel> {
    let at = columns(names);
    let mut out = Vec::new();
    for (i, n) in names.iter().enumerate() {
        let (stem, idx) = match n.find('[') {
            Some(p) => (&n[..p], &n[p..]),
            None => (n.as_str(), ""),
        };
        let Some(base) = stem.strip_suffix("_innov") else {
            continue;
        };
        let var_name = format!("{stem}_var{idx}");
        if let Some(&v) = at.get(var_name.as_str()) {
            let name = format!("{base}{idx}");
            let (base, idx) = split_index(&name);
            out.push(Channel {
                name,
                innov: i,
                var: v,
                base,
                idx,
            });
        }
    }
    out
}

/// For each row time of `innov`, the index of the row of `var` (exact time, or the nearest
/// within 50 ms, the earlier on a tie) and whether it was exact.
fn pair(innov: &[u64], var: &[u64]) -> Vec<Option<(usize, bool)>> {
    let mut exact: HashMap<u64, usize> = HashMap::new();
    for (j, &t) in var.iter().enumerate() {
        exact.entry(t).or_insert(j);
    }
    let mut order: Vec<usize> = (0..var.len()).collect();
    order.sort_by_key(|&j| (var[j], j));
    innov
        .iter()
        .map(|&t| {
            if let Some(&j) = exact.get(&t) {
                return Some((j, true));
            }
            let p = order.partition_point(|&j| var[j] < t);
            let before = p.checked_sub(1).map(|q| order[q]);
            let after = order.get(p).copied();
            let best = match (before, after) {
                (Some(b), Some(a)) => {
                    if t - var[b] <= var[a] - t {
                        Some(b)
                    } else {
                        Some(a)
                    }
                }
                (b, a) => b.or(a),
            }?;
            (var[best].abs_diff(t) <= PAIR_WITHIN_US).then_some((best, false))
        })
        .collect()
}

/// One row of a channel, as the layouts give it.
struct Row {
    time: u64,
    nu: f64,
    s: f64,
    /// The variance is from this row's filter cycle (a repeat needs both values equal).
    exact: bool,
    test_ratio: Option<f64>,
    /// Aid-source topics: (fused, rejected).
    fused: Option<(bool, bool)>,
    obs_var: Option<f64>,
}

/// What the reader knows while it reads one log.
struct Ctx<'a> {
    read: &'a Read,
    options: &'a ReadOptions,
    land: Vec<(u64, bool)>,
    origin: u64,
    rates: BTreeMap<&'static str, f64>,
    /// No parameter or topic confirms that EKF2 published the innovations.
    publisher_assumed: bool,
}

impl Ctx<'_> {
    fn secs(&self, t: u64) -> f64 {
        (t as f64 - self.origin as f64) * 1e-6
    }
}

/// How one channel's rows were sorted.
#[derive(Default)]
struct Sorted {
    dropped: Dropped,
    updates: Vec<Update>,
    fake: usize,
    inactive: usize,
    ratios: Vec<f64>,
    gates: Vec<f64>,
    rejected: usize,
    obs_vars: Vec<f64>,
    s_sum: f64,
    /// Updates whose variance equals the first update's bit for bit.
    same_variance: usize,
    first_variance: Option<u64>,
}

/// Sort a channel's rows into updates and the reasons the others were dropped.
fn sort_rows(ctx: &Ctx, rows: &[Row], source: &Source, flags: Option<&Flags>) -> Sorted {
    let mut out = Sorted::default();
    let mut prev: Option<(u64, u64)> = None;
    for row in rows {
        let bits = (row.nu.to_bits(), row.s.to_bits());
        let last = prev.replace(bits);
        let repeat = row.fused.is_none()
            && last.is_some_and(|(n, v)| n == bits.0 && (v == bits.1 || !row.exact));
        let status = match flags {
            None => Status::Unknown,
            Some(f) => estimator::judged_under(source, f.at(row.time), f.has_fake),
        };
        if row.fused == Some((false, false)) || (row.nu == 0.0 && row.s == 0.0) {
            out.dropped.idle += 1;
        } else if !row.nu.is_finite() || !row.s.is_finite() || row.s <= 0.0 {
            out.dropped.invalid += 1;
        } else if repeat {
            out.dropped.repeats += 1;
        } else if status == Status::Fake {
            out.fake += 1;
        } else if matches!(status, Status::Inactive)
            || (status == Status::Unknown && flags.is_some())
        {
            out.inactive += 1;
        } else if ctx.options.in_air && !in_air(&ctx.land, row.time) {
            out.dropped.on_ground += 1;
        } else {
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
    }
    out
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// Push one channel's sorted rows into the analyzer (or note why it is not judged).
#[allow(clippy::too_many_arguments)]
fn judge_channel(
    ctx: &Ctx,
    path: &Path,
    an: &mut NisAnalyzer,
    info: &mut Px4Info,
    inst: u8,
    name: &str,
    base: &str,
    source: &Source,
    logged_hz: f64,
    mut sorted: Sorted,
) -> Result<(), FileError> {
    let full = format!("ekf{inst}.{name}");
    let n = sorted.updates.len();
    if let Some((reason, updates)) = not_judged(ctx, &sorted, source) {
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
            group: format!("ekf{inst}"),
        })
        .map_err(|e| FileError::new(path, "", e.to_string()))?;
    let (first, last) = (
        sorted.updates.first().map(|u| u.time),
        sorted.updates.last().map(|u| u.time),
    );
    let repeats = sorted.dropped.repeats;
    for up in std::mem::take(&mut sorted.updates) {
        an.push(i, up)
            .map_err(|e| FileError::new(path, "", e.to_string()))?;
    }
    an.drop_rows(i, sorted.dropped);
    let span = match (first, last) {
        (Some(a), Some(b)) if b > a => b - a,
        _ => 0.0,
    };
    let update_hz = if span > 0.0 {
        (n.saturating_sub(1)) as f64 / span
    } else {
        0.0
    };
    let source_hz = estimator::rate_key(base).and_then(|k| ctx.rates.get(k).copied());
    // Every logged row a new value while the source's own data come faster: the rows are
    // samples of the fusions, not each fusion.
    let sampled =
        source_hz.is_some_and(|s| logged_hz > 0.0 && logged_hz < 0.9 * s) && repeats * 20 <= n;
    let heading_source = None;
    let param = ekf2::noise_param(base, heading_source);
    // EKF2 logs one test ratio for a horizontal pair, in its first element: a channel whose
    // ratios are all exactly 0 has none of its own.
    if sorted.ratios.iter().all(|r| *r == 0.0) {
        sorted.ratios.clear();
        sorted.gates.clear();
    }
    let ratios = &sorted.ratios;
    info.channels.push(Px4Channel {
        name: full,
        source: words_of(source).to_string(),
        active_s: None,
        inactive: sorted.inactive,
        fake: sorted.fake,
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
    });
    Ok(())
}

/// Why a channel's rows are not judged, and how many updates that leaves out: only
/// fake-position fusions, a source never active, or (where EKF2 is only assumed) a variance
/// that never moves.
fn not_judged(ctx: &Ctx, sorted: &Sorted, source: &Source) -> Option<(String, usize)> {
    let n = sorted.updates.len();
    if n == 0 && sorted.fake > 0 {
        return Some((
            "fake-position fusion: EKF2 had no horizontal aiding source, so these innovations are the filter's own, not a sensor's".into(),
            sorted.fake,
        ));
    }
    if n == 0 && sorted.inactive > 0 {
        return Some((
            format!(
                "its source ({}) was never active by EKF2's status flags while it updated",
                words_of(source)
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

fn words_of(source: &Source) -> &'static str {
    match source {
        Source::Sensor { words, .. } | Source::HorizontalPosition { words, .. } => words,
        Source::Always(w) => w,
    }
}

/// The channels of one instance's `estimator_innovations` (or legacy) rows.
#[allow(clippy::too_many_arguments)]
fn read_innovations(
    ctx: &Ctx,
    path: &Path,
    an: &mut NisAnalyzer,
    source_out: &mut LogSource,
    info: &mut Px4Info,
    inst: u8,
    topic: &Topic,
    legacy: bool,
) -> Result<usize, FileError> {
    let read = ctx.read;
    type Pairing = Vec<Option<(usize, bool)>>;
    let (channels, pairing, var_topic): (Vec<Channel>, Pairing, &Topic) = if legacy {
        let pairing = (0..topic.times.len()).map(|r| Some((r, true))).collect();
        (legacy_channels(&topic.names), pairing, topic)
    } else {
        let Some(vt) = read.topics.get(&(VARIANCES.to_string(), inst)) else {
            source_out.notes.push(format!(
                "ekf{inst}: {INNOVATIONS} without {VARIANCES}: skipped"
            ));
            return Ok(0);
        };
        (
            innovation_channels(topic, vt),
            pair(&topic.times, &vt.times),
            vt,
        )
    };
    let ratio_topic = read.topics.get(&(TEST_RATIOS.to_string(), inst));
    let ratio_rows = ratio_topic.map(|t| pair(&topic.times, &t.times));
    let ratio_cols = ratio_topic.map(|t| columns(&t.names));
    source_out
        .notes
        .push(pairing_note(inst, topic, &pairing, legacy));
    let flags = Flags::of(read, inst);
    let logged_hz = topic.rate_hz();
    for ch in &channels {
        let source = estimator::source_of(&ch.base, ch.idx);
        let ratio_col = ratio_cols.as_ref().and_then(|c| {
            let key = if legacy {
                format!(
                    "{}_innov{}",
                    ch.base,
                    ch.idx.map_or(String::new(), |i| format!("[{i}]"))
                )
            } else {
                ch.name.clone()
            };
            c.get(key.as_str()).copied()
        });
        let rows: Vec<Row> = pairing
            .iter()
            .enumerate()
            .filter_map(|(r, p)| {
                let (vr, exact) = (*p)?;
                let test_ratio = match (ratio_topic, &ratio_rows, ratio_col) {
                    (Some(t), Some(rr), Some(c)) => {
                        rr[r].filter(|x| x.1).map(|(k, _)| t.values[k][c])
                    }
                    _ => None,
                };
                Some(Row {
                    time: topic.times[r],
                    nu: topic.values[r][ch.innov],
                    s: var_topic.values[vr][ch.var],
                    exact,
                    test_ratio,
                    fused: None,
                    obs_var: None,
                })
            })
            .collect();
        let sorted = sort_rows(ctx, &rows, &source, flags.as_ref());
        let judged = info.channels.len();
        judge_channel(
            ctx, path, an, info, inst, &ch.name, &ch.base, &source, logged_hz, sorted,
        )?;
        if let (Some(c), Some(f), Some(&end)) = (
            info.channels.get_mut(judged),
            &flags,
            topic.times.iter().max(),
        ) {
            c.active_s = Some(f.active_seconds(&source, end));
        }
    }
    Ok(pairing.len())
}

/// The channels of an innovations topic that its variances topic `vt` has a column for.
fn innovation_channels(topic: &Topic, vt: &Topic) -> Vec<Channel> {
    let var_at = columns(&vt.names);
    topic
        .names
        .iter()
        .enumerate()
        .filter_map(|(i, n)| {
            var_at.get(n.as_str()).map(|&v| {
                let (base, idx) = split_index(n);
                Channel {
                    name: n.clone(),
                    innov: i,
                    var: v,
                    base,
                    idx,
                }
            })
        })
        .collect()
}

/// The note on how instance `inst`'s innovation rows were paired with their variances.
fn pairing_note(
    inst: u8,
    topic: &Topic,
    pairing: &[Option<(usize, bool)>],
    legacy: bool,
) -> String {
    if legacy {
        return format!(
            "ekf{inst}: {} rows of {LEGACY} (innovations and variances in one message)",
            pairing.len()
        );
    }
    let exact = pairing
        .iter()
        .filter(|p| matches!(p, Some((_, true))))
        .count();
    let near = pairing
        .iter()
        .filter(|p| matches!(p, Some((_, false))))
        .count();
    let unpaired = pairing.len() - exact - near;
    let stamp = if topic.sampled_time {
        "timestamp_sample"
    } else {
        "timestamp (this release logs no timestamp_sample)"
    };
    format!(
        "ekf{inst}: {} rows; {exact} paired with a variances row of the same {stamp}, {near} with the nearest within 50 ms, {unpaired} unpaired (dropped)",
        pairing.len()
    )
}

/// Takeoffs, landings, primary switches and aiding-source changes, in time order.
fn events(ctx: &Ctx, instances: &[u8], info: &mut Px4Info) {
    let mut ev = Vec::new();
    let mut was: Option<bool> = None;
    for &(t, landed) in &ctx.land {
        if was.is_some_and(|w| w != landed) || (was.is_none() && !landed) {
            ev.push(Px4Event {
                time: ctx.secs(t),
                what: if landed {
                    "landing".into()
                } else {
                    "takeoff".into()
                },
                kind: if landed {
                    EventKind::Landing
                } else {
                    EventKind::Takeoff
                },
            });
        }
        was = Some(landed);
    }
    if let Some(sel) = ctx.read.topics.get(&(SELECTOR.to_string(), 0))
        && let Some(c) = sel.column("primary_instance")
    {
        let mut prev: Option<u8> = None;
        let mut time_as: BTreeMap<u8, f64> = BTreeMap::new();
        for (k, (&t, v)) in sel.stamps.iter().zip(&sel.values).enumerate() {
            let p = v[c] as u8;
            if prev != Some(p) {
                ev.push(Px4Event {
                    time: ctx.secs(t),
                    what: format!("primary: ekf{p}"),
                    kind: EventKind::Primary,
                });
            }
            prev = Some(p);
            if let Some(&next) = sel.stamps.get(k + 1) {
                *time_as.entry(p).or_default() += next.saturating_sub(t) as f64 * 1e-6;
            }
        }
        for inst in &mut info.instances {
            inst.primary_s = Some(time_as.get(&inst.index).copied().unwrap_or(0.0));
        }
    }
    for &inst in instances {
        if let Some(flags) = Flags::of(ctx.read, inst) {
            for (t, name, on) in flags.changes(estimator::aiding_mask()) {
                ev.push(Px4Event {
                    time: ctx.secs(t),
                    what: format!(
                        "ekf{inst}: {} {}",
                        estimator::flag_words(name),
                        if on { "on" } else { "off" }
                    ),
                    kind: EventKind::Aiding,
                });
            }
        }
    }
    ev.sort_by(|a, b| a.time.total_cmp(&b.time));
    info.events = ev;
}

/// Read a PX4 ULog file into `an`.
pub(super) fn read(
    path: &Path,
    options: &ReadOptions,
    an: &mut NisAnalyzer,
) -> Result<LogSource, FileError> {
    let (read, ending) = read::read_file(path)?;
    let mut source = LogSource::new(path, "px4-ulog");
    source.rows = read.rows;
    note_ending(path, ending, options, &mut source)?;
    let instances = instances(path, &read)?;
    let legacy_only = instances.iter().all(|(_, k)| *k == "legacy");
    let (publisher, evidence) = estimator::publisher(&read, legacy_only)
        .map_err(|why| FileError::new(path, "", why.to_string()))?;
    if options.in_air && !read.topics.keys().any(|(n, _)| n == LAND) {
        return Err(FileError::new(
            path,
            "",
            format!("--in-air needs the {LAND} topic, which this log does not have"),
        ));
    }
    let land: Vec<(u64, bool)> = read
        .topics
        .get(&(LAND.to_string(), 0))
        .map(|t| {
            t.stamps
                .iter()
                .zip(&t.values)
                .map(|(&s, v)| (s, v.first().is_some_and(|x| *x != 0.0)))
                .collect()
        })
        .unwrap_or_default();
    let ctx = Ctx {
        read: &read,
        options,
        land,
        origin: read.header_us,
        rates: estimator::source_rates(&read),
        publisher_assumed: evidence.starts_with("assumed"),
    };
    let mut info = Px4Info {
        version: read.release.map(estimator::version),
        publisher,
        publisher_evidence: evidence,
        time_origin_us: read.header_us,
        params: read.params.clone(),
        param_changes: read
            .param_changes
            .iter()
            .map(|(t, n, v)| (ctx.secs(*t), n.clone(), *v))
            .collect(),
        ..Px4Info::default()
    };
    let mut numbers: Vec<u8> = instances.iter().map(|x| x.0).collect();
    numbers.sort_unstable();
    numbers.dedup();
    for &inst in &numbers {
        let kinds: Vec<&str> = instances
            .iter()
            .filter(|x| x.0 == inst)
            .map(|x| x.1)
            .collect();
        let instance = read_instance(&ctx, path, an, &mut source, &mut info, inst, &kinds)?;
        info.instances.push(instance);
    }
    events(&ctx, &numbers, &mut info);
    let sampled: Vec<String> = info
        .channels
        .iter()
        .filter(|c| c.sampled)
        .map(|c| c.name.clone())
        .collect();
    if !sampled.is_empty() {
        source.notes.push(format!(
            "{} channel{} logged more slowly than their source is fused: each update judged is a sample of the fusions, not every fusion ({})",
            sampled.len(),
            if sampled.len() == 1 { " is" } else { "s are" },
            sampled.join(", ")
        ));
    }
    source.px4 = Some(info);
    Ok(source)
}

/// How the file ended, as a note when the data before a cut or a damaged message may be
/// judged (`--allow-truncated`), an error otherwise.
fn note_ending(
    path: &Path,
    ending: Ending,
    options: &ReadOptions,
    source: &mut LogSource,
) -> Result<(), FileError> {
    match ending {
        Ending::Complete => {}
        Ending::Truncated if options.allow_truncated => source
            .notes
            .push("the file is truncated: the data before the cut were judged".into()),
        Ending::Truncated => {
            return Err(FileError::new(
                path,
                "",
                "the file is truncated (it ends partway through a message); --allow-truncated judges the data before the cut",
            ));
        }
        Ending::Malformed(why) if options.allow_truncated => source.notes.push(format!(
            "a malformed message ({}) ends the readable data: what came before was judged",
            first_line(&why)
        )),
        Ending::Malformed(why) => {
            return Err(FileError::new(
                path,
                "",
                format!(
                    "a malformed message in the data ({}); --allow-truncated judges the data before it",
                    first_line(&why)
                ),
            ));
        }
    }
    Ok(())
}

/// The estimator instances of the log and the kind of each innovation topic they logged
/// (`aid`, `innov`, `legacy`); an error when there is none.
fn instances<'r>(path: &Path, read: &'r Read) -> Result<Vec<(u8, &'r str)>, FileError> {
    let mut instances: Vec<(u8, &str)> = Vec::new();
    for (name, i) in read.topics.keys() {
        let kind = if name.starts_with(AID_SRC) {
            "aid"
        } else if name == INNOVATIONS {
            "innov"
        } else if name == LEGACY {
            "legacy"
        } else {
            continue;
        };
        instances.push((*i, kind));
    }
    if instances.is_empty() {
        return Err(FileError::new(
            path,
            "",
            format!(
                "no estimator_aid_src_*, {INNOVATIONS} (with {VARIANCES}) or {LEGACY} data: nothing to judge"
            ),
        ));
    }
    Ok(instances)
}

/// Read estimator instance `inst`'s channels, from the aid-source topics where it logged
/// them (its topics' `kinds`), else from its innovation topic.
#[allow(clippy::too_many_arguments)]
fn read_instance(
    ctx: &Ctx<'_>,
    path: &Path,
    an: &mut NisAnalyzer,
    source: &mut LogSource,
    info: &mut Px4Info,
    inst: u8,
    kinds: &[&str],
) -> Result<Px4Instance, FileError> {
    let read = ctx.read;
    let has = |k: &str| kinds.contains(&k);
    let (rows, topics, hz) = if has("aid") {
        if has("innov") {
            source.notes.push(format!(
                "ekf{inst}: judged from the aid-source topics, which say what was fused; {INNOVATIONS} not used"
            ));
        }
        let rows = aid_src::read_aid_sources(ctx, path, an, source, info, inst)?;
        let hz = read
            .topics
            .iter()
            .filter(|((n, i), _)| *i == inst && n.starts_with(AID_SRC))
            .map(|(_, t)| t.rate_hz())
            .fold(0.0, f64::max);
        (rows, "estimator_aid_src_*".to_string(), hz)
    } else {
        let legacy = !has("innov");
        let name = if legacy { LEGACY } else { INNOVATIONS };
        let topic = &read.topics[&(name.to_string(), inst)];
        if !topic.stamps.is_empty() && topic.stamps.iter().all(|&t| t == topic.stamps[0]) {
            source.notes.push(format!(
                "ekf{inst}: every row of {name} has the timestamp {}: the time axis and time windows are meaningless",
                topic.stamps[0]
            ));
        }
        let rows = read_innovations(ctx, path, an, source, info, inst, topic, legacy)?;
        (rows, name.to_string(), topic.rate_hz())
    };
    Ok(Px4Instance {
        index: inst,
        topics,
        rows,
        logged_hz: hz,
        primary_s: None,
    })
}

fn first_line(s: &str) -> String {
    let l = s.lines().next().unwrap_or("");
    crate::records::shown_up_to(l, 120)
}
