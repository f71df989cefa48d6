//! A small ULog writer for test fixtures (PX4 user guide, "ULog File Format").
//!
//! It writes the 16-byte header, the 'B' flag bits (no flags, no appended data), 'I' info,
//! 'P' parameters (definitions before the data section, changes inside it), 'F' formats,
//! 'A' subscriptions (each just before its first row), 'D' rows and 'L' logged strings.
//! Data-section messages are merged in time order, as the PX4 logger writes them.
//! Independent of autotune's reader on purpose: the fixtures must not inherit its bugs.

use std::collections::BTreeMap;

/// One field of a format: its ULog type, element count (1 for a scalar) and name.
#[derive(Clone, Debug)]
pub struct Field {
    /// ULog type name (`uint64_t`, `float`, `bool`, `char`, ...).
    pub ty: String,
    /// Element count; 1 for a scalar.
    pub count: usize,
    /// Field name.
    pub name: String,
}

/// Byte size of a basic ULog type; `None` for nested types, which this writer does not need.
pub fn type_size(ty: &str) -> Option<usize> {
    Some(match ty {
        "int8_t" | "uint8_t" | "bool" | "char" => 1,
        "int16_t" | "uint16_t" => 2,
        "int32_t" | "uint32_t" | "float" => 4,
        "int64_t" | "uint64_t" | "double" => 8,
        _ => return None,
    })
}

/// Parse a format spec such as `"uint64_t timestamp;float[2] x;bool fused;"`.
pub fn parse_spec(spec: &str) -> Vec<Field> {
    spec.split(';')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|item| {
            let (ty, name) = item.split_once(' ').expect("field is `type name`");
            let (ty, count) = match ty.split_once('[') {
                Some((t, n)) => (t, n.trim_end_matches(']').parse().expect("array size")),
                None => (ty, 1),
            };
            assert!(type_size(ty).is_some(), "unsupported type {ty}");
            Field {
                ty: ty.to_string(),
                count,
                name: name.trim().to_string(),
            }
        })
        .collect()
}

/// Encode one element of `ty` from an f64 (integers are truncated, bools are `v != 0`).
fn encode(ty: &str, v: f64, out: &mut Vec<u8>) {
    match ty {
        "int8_t" => out.push(v as i8 as u8),
        "uint8_t" | "char" => out.push(v as u8),
        "bool" => out.push(u8::from(v != 0.0)),
        "int16_t" => out.extend((v as i16).to_le_bytes()),
        "uint16_t" => out.extend((v as u16).to_le_bytes()),
        "int32_t" => out.extend((v as i32).to_le_bytes()),
        "uint32_t" => out.extend((v as u32).to_le_bytes()),
        "float" => out.extend((v as f32).to_le_bytes()),
        "int64_t" => out.extend((v as i64).to_le_bytes()),
        "uint64_t" => out.extend((v as u64).to_le_bytes()),
        "double" => out.extend(v.to_le_bytes()),
        _ => unreachable!("checked by parse_spec"),
    }
}

/// A row's values by field name; a missing field (or missing trailing elements) is zero.
pub type Values<'a> = &'a [(&'a str, &'a [f64])];

/// Build the bytes of a data row of `fields` from `values`, without a trailing `_padding`
/// field (PX4 does not write it, so readers must accept such short rows).
pub fn encode_row(fields: &[Field], values: Values) -> Vec<u8> {
    for (name, _) in values {
        assert!(
            fields.iter().any(|f| f.name == *name),
            "no field {name} in the format"
        );
    }
    let mut out = Vec::new();
    for (i, f) in fields.iter().enumerate() {
        if i + 1 == fields.len() && f.name.starts_with("_padding") {
            break;
        }
        let given = values.iter().find(|(n, _)| *n == f.name).map(|(_, v)| *v);
        for k in 0..f.count {
            encode(
                &f.ty,
                given.and_then(|v| v.get(k)).copied().unwrap_or(0.0),
                &mut out,
            );
        }
    }
    out
}

fn message(kind: u8, payload: &[u8]) -> Vec<u8> {
    let len = u16::try_from(payload.len()).expect("ULog message under 64 kB");
    let mut out = len.to_le_bytes().to_vec();
    out.push(kind);
    out.extend_from_slice(payload);
    out
}

fn key_value(key: &str, value: &[u8]) -> Vec<u8> {
    let mut p = vec![u8::try_from(key.len()).expect("key under 256 bytes")];
    p.extend_from_slice(key.as_bytes());
    p.extend_from_slice(value);
    p
}

/// A parameter value as PX4 stores it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Param {
    /// `float NAME`.
    Float(f32),
    /// `int32_t NAME`.
    Int(i32),
}

impl Param {
    fn key_value(self, name: &str) -> Vec<u8> {
        match self {
            Param::Float(v) => key_value(&format!("float {name}"), &v.to_le_bytes()),
            Param::Int(v) => key_value(&format!("int32_t {name}"), &v.to_le_bytes()),
        }
    }
}

enum Pending {
    Row { sub: usize, bytes: Vec<u8> },
    Param(Vec<u8>),
    Log(Vec<u8>),
}

/// Collects a log's definitions and time-stamped messages; [`ULogWriter::finish`] writes them.
pub struct ULogWriter {
    start_us: u64,
    infos: Vec<Vec<u8>>,
    params: Vec<Vec<u8>>,
    formats: BTreeMap<String, Vec<Field>>,
    format_order: Vec<String>,
    subs: Vec<(String, u8)>,
    pending: Vec<(u64, usize, Pending)>,
}

impl ULogWriter {
    /// A log whose header start timestamp is `start_us` (µs since boot).
    pub fn new(start_us: u64) -> Self {
        ULogWriter {
            start_us,
            infos: Vec::new(),
            params: Vec::new(),
            formats: BTreeMap::new(),
            format_order: Vec::new(),
            subs: Vec::new(),
            pending: Vec::new(),
        }
    }

