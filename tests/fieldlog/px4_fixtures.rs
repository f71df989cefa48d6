//! The issue-23 ULog writer and PX4 fixtures are right, independently of autotune's reader:
//! every fixture is read back with the px4-ulog crate's own reader (and with pyulog when it
//! is installed), and the statistical properties the behaviour tests rely on are measured
//! on what the files contain, over several seeds.
use crate::support;

use std::collections::BTreeMap;
use std::path::Path;

use px4_ulog::stream_parser::model::{FlattenedFieldType, LogStage, ParameterMessage};
use px4_ulog::stream_parser::{Message, SimpleCallbackResult, read_file_with_simple_callback};
use support::px4_fixtures::{self as fx, Kind, Truth};
use support::ulog::{Param, ULogWriter};

type Rows = Vec<BTreeMap<String, f64>>;

/// What the px4-ulog crate reads from a file.
#[derive(Default)]
struct ReadBack {
    ver_sw_release: Option<u32>,
    params: BTreeMap<String, f64>,
    param_changes: Vec<(String, f64)>,
    topics: BTreeMap<(String, u8), Rows>,
    /// (topic, multi_id, timestamp) of every data row, in file order.
    order: Vec<(String, u8, u64)>,
    strings: Vec<String>,
}

impl ReadBack {
    fn rows(&self, topic: &str, multi: u8) -> &Rows {
        self.topics
            .get(&(topic.to_string(), multi))
            .unwrap_or_else(|| panic!("no rows of {topic}/{multi}"))
    }
    fn col(&self, topic: &str, multi: u8, field: &str) -> Vec<f64> {
        self.rows(topic, multi)
            .iter()
            .map(|r| {
                *r.get(field)
                    .unwrap_or_else(|| panic!("no field {field} in {topic}"))
            })
            .collect()
    }
}

fn decode(ty: &FlattenedFieldType, b: &[u8]) -> f64 {
    let a = |n: usize| -> [u8; 8] {
        let mut x = [0u8; 8];
        x[..n].copy_from_slice(&b[..n]);
        x
    };
    match ty {
        FlattenedFieldType::Int8 => f64::from(b[0] as i8),
        FlattenedFieldType::UInt8 | FlattenedFieldType::Char => f64::from(b[0]),
        FlattenedFieldType::Bool => f64::from(u8::from(b[0] != 0)),
        FlattenedFieldType::Int16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
        FlattenedFieldType::UInt16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
        FlattenedFieldType::Int32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        FlattenedFieldType::UInt32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        FlattenedFieldType::Float => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        FlattenedFieldType::Int64 => i64::from_le_bytes(a(8)) as f64,
        FlattenedFieldType::UInt64 => u64::from_le_bytes(a(8)) as f64,
        FlattenedFieldType::Double => f64::from_le_bytes(a(8)),
    }
}

fn read_back_file(path: &Path) -> ReadBack {
    let mut rb = ReadBack::default();
    let mut cb = |m: &Message| {
        match m {
            Message::Data(d) => {
                let name = d.flattened_format.message_name().to_string();
                let mut row = BTreeMap::new();
                for f in d.flattened_format.field_iter() {
                    if f.flattened_field_name.starts_with("_padding") {
                        continue;
                    }
                    row.insert(
                        f.flattened_field_name.clone(),
                        decode(&f.field_type, &d.data[f.offset as usize..]),
                    );
                }
                let t = row.get("timestamp").copied().unwrap_or(-1.0) as u64;
                rb.order.push((name.clone(), d.multi_id.value(), t));
                rb.topics
                    .entry((name, d.multi_id.value()))
                    .or_default()
                    .push(row);
            }
            Message::ParameterMessage(p) => {
                let (name, v, stage) = match p {
                    ParameterMessage::Float(n, v, s) => (n, f64::from(*v), s),
                    ParameterMessage::Int32(n, v, s) => (n, f64::from(*v), s),
                };
                if *stage == LogStage::Definitions {
                    rb.params.insert(name.to_string(), v);
                } else {
                    rb.param_changes.push((name.to_string(), v));
                }
            }
            Message::InfoMessage(i) if i.key == "ver_sw_release" => {
                rb.ver_sw_release = Some(u32::from_le_bytes(i.value[..4].try_into().unwrap()));
            }
            Message::LoggedMessage(l) => rb.strings.push(l.logged_message.to_string()),
            _ => {}
        }
        SimpleCallbackResult::KeepReading
    };
    let completeness = read_file_with_simple_callback(path.to_str().unwrap(), &mut cb)
        .expect("the crate reads the fixture");
    assert!(
        !completeness.is_incomplete(),
        "{}: the crate found the file incomplete: {completeness:?}",
        path.display()
    );
    rb
}

