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
mod channel;
mod context;
mod ekf2;
mod estimator;
mod info;
mod innovations;
mod read;

pub(super) use annotate::annotate;
pub use ekf2::ParamAdvice;
pub use info::{EventKind, NotJudged, Px4Channel, Px4Event, Px4Info, Px4Instance};

use std::collections::BTreeMap;
use std::path::Path;

use super::analysis::NisAnalyzer;
use super::ulog_walk::Ending;
use super::{LogSource, ReadOptions};
use crate::input::FileError;
use context::Ctx;
use estimator::Flags;
use read::{AID_SRC, INNOVATIONS, LAND, LEGACY, Read, SELECTOR, VARIANCES};

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
        let rows = innovations::read_innovations(ctx, path, an, source, info, inst, topic, legacy)?;
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
