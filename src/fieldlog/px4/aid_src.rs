//! The v1.14+ aid-source topics (`estimator_aid_src_*`): one topic per aiding source and
//! instance, each row a fusion attempt with EKF2's own `fused` and `innovation_rejected`.

use std::path::Path;

use super::channel::{ChannelId, Row, Shape, judge_channel, sort_rows};
use super::context::Ctx;
use super::read::{AID_SRC, Topic};
use super::{NotJudged, Px4Info, estimator};
use crate::fieldlog::LogSource;
use crate::fieldlog::analysis::NisAnalyzer;
use crate::input::FileError;

/// The channels of one instance's `estimator_aid_src_*` topics.
pub(super) fn read_aid_sources(
    ctx: &Ctx,
    path: &Path,
    an: &mut NisAnalyzer,
    source_out: &mut LogSource,
    info: &mut Px4Info,
    inst: u8,
) -> Result<usize, FileError> {
    let mut rows_read = 0;
    let mut topics = Vec::new();
    for ((name, i), topic) in &ctx.read.topics {
        let Some(src) = name.strip_prefix(AID_SRC) else {
            continue;
        };
        if *i != inst {
            continue;
        }
        topics.push(src.to_string());
        rows_read += topic.times.len();
        // 1-d topics have `innovation`; 2-d and 3-d ones `innovation[j]`.
        let axes: Vec<Option<usize>> = if topic.column("innovation").is_some() {
            vec![None]
        } else {
            (0..3)
                .map(Some)
                .filter(|j| {
                    topic
                        .column(&format!("innovation[{}]", j.unwrap_or(0)))
                        .is_some()
                })
                .collect()
        };
        for axis in axes {
            read_axis(ctx, path, an, info, inst, src, topic, axis)?;
        }
    }
    source_out.notes.push(format!(
        "ekf{inst}: {rows_read} rows of {} aid-source topics ({}); a row is an update when EKF2 fused or rejected it",
        topics.len(),
        topics.join(", ")
    ));
    Ok(rows_read)
}

/// Judge one axis (`None` for a 1-d source) of aid-source topic `src` of instance `inst`,
/// or note why it is not judged (a fake fusion).
#[allow(clippy::too_many_arguments)]
fn read_axis(
    ctx: &Ctx,
    path: &Path,
    an: &mut NisAnalyzer,
    info: &mut Px4Info,
    inst: u8,
    src: &str,
    topic: &Topic,
    axis: Option<usize>,
) -> Result<(), FileError> {
    let field = |f: &str| match axis {
        None => topic.column(f),
        Some(j) => topic
            .column(&format!("{f}[{j}]"))
            .or_else(|| topic.column(f)),
    };
    let (Some(ci), Some(cv)) = (field("innovation"), field("innovation_variance")) else {
        return Ok(());
    };
    let (ct, co, cf, cr) = (
        field("test_ratio"),
        field("observation_variance"),
        field("fused"),
        field("innovation_rejected"),
    );
    let name = match axis {
        None => src.to_string(),
        Some(j) => format!("{src}[{j}]"),
    };
    if src.starts_with("fake_") {
        let fused = topic
            .values
            .iter()
            .filter(|v| cf.is_some_and(|c| v[c] != 0.0))
            .count();
        info.not_judged.push(NotJudged {
            name: format!("ekf{inst}.{name}"),
            reason: "fake fusion (no aiding source): these innovations are the filter's own, not a sensor's".into(),
            updates: fused,
        });
        return Ok(());
    }
    let rows: Vec<Row> = (0..topic.times.len())
        .map(|r| {
            let v = &topic.values[r];
            Row {
                time: topic.times[r],
                nu: v[ci],
                s: v[cv],
                exact: true,
                test_ratio: ct.map(|c| v[c]),
                fused: Some((
                    cf.is_none_or(|c| v[c] != 0.0),
                    cr.is_some_and(|c| v[c] != 0.0),
                )),
                obs_var: co.map(|c| v[c]),
            }
        })
        .collect();
    let source = estimator::Source::Always(aid_words(src));
    // The flags still say when the vehicle was at rest (gravity's updates there say nothing
    // about its noise); an aid-source row says itself whether it was fused.
    let flags = estimator::Flags::of(ctx.read, inst);
    let shape = Shape::of(src, axis);
    let sorted = sort_rows(ctx, &rows, &source, flags.as_ref(), shape);
    let id = ChannelId {
        inst,
        name: &name,
        base: src,
        source: &source,
        shape,
        logged_hz: topic.rate_hz(),
    };
    judge_channel(ctx, path, an, info, &id, sorted)
}

fn aid_words(src: &str) -> &'static str {
    match src {
        "baro_hgt" => "baro height",
        "gnss_pos" => "GNSS position",
        "gnss_vel" => "GNSS velocity",
        "gnss_hgt" => "GNSS height",
        "gnss_yaw" => "GNSS yaw",
        "mag" => "3-axis magnetometer",
        "mag_heading" => "magnetic heading",
        "rng_hgt" => "range-finder height",
        "ev_pos" => "vision position",
        "ev_vel" => "vision velocity",
        "ev_hgt" => "vision height",
        "ev_yaw" => "vision yaw",
        "airspeed" => "airspeed",
        "sideslip" => "synthetic sideslip",
        "optical_flow" => "optical flow",
        "terrain_range_finder" => "terrain range finder",
        "gravity" => "gravity vector",
        "drag" => "multirotor drag",
        "aux_vel" => "auxiliary velocity",
        "aux_global_position" => "auxiliary global position",
        _ => "aiding source",
    }
}
