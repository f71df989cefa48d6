//! The older layouts: `estimator_innovations` paired with `estimator_innovation_variances`
//! (and `estimator_innovation_test_ratios`) per instance, or the single `ekf2_innovations`
//! topic; each array element its own channel.

use std::collections::HashMap;
use std::path::Path;

use super::Px4Info;
use super::channel::{ChannelId, Row, Shape, judge_channel, sort_rows};
use super::context::{Ctx, PAIR_WITHIN_US};
use super::estimator::{self, Flags};
use super::read::{INNOVATIONS, LEGACY, TEST_RATIOS, Topic, VARIANCES};
use crate::fieldlog::LogSource;
use crate::fieldlog::analysis::NisAnalyzer;
use crate::input::FileError;

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
pub(super) fn split_index(name: &str) -> (String, Option<usize>) {
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

/// The test ratios of one instance: the topic, each innovations row's pairing with it, and
/// its columns by name.
struct Ratios<'a> {
    topic: &'a Topic,
    rows: Vec<Option<(usize, bool)>>,
    cols: HashMap<&'a str, usize>,
}

/// The channels of one instance's `estimator_innovations` (or legacy) rows.
#[allow(clippy::too_many_arguments)]
pub(super) fn read_innovations(
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
    let ratios = read
        .topics
        .get(&(TEST_RATIOS.to_string(), inst))
        .map(|t| Ratios {
            topic: t,
            rows: pair(&topic.times, &t.times),
            cols: columns(&t.names),
        });
    source_out
        .notes
        .push(pairing_note(inst, topic, &pairing, legacy));
    source_out
        .notes
        .extend(ratio_note(inst, topic, ratios.as_ref()));
    let flags = Flags::of(read, inst);
    for ch in &channels {
        let source = estimator::source_of(&ch.base, ch.idx);
        let shape = Shape::of(&ch.base, ch.idx);
        let rows = channel_rows(topic, var_topic, &pairing, ratios.as_ref(), ch, legacy);
        let sorted = sort_rows(ctx, &rows, &source, flags.as_ref(), shape);
        let judged = info.channels.len();
        let id = ChannelId {
            inst,
            name: &ch.name,
            base: &ch.base,
            source: &source,
            shape,
            logged_hz: topic.rate_hz(),
        };
        judge_channel(ctx, path, an, info, &id, sorted)?;
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

/// The paired rows of channel `ch`, each with its test ratio where a ratios row of the same
/// filter cycle has one.
fn channel_rows(
    topic: &Topic,
    var_topic: &Topic,
    pairing: &[Option<(usize, bool)>],
    ratios: Option<&Ratios>,
    ch: &Channel,
    legacy: bool,
) -> Vec<Row> {
    let ratio_col = ratios.and_then(|r| {
        let key = if legacy {
            format!(
                "{}_innov{}",
                ch.base,
                ch.idx.map_or(String::new(), |i| format!("[{i}]"))
            )
        } else {
            ch.name.clone()
        };
        r.cols.get(key.as_str()).copied()
    });
    pairing
        .iter()
        .enumerate()
        .filter_map(|(r, p)| {
            let (vr, exact) = (*p)?;
            let test_ratio = match (ratios, ratio_col) {
                (Some(t), Some(c)) => t.rows[r].filter(|x| x.1).map(|(k, _)| t.topic.values[k][c]),
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
        .collect()
}

/// Why some or all of the logged test ratios are not used: a ratio is read only from a row
/// of the same filter cycle (time) as the innovations row; another cycle's ratio describes
/// another innovation.
fn ratio_note(inst: u8, topic: &Topic, ratios: Option<&Ratios>) -> Option<String> {
    let r = ratios?;
    let rows = r.rows.len();
    let same = r
        .rows
        .iter()
        .filter(|p| matches!(p, Some((_, true))))
        .count();
    let stamp = if topic.sampled_time {
        "timestamp_sample"
    } else {
        "timestamp"
    };
    if same == rows {
        return None;
    }
    Some(if same == 0 {
        format!(
            "ekf{inst}: {TEST_RATIOS} is logged, but none of its rows has the {stamp} of an innovations row: its ratios are from other filter cycles and describe other innovations, so EKF2's test ratio, gate and rejections are not shown"
        )
    } else {
        format!(
            "ekf{inst}: {TEST_RATIOS}: {same} of {rows} innovations rows have a ratios row of the same {stamp}; the ratios of the other {} (from other filter cycles) are not used",
            rows - same
        )
    })
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