    /// 'I' message `char[N] key` = `value`.
    pub fn info_str(&mut self, key: &str, value: &str) -> &mut Self {
        self.infos.push(key_value(
            &format!("char[{}] {key}", value.len()),
            value.as_bytes(),
        ));
        self
    }

    /// 'I' message `uint32_t key` = `value` (e.g. `ver_sw_release`).
    pub fn info_u32(&mut self, key: &str, value: u32) -> &mut Self {
        self.infos
            .push(key_value(&format!("uint32_t {key}"), &value.to_le_bytes()));
        self
    }

    /// A parameter's initial value ('P' before the data section).
    pub fn param(&mut self, name: &str, value: Param) -> &mut Self {
        self.params.push(value.key_value(name));
        self
    }

    /// A parameter change at `t_us` ('P' inside the data section).
    pub fn param_change(&mut self, t_us: u64, name: &str, value: Param) -> &mut Self {
        let n = self.pending.len();
        self.pending
            .push((t_us, n, Pending::Param(value.key_value(name))));
        self
    }

    /// A logged string ('L') at `t_us`; `level` is the syslog digit ('0'..'7').
    pub fn log_string(&mut self, t_us: u64, level: u8, text: &str) -> &mut Self {
        let mut p = vec![level];
        p.extend(t_us.to_le_bytes());
        p.extend_from_slice(text.as_bytes());
        let n = self.pending.len();
        self.pending.push((t_us, n, Pending::Log(p)));
        self
    }

    /// Define topic `name` with `spec` ('F'); a second definition must be the same.
    pub fn format(&mut self, name: &str, spec: &str) -> &mut Self {
        let fields = parse_spec(spec);
        if self.formats.insert(name.to_string(), fields).is_none() {
            self.format_order.push(name.to_string());
        }
        self
    }

    /// The parsed fields of a defined topic.
    pub fn fields(&self, name: &str) -> &[Field] {
        &self.formats[name]
    }

    fn sub(&mut self, topic: &str, multi_id: u8) -> usize {
        assert!(
            self.formats.contains_key(topic),
            "topic {topic} has no format"
        );
        match self
            .subs
            .iter()
            .position(|(t, m)| t == topic && *m == multi_id)
        {
            Some(i) => i,
            None => {
                self.subs.push((topic.to_string(), multi_id));
                self.subs.len() - 1
            }
        }
    }

    /// A row of `topic` instance `multi_id`, placed in the log by its `timestamp` field.
    pub fn data(&mut self, topic: &str, multi_id: u8, values: Values) -> &mut Self {
        let t = values
            .iter()
            .find(|(n, _)| *n == "timestamp")
            .and_then(|(_, v)| v.first())
            .map_or(0, |t| *t as u64);
        self.data_at(t, topic, multi_id, values)
    }

    /// A row placed in the log at `order_us` whatever its own `timestamp` field says (a
    /// publisher that writes zero timestamps is still logged when it publishes).
    pub fn data_at(
        &mut self,
        order_us: u64,
        topic: &str,
        multi_id: u8,
        values: Values,
    ) -> &mut Self {
        let sub = self.sub(topic, multi_id);
        let bytes = encode_row(&self.formats[topic], values);
        let n = self.pending.len();
        self.pending
            .push((order_us, n, Pending::Row { sub, bytes }));
        self
    }

    /// The whole file.
    pub fn finish(&self) -> Vec<u8> {
        let mut out = b"ULog\x01\x12\x35".to_vec();
        out.push(1);
        out.extend(self.start_us.to_le_bytes());
        out.extend(message(b'B', &[0u8; 40]));
        for i in &self.infos {
            out.extend(message(b'I', i));
        }
        for name in &self.format_order {
            let spec: String = self.formats[name]
                .iter()
                .map(|f| {
                    if f.count == 1 && f.ty != "char" {
                        format!("{} {};", f.ty, f.name)
                    } else {
                        format!("{}[{}] {};", f.ty, f.count, f.name)
                    }
                })
                .collect();
            out.extend(message(b'F', format!("{name}:{spec}").as_bytes()));
        }
        for p in &self.params {
            out.extend(message(b'P', p));
        }
        let mut order: Vec<&(u64, usize, Pending)> = self.pending.iter().collect();
        order.sort_by_key(|(t, n, _)| (*t, *n));
        let mut announced = vec![false; self.subs.len()];
        for (_, _, m) in order {
            match m {
                Pending::Row { sub, bytes } => {
                    let id = u16::try_from(*sub).expect("under 65536 subscriptions");
                    if !announced[*sub] {
                        announced[*sub] = true;
                        let (topic, multi) = &self.subs[*sub];
                        let mut p = vec![*multi];
                        p.extend(id.to_le_bytes());
                        p.extend_from_slice(topic.as_bytes());
                        out.extend(message(b'A', &p));
                    }
                    let mut p = id.to_le_bytes().to_vec();
                    p.extend_from_slice(bytes);
                    out.extend(message(b'D', &p));
                }
                Pending::Param(p) => out.extend(message(b'P', p)),
                Pending::Log(p) => out.extend(message(b'L', p)),
            }
        }
        out
    }
}

impl ULogWriter {
    /// Rows written so far per (topic, multi_id).
    pub fn rows_written(&self) -> BTreeMap<(String, u8), usize> {
        let mut out = BTreeMap::new();
        for (_, _, m) in &self.pending {
            if let Pending::Row { sub, .. } = m {
                *out.entry(self.subs[*sub].clone()).or_insert(0) += 1;
            }
        }
        out
    }
}