fn read_back(bytes: &[u8]) -> ReadBack {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("f.ulg");
    std::fs::write(&p, bytes).unwrap();
    read_back_file(&p)
}

fn all_fixtures(seed: u64) -> Vec<(Vec<u8>, Truth)> {
    vec![
        fx::fake_position_v111(seed),
        fx::lpe_legacy(seed),
        fx::biased_heading(seed),
        fx::all_r_too_small(seed),
        fx::all_q_too_small(seed),
        fx::known_baro_noise(seed),
        fx::aid_src_v114(seed),
        fx::primary_switch(seed),
    ]
}

/// ν/√S of an innovation-topic channel such as `gps_hpos[1]`, as read back.
fn normalised(rb: &ReadBack, multi: u8, field: &str) -> Vec<f64> {
    let nu = rb.col("estimator_innovations", multi, field);
    let s = rb.col("estimator_innovation_variances", multi, field);
    nu.iter().zip(&s).map(|(n, s)| n / s.sqrt()).collect()
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

fn mean_square(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64
}

/// Pooled raw (not demeaned) lag-1 autocorrelation: Σ z_k z_{k+1} / Σ z_k² over channels,
/// the statistic autotune's whiteness test reports as ρ₁.
fn pooled_rho1(seqs: &[Vec<f64>]) -> f64 {
    let num: f64 = seqs
        .iter()
        .map(|z| z.windows(2).map(|w| w[0] * w[1]).sum::<f64>())
        .sum();
    let den: f64 = seqs
        .iter()
        .map(|z| z.iter().map(|v| v * v).sum::<f64>())
        .sum();
    num / den
}

/// The NIS mean of N independent draws of ratio·χ²₁ has standard deviation ratio·√(2/N);
/// a 4.5σ band is missed by chance with probability < 1e-5 per check.
fn nis_band(ratio: f64, n: usize) -> f64 {
    4.5 * ratio * (2.0 / n as f64).sqrt()
}

#[test]
fn issue23_ulog_writer_round_trips_every_type_through_the_px4_ulog_crate() {
    let mut w = ULogWriter::new(1_000);
    w.info_str("sys_name", "PX4")
        .info_u32("ver_sw_release", 0x010D_0000);
    w.param("A_FLOAT", Param::Float(1.5))
        .param("AN_INT", Param::Int(-7));
    w.format(
        "all_types",
        "uint64_t timestamp;int64_t i64;double d;float[2] f;int32_t i32;uint32_t u32;int16_t i16;uint16_t u16;int8_t i8;uint8_t u8;bool b;char[3] c;uint8_t[5] _padding0;",
    );
    // Written out of time order across topics and instances: the file must be merged.
    w.data(
        "all_types",
        1,
        &[
            ("timestamp", &[3_000.0]),
            ("i64", &[-5.0e12]),
            ("f", &[0.25, -2.5]),
        ],
    );
    w.data(
        "all_types",
        0,
        &[
            ("timestamp", &[2_000.0]),
            ("d", &[1.0 / 3.0]),
            ("i32", &[-70_000.0]),
            ("u32", &[4_000_000_000.0]),
            ("i16", &[-300.0]),
            ("u16", &[60_000.0]),
            ("i8", &[-100.0]),
            ("u8", &[200.0]),
            ("b", &[1.0]),
            ("c", &[65.0, 66.0]),
        ],
    );
    w.param_change(2_500, "A_FLOAT", Param::Float(2.5));
    w.log_string(2_600, b'6', "hello");
    let bytes = w.finish();
    assert_eq!(&bytes[..8], b"ULog\x01\x12\x35\x01");
    let rb = read_back(&bytes);
    assert_eq!(rb.ver_sw_release, Some(0x010D_0000));
    assert_eq!(rb.params["A_FLOAT"], 1.5);
    assert_eq!(rb.params["AN_INT"], -7.0);
    assert_eq!(rb.param_changes, vec![("A_FLOAT".to_string(), 2.5)]);
    assert_eq!(rb.strings, vec!["hello".to_string()]);
    let ts: Vec<u64> = rb.order.iter().map(|o| o.2).collect();
    assert_eq!(ts, vec![2_000, 3_000], "rows merged in time order");
    let r0 = &rb.rows("all_types", 0)[0];
    for (k, v) in [
        ("d", 1.0 / 3.0),
        ("i32", -70_000.0),
        ("u32", 4_000_000_000.0),
        ("i16", -300.0),
        ("u16", 60_000.0),
        ("i8", -100.0),
        ("u8", 200.0),
        ("b", 1.0),
        ("c[0]", 65.0),
        ("c[1]", 66.0),
        ("c[2]", 0.0),
        ("f[0]", 0.0),
    ] {
        assert_eq!(r0[k], v, "field {k}");
    }
    let r1 = &rb.rows("all_types", 1)[0];
    assert_eq!((r1["i64"], r1["f[0]"], r1["f[1]"]), (-5.0e12, 0.25, -2.5));
    // The trailing _padding0 bytes are not written (as PX4 does): 8 type-size-sorted
    // fields of 8+8+8+8+4+4+2+2+1+1+1+3 = 50 bytes, plus the 2-byte msg_id.
    let d_sizes: Vec<usize> = {
        let mut i = 16;
        let mut out = Vec::new();
        while i + 3 <= bytes.len() {
            let size = u16::from_le_bytes([bytes[i], bytes[i + 1]]) as usize;
            if bytes[i + 2] == b'D' {
                out.push(size);
            }
            i += 3 + size;
        }
        out
    };
    assert_eq!(d_sizes, vec![52, 52]);
}

#[test]
fn issue23_every_fixture_reads_back_with_the_px4_ulog_crate() {
    for seed in [1, 2] {
        for (bytes, truth) in all_fixtures(seed) {
            let name = truth.name;
            assert!(bytes.len() < 600_000, "{name}: {} bytes", bytes.len());
            let rb = read_back(&bytes);
            assert_eq!(rb.ver_sw_release, Some(truth.ver_sw_release), "{name}");
            let counts: BTreeMap<(String, u8), usize> = rb
                .topics
                .iter()
                .map(|(k, v)| (k.clone(), v.len()))
                .collect();
            assert_eq!(counts, truth.rows, "{name}: rows per topic and instance");
            assert_eq!(rb.params, truth.params, "{name}: parameters");
            let changes: Vec<(String, f64)> = truth
                .param_changes
                .iter()
                .map(|c| (c.1.clone(), c.2))
                .collect();
            assert_eq!(rb.param_changes, changes, "{name}: parameter changes");
            // Time order in the file (LPE's zero timestamps excepted).
            let stamped: Vec<u64> = rb.order.iter().map(|o| o.2).filter(|t| *t != 0).collect();
            assert!(
                stamped.windows(2).all(|w| w[0] <= w[1]),
                "{name}: rows not in time order"
            );
            // Landed until takeoff, flying until landing, landed after.
            let t = rb.col("vehicle_land_detected", 0, "timestamp");
            let landed = rb.col("vehicle_land_detected", 0, "landed");
            for (t, l) in t.iter().zip(&landed) {
                let flying = (*t as u64) >= truth.takeoff_us && (*t as u64) < truth.landing_us;
                assert_eq!(*l, f64::from(u8::from(!flying)), "{name}: landed at {t}");
            }
            for c in &truth.channels {
                assert!(
                    rb.topics.contains_key(&(c.topic.clone(), c.instance)),
                    "{name}: channel {} of {} missing",
                    c.field,
                    c.topic
                );
            }
        }
    }
}

#[test]
fn issue23_fake_position_v111_has_fake_fusion_an_underconfident_baro_and_no_gps() {
    for seed in [1, 2, 3] {
        let (bytes, truth) = fx::fake_position_v111(seed);
        let rb = read_back(&bytes);
        assert_eq!(rb.params["SYS_MC_EST_GROUP"], 2.0);
        assert_eq!(rb.params["EKF2_BARO_NOISE"], 3.5);
        for topic in [
            "estimator_innovations",
            "estimator_innovation_variances",
            "estimator_status",
        ] {
            assert!(
                !rb.rows(topic, 0)[0].contains_key("timestamp_sample"),
                "{topic}"
            );
        }
        let flags = rb.col("estimator_status", 0, "control_mode_flags");
        assert!(
            flags.iter().all(|f| (*f as u32) & (1 << 2) == 0),
            "GPS bit never set"
        );
        assert!(
            flags
                .iter()
                .all(|f| (*f as u32) & (1 << 9 | 1 << 4) == (1 << 9 | 1 << 4))
        );
        let n = rb.rows("estimator_innovations", 0).len();
        for f in ["gps_hpos[0]", "gps_hpos[1]"] {
            let nu = rb.col("estimator_innovations", 0, f);
            assert!(
                nu.iter().all(|v| v.abs() < 0.01),
                "{f}: millimetre innovations"
            );
            assert_eq!(
                truth.channel("estimator_innovations", 0, f).kind,
                Kind::FakeFusion
            );
        }
        // Test ratio with a gate of 100: the larger axis, in the first element.
        let (a, b) = (
            rb.col("estimator_innovations", 0, "gps_hpos[0]"),
            rb.col("estimator_innovations", 0, "gps_hpos[1]"),
        );
        let s = rb.col("estimator_innovation_variances", 0, "gps_hpos[0]");
        let tr = rb.col("estimator_innovation_test_ratios", 0, "gps_hpos[0]");
        for k in 0..n {
            let want = a[k].powi(2).max(b[k].powi(2)) / (1e4 * s[k]);
            assert!((tr[k] - want).abs() <= 1e-6 * want + 1e-30, "row {k}");
        }
        let baro = mean_square(&normalised(&rb, 0, "baro_vpos"));
        assert!(
            (baro - 1.0 / 3.0).abs() < nis_band(1.0 / 3.0, n),
            "baro NIS mean {baro}"
        );
        let head = mean_square(&normalised(&rb, 0, "heading"));
        assert!(
            (head - 1.0).abs() < nis_band(1.0, n),
            "heading NIS mean {head}"
        );
        // Innovations logged at 5 Hz, the baro source at 20 Hz.
        let rate = |topic: &str| {
            let t = rb.col(topic, 0, "timestamp");
            (t.len() - 1) as f64 / ((t[t.len() - 1] - t[0]) * 1e-6)
        };
        assert!((rate("estimator_innovations") - 5.0).abs() < 0.05);
        assert!((rate("vehicle_air_data") - 20.0).abs() < 0.1);
        println!("fake_position_v111 seed {seed}: baro NIS mean {baro:.3}, heading {head:.3}");
    }
}

#[test]
fn issue23_lpe_legacy_has_zero_timestamps_and_a_constant_r() {
    let (bytes, truth) = fx::lpe_legacy(7);
    let rb = read_back(&bytes);
    assert_eq!(rb.params["SYS_MC_EST_GROUP"], 1.0);
    assert!(
        rb.col("ekf2_innovations", 0, "timestamp")
            .iter()
            .all(|t| *t == 0.0)
    );
    let var = rb.col("ekf2_innovations", 0, "hagl_innov_var");
    assert!(var.iter().all(|v| *v == f64::from(0.0009f32)));
    let row = &rb.rows("ekf2_innovations", 0)[3];
    for (k, v) in row {
        if !k.starts_with("hagl") {
            assert_eq!(*v, 0.0, "{k}");
        }
    }
    assert_eq!(
        row.len(),
        1 + 2 * 15,
        "timestamp and the 15 + 15 legacy fields"
    );
    assert!(
        !rb.topics
            .keys()
            .any(|(t, _)| t == "ekf2_timestamps" || t.starts_with("estimator_"))
    );
    assert_eq!(truth.channels[0].kind, Kind::NotEkf2);
}

#[test]
fn issue23_biased_heading_is_a_bias_with_rho1_near_one_on_every_seed() {
    let (mut rho_min, mut rho_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut share_lo, mut share_hi) = (1.0f64, 0.0f64);
    for seed in 0..20 {
        let (bytes, truth) = fx::biased_heading(seed);
        let rb = read_back(&bytes);
        let z = normalised(&rb, 0, "heading");
        let nis = mean_square(&z);
        let share = mean(&z).powi(2) / nis;
        let rho = pooled_rho1(std::slice::from_ref(&z));
        // Written with exact sample moments (f32 rounding aside).
        assert!((nis - 0.3).abs() < 1e-4, "seed {seed}: NIS mean {nis}");
        assert!(
            (share - 0.8).abs() < 1e-3,
            "seed {seed}: mean share {share}"
        );
        assert!(rho > 0.97, "seed {seed}: raw rho1 {rho}");
        rho_min = rho_min.min(rho);
        rho_max = rho_max.max(rho);
        share_lo = share_lo.min(share);
        share_hi = share_hi.max(share);
        for c in truth.channels.iter().filter(|c| c.field != "heading") {
            let m = mean_square(&normalised(&rb, 0, &c.field));
            let n = rb.rows("estimator_innovations", 0).len();
            assert!(
                (m - 1.0).abs() < nis_band(1.0, n),
                "seed {seed} {}: {m}",
                c.field
            );
        }
    }
    println!(
        "biased_heading over 20 seeds: raw rho1 {rho_min:.4}..{rho_max:.4}, mean share {share_lo:.4}..{share_hi:.4}"
    );
}

/// The filter fixtures: ν/√S of every channel as read back.
fn filter_channels(bytes: &[u8], truth: &Truth) -> Vec<(String, Vec<f64>)> {
    let rb = read_back(bytes);
    truth
        .channels
        .iter()
        .map(|c| (c.field.clone(), normalised(&rb, 0, &c.field)))
        .collect()
}

#[test]
fn issue23_filter_fixtures_lag_one_sign_separates_r_from_q_on_every_seed() {
    let mut r_rho = Vec::new();
    let mut q_rho = Vec::new();
    let mut r_nis = Vec::new();
    let mut q_nis = Vec::new();
    let mut baro = Vec::new();
    for seed in 0..20 {
        for (which, (bytes, truth)) in [
            ("r", fx::all_r_too_small(seed)),
            ("q", fx::all_q_too_small(seed)),
            ("b", fx::known_baro_noise(seed)),
        ] {
            let ch = filter_channels(&bytes, &truth);
            let seqs: Vec<Vec<f64>> = ch.iter().map(|c| c.1.clone()).collect();
            let rho = pooled_rho1(&seqs);
            let nis = mean(&seqs.iter().map(|z| mean_square(z)).collect::<Vec<_>>());
            match which {
                "r" => {
                    r_rho.push(rho);
                    r_nis.push(nis);
                }
                "q" => {
                    q_rho.push(rho);
                    q_nis.push(nis);
                }
                _ => {
                    let b = ch.iter().find(|c| c.0 == "baro_vpos").unwrap();
                    baro.push(mean_square(&b.1));
                    // The other channels are right: NIS means near 1 (4.5σ band of
                    // 1000 samples that are nearly white when Q and R are right).
                    for (f, z) in ch.iter().filter(|c| c.0 != "baro_vpos") {
                        let m = mean_square(z);
                        assert!(
                            (m - 1.0).abs() < nis_band(1.0, z.len()),
                            "seed {seed} {f}: {m}"
                        );
                    }
                    let t = truth.channel("estimator_innovations", 0, "baro_vpos");
                    assert_eq!((t.param_value, t.true_sigma), (Some(3.5), Some(2.0)));
                }
            }
        }
    }
    let range = |v: &[f64]| {
        (
            v.iter().copied().fold(f64::INFINITY, f64::min),
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    println!(
        "all_r_too_small: pooled rho1 {:?}, NIS mean {:?}",
        range(&r_rho),
        range(&r_nis)
    );
    println!(
        "all_q_too_small: pooled rho1 {:?}, NIS mean {:?}",
        range(&q_rho),
        range(&q_nis)
    );
    println!("known_baro_noise: baro NIS mean {:?}", range(&baro));
    assert!(
        r_rho.iter().all(|r| *r < 0.0),
        "R too small: rho1 {r_rho:?}"
    );
    assert!(
        q_rho.iter().all(|r| *r > 0.0),
        "Q too small: rho1 {q_rho:?}"
    );
    assert!(
        r_nis.iter().all(|n| *n > 2.5),
        "R ×4 too small: NIS means {r_nis:?}"
    );
    assert!(q_nis.iter().all(|n| *n > 1.2), "Q ÷25: NIS means {q_nis:?}");
    // Baro: E[ν²]/S = (2² + P)/(3.5² + P) with P ≲ 0.5 m², so 0.33..0.36.
    assert!(
        baro.iter().all(|b| (0.28..0.42).contains(b)),
        "baro NIS means {baro:?}"
    );
}

#[test]
fn issue23_aid_src_fixture_flags_rejections_and_instances_read_back() {
    for seed in [1, 2, 3] {
        let (bytes, truth) = fx::aid_src_v114(seed);
        let rb = read_back(&bytes);
        for c in &truth.channels {
            let rows = rb.rows(&c.topic, c.instance);
            let fused = rows.iter().filter(|r| r["fused"] == 1.0).count();
            let rejected = rows
                .iter()
                .filter(|r| r["innovation_rejected"] == 1.0)
                .count();
            assert_eq!(
                (fused, rejected),
                (c.fused, c.rejected),
                "{} {}",
                c.topic,
                c.instance
            );
            for r in rows {
                assert_eq!(r["estimator_instance"], f64::from(c.instance));
                let over = r
                    .iter()
                    .any(|(k, v)| k.starts_with("test_ratio") && *v > 1.0);
                if r["innovation_rejected"] == 1.0 {
                    assert!(over && r["fused"] == 0.0);
                }
            }
        }
        let fake = rb.rows("estimator_aid_src_fake_pos", 0);
        let gps_us = fx::us(fx::AID_GPS_START_S) as f64;
        assert!(
            fake.iter()
                .all(|r| (r["fused"] == 1.0) <= (r["timestamp"] < gps_us))
        );
        assert!(fake.iter().any(|r| r["fused"] == 1.0));
        assert!(
            rb.rows("estimator_aid_src_gnss_pos", 0)
                .iter()
                .all(|r| r["timestamp"] >= gps_us)
        );
        let baro = rb.rows("estimator_aid_src_baro_hgt", 0);
        for k in fx::AID_BARO_OUTLIER_ROWS {
            assert_eq!(
                (baro[k]["innovation_rejected"], baro[k]["fused"]),
                (1.0, 0.0)
            );
        }
        // Instance 1's GNSS position logs S four times too small.
        let nis = |inst: u8| {
            let rows = rb.rows("estimator_aid_src_gnss_pos", inst);
            let z: Vec<f64> = rows
                .iter()
                .flat_map(|r| {
                    (0..2).map(|d| {
                        r[&format!("innovation[{d}]")]
                            / r[&format!("innovation_variance[{d}]")].sqrt()
                    })
                })
                .collect();
            (mean_square(&z), z.len())
        };
        let ((n0, k0), (n1, k1)) = (nis(0), nis(1));
        assert!((n0 - 1.0).abs() < nis_band(1.0, k0), "instance 0: {n0}");
        assert!((n1 - 4.0).abs() < nis_band(4.0, k1), "instance 1: {n1}");
        let g1 = truth.channel("estimator_aid_src_gnss_pos", 1, "innovation[0]");
        println!(
            "aid_src_v114 seed {seed}: gnss_pos NIS mean {n0:.3} / {n1:.3}, instance 1 fused {} rejected {}",
            g1.fused, g1.rejected
        );
        let flags = rb.rows("estimator_status_flags", 1);
        assert!(flags.iter().all(|r| r["cs_fake_pos"] + r["cs_gps"] == 1.0));
    }
}

#[test]
fn issue23_primary_switch_fixture_switches_once_at_the_known_time() {
    let (bytes, truth) = fx::primary_switch(4);
    let rb = read_back(&bytes);
    let at = fx::us(fx::PRIMARY_SWITCH_S) as f64;
    for r in rb.rows("estimator_selector_status", 0) {
        assert_eq!(
            r["primary_instance"],
            f64::from(u8::from(r["timestamp"] >= at))
        );
    }
    for inst in 0..2 {
        assert_eq!(rb.rows("estimator_innovations", inst).len(), 400);
        let n = 400;
        let z = normalised(&rb, inst, "baro_vpos");
        assert!((mean_square(&z) - 1.0).abs() < nis_band(1.0, n));
    }
    assert_eq!(
        truth.primary.last(),
        Some(&(fx::us(fx::PRIMARY_SWITCH_S), 1))
    );
}

/// pyulog (PX4's own Python parser) reads the same rows, sums and parameters from every
/// fixture as the px4-ulog crate. Skipped with a note when pyulog is missing, unless
/// AUTOTUNE_REQUIRE_PYULOG=1; the interpreter is AUTOTUNE_PYTHON or `python3`.
#[test]
fn issue23_fixtures_read_the_same_with_pyulog() {
    let python = std::env::var("AUTOTUNE_PYTHON").unwrap_or_else(|_| "python3".into());
    let has = std::process::Command::new(&python)
        .args(["-c", "import pyulog"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has {
        assert!(
            std::env::var("AUTOTUNE_REQUIRE_PYULOG").as_deref() != Ok("1"),
            "pyulog is required (AUTOTUNE_REQUIRE_PYULOG=1) but `{python} -c 'import pyulog'` fails"
        );
        println!(
            "note: pyulog not importable with `{python}`; set AUTOTUNE_PYTHON to check with it"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for (bytes, truth) in all_fixtures(5) {
        let p = dir.path().join(format!("{}.ulg", truth.name));
        std::fs::write(&p, bytes).unwrap();
        files.push(p);
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/px4/read_fixture.py");
    let out = std::process::Command::new(&python)
        .arg(script)
        .args(&files)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let py: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for p in &files {
        let rb = read_back_file(p);
        let f = &py[p.to_str().unwrap()];
        assert_eq!(
            f["ver_sw_release"].as_u64(),
            rb.ver_sw_release.map(u64::from)
        );
        for (k, v) in &rb.params {
            assert_eq!(
                f["params"][k].as_f64(),
                Some(*v),
                "{}: param {k}",
                p.display()
            );
        }
        let topics = f["topics"].as_object().unwrap();
        assert_eq!(topics.len(), rb.topics.len(), "{}", p.display());
        for ((topic, multi), rows) in &rb.topics {
            let t = &topics[&format!("{topic}/{multi}")];
            assert_eq!(
                t["rows"].as_u64(),
                Some(rows.len() as u64),
                "{topic}/{multi}"
            );
            for field in rows[0].keys() {
                let ours: f64 = rows.iter().map(|r| r[field]).sum();
                let theirs = t["sums"][field]
                    .as_f64()
                    .unwrap_or_else(|| panic!("{topic}.{field}"));
                assert!(
                    (ours - theirs).abs() <= 1e-9 * ours.abs().max(1.0),
                    "{}: {topic}/{multi}.{field}: {ours} vs pyulog {theirs}",
                    p.display()
                );
            }
        }
    }
}

/// Not a check: writes every fixture (seed 1) and its truth to $AUTOTUNE_FIXTURE_DIR for
/// looking at them (`cargo test --release --test fieldlog -- --ignored px4_fixtures::`).
#[test]
#[ignore]
fn issue23_write_fixtures_for_inspection() {
    let dir = std::env::var("AUTOTUNE_FIXTURE_DIR").expect("set AUTOTUNE_FIXTURE_DIR");
    let seed = std::env::var("AUTOTUNE_FIXTURE_SEED").map_or(1, |s| s.parse().unwrap());
    for (bytes, truth) in all_fixtures(seed) {
        let p = Path::new(&dir).join(truth.name);
        std::fs::write(p.with_extension("ulg"), bytes).unwrap();
        std::fs::write(p.with_extension("truth.txt"), format!("{truth:#?}\n")).unwrap();
    }
}
