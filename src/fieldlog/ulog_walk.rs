//! Feeding a ULog file to the `px4-ulog` crate's parser one checked message at a time.
//!
//! The crate's own file reader (`read_file_with_simple_callback`) hands it the raw bytes, and
//! some damaged files then panic or run away inside the crate (px4-ulog 0.6.1):
//!
//! - an 'A' (subscription) message shorter than 3 bytes, or a 'P' (parameter) message that is
//!   empty or whose key length runs past its end, panics on a slice index;
//! - when the data section starts, every format is flattened recursively: formats nested
//!   deeper than a few thousand levels overflow the stack, and arrays of zero-sized formats
//!   (`e:` then `a:e[32767] x;`, `b:a[32767] y;`, …) cost 32767^depth steps for a few bytes;
//! - each subscription copies its flattened format, so a format of 32000 one-byte fields
//!   subscribed under 65000 msg_ids asks for hundreds of gigabytes from a file of a megabyte;
//! - while it looks for the flag bits it reads the file one byte per system call.
//!
//! So this walker reads the file itself (the 16-byte header, then per message `u16 size`,
//! `u8 type`, payload), refuses the messages the crate would panic on, counts what the
//! flattening and the subscriptions will cost (and how deep the formats nest) before the
//! crate does it, and passes whole messages to [`LogParser::consume_bytes`]. It follows the
//! crate's reading of appended data (the flag bits' offsets: the main section ends at the
//! first, each section at the next) and its verdict on how the file ended.

use std::collections::{HashMap, HashSet};
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use px4_ulog::stream_parser::LogParser;

use crate::input::FileError;
use crate::records::shown_up_to;

/// Flattened fields the crate may build (all formats when the data starts, and a copy of a
/// format per subscription) before the file is refused. A full PX4 log needs a few tens of
/// thousands; each costs the crate about 200 bytes.
pub(super) const MAX_FIELD_COPIES: u64 = 300_000;
/// How deep formats may nest (PX4 nests 3 or 4 levels).
pub(super) const MAX_NESTING: usize = 64;

/// How the file ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum Ending {
    /// On a message boundary.
    Complete,
    /// Partway through a message.
    Truncated,
    /// At a damaged message in the data section (the data before it were read).
    Malformed(String),
}

/// The formats seen before the data section, as the crate will flatten them: per format,
/// its fields' types and repetitions.
#[derive(Default)]
struct Formats {
    fields: HashMap<String, Vec<(String, u64)>>,
    /// Flattening steps per format, once counted, and how deep it nests.
    cost: HashMap<String, (u64, usize)>,
}

fn primitive(ty: &str) -> bool {
    matches!(
        ty,
        "int8_t"
            | "uint8_t"
            | "int16_t"
            | "uint16_t"
            | "int32_t"
            | "uint32_t"
            | "int64_t"
            | "uint64_t"
            | "float"
            | "double"
            | "bool"
            | "char"
    )
}

/// Too deep to count: the formats nest beyond [`MAX_NESTING`].
struct TooDeep;

impl Formats {
    /// Note an 'F' message the crate accepted: `name:type field;type[n] field;…`. Fields it
    /// would not have accepted are left out (they cannot be reached).
    fn add(&mut self, payload: &[u8]) {
        let Ok(text) = std::str::from_utf8(payload) else {
            return;
        };
        let Some((name, body)) = text.split_once(':') else {
            return;
        };
        let mut fields = Vec::new();
        for f in body.split(';').filter(|f| !f.is_empty()) {
            let Some((ty, _)) = f.split_once(' ') else {
                continue;
            };
            let (base, n) = match ty.split_once('[') {
                Some((base, rest)) => {
                    let Some(n) = rest.strip_suffix(']').and_then(|n| n.parse::<i16>().ok()) else {
                        continue;
                    };
                    (base, n.max(0) as u64)
                }
                None => (ty, 1),
            };
            fields.push((base.to_string(), n));
        }
        self.fields.insert(name.to_string(), fields);
        self.cost.clear();
    }

    /// The steps the crate takes to flatten format `name` (one per field element, nested
    /// ones included): an upper bound of the fields it builds.
    fn cost(&mut self, name: &str) -> Result<u64, TooDeep> {
        let mut visiting = HashSet::new();
        self.cost_at(name, 0, &mut visiting).map(|(c, _)| c)
    }

    /// The cost of format `name` reached at nesting `depth`, and how deep it nests below.
    fn cost_at(
        &mut self,
        name: &str,
        depth: usize,
        visiting: &mut HashSet<String>,
    ) -> Result<(u64, usize), TooDeep> {
        if depth > MAX_NESTING {
            return Err(TooDeep);
        }
        if let Some(&(c, h)) = self.cost.get(name) {
            return if depth + h > MAX_NESTING {
                Err(TooDeep)
            } else {
                Ok((c, h))
            };
        }
        // An undefined or circular format: the crate stops there with an error.
        let Some(fields) = self.fields.get(name).cloned() else {
            return Ok((1, 0));
        };
        if !visiting.insert(name.to_string()) {
            return Ok((1, 0));
        }
        let (mut total, mut height) = (0u64, 0usize);
        for (ty, n) in &fields {
            let each = if primitive(ty) {
                1
            } else {
                let (c, h) = self.cost_at(ty, depth + 1, visiting)?;
                height = height.max(h + 1);
                1u64.saturating_add(c)
            };
            total = total.saturating_add(n.saturating_mul(each));
        }
        visiting.remove(name);
        self.cost.insert(name.to_string(), (total, height));
        Ok((total, height))
    }

    /// The steps to flatten every format, as the crate does when the data section starts.
    fn total(&mut self) -> Result<u64, TooDeep> {
        let names: Vec<String> = self.fields.keys().cloned().collect();
        let mut total = 0u64;
        for n in names {
            total = total.saturating_add(self.cost(&n)?);
        }
        Ok(total)
    }
}

/// Why a message cannot be given to the crate (it would panic on it), if so.
fn unsafe_for_parser(typ: u8, p: &[u8]) -> Option<String> {
    match typ {
        b'A' if p.len() < 3 => Some(format!(
            "a subscription ('A') message of {} bytes (at least 3)",
            p.len()
        )),
        b'P' if p.is_empty() => Some("an empty parameter ('P') message".into()),
        b'P' if 1 + p[0] as usize > p.len() => Some(format!(
            "a parameter ('P') message whose key of {} bytes runs past its {} bytes",
            p[0],
            p.len()
        )),
        _ => None,
    }
}

/// The messages that start the data section (the crate flattens the formats then).
fn starts_data(typ: u8) -> bool {
    matches!(typ, b'A' | b'L' | b'O' | b'S' | b'R' | b'C')
}

/// Read as many bytes as `buf` holds, fewer only at the end of the file.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// Feed the ULog file at `path` (its header already checked) to `parser` message by
/// message; `stop` is asked between messages. `Err` for a file whose header or definitions
/// are unreadable, or that would cost too much.
pub(super) fn feed_ulog(
    path: &Path,
    parser: &mut LogParser,
    stop: &dyn Fn() -> bool,
) -> Result<Ending, FileError> {
    let io = |e: std::io::Error| FileError::new(path, "", format!("cannot read: {e}"));
    let file = crate::userfile::open_io(path).map_err(io)?;
    let file_len = file.metadata().map_err(io)?.len();
    let mut w = Walker {
        path,
        parser,
        r: BufReader::with_capacity(1 << 16, file),
        msg: vec![0u8; 16],
        formats: Formats::default(),
        copies: 0,
        end: None,
        sections: Vec::new(),
        offsets_known: false,
        pos: 16,
    };
    if read_full(&mut w.r, &mut w.msg).map_err(io)? < 16 {
        return Err(FileError::new(
            path,
            "",
            "not a ULog file (shorter than its header)",
        ));
    }
    if let Err(e) = w.parser.consume_bytes(&w.msg) {
        return w.damaged(0, &e.description, false);
    }
    loop {
        let partial = match w.section(stop)? {
            Section::Ended { partial } => partial,
            Section::Stopped(ending) => return Ok(ending),
        };
        let Some((start, next_end)) = w.sections.pop() else {
            return Ok(if partial {
                Ending::Truncated
            } else {
                Ending::Complete
            });
        };
        // A message cut by the section's end is dropped, as the crate does. A section that
        // starts past the end of the file is empty (an offset beyond 2^63 would not even
        // seek).
        if start >= file_len {
            w.pos = start;
            w.end = Some(start);
            continue;
        }
        w.r.seek(SeekFrom::Start(start)).map_err(io)?;
        w.pos = start;
        w.end = next_end;
    }
}

/// How reading a section's messages ended.
enum Section {
    /// At its end; `partial`: partway through a message.
    Ended { partial: bool },
    /// Before it: asked to stop, or at a damaged message in the data.
    Stopped(Ending),
}

/// One file being fed to the parser: where it is, the formats defined so far and what
/// flattening them costs, and the sections of appended data still to read.
struct Walker<'a, 'p> {
    path: &'a Path,
    parser: &'a mut LogParser<'p>,
    r: BufReader<std::fs::File>,
    /// The current message.
    msg: Vec<u8>,
    formats: Formats,
    /// Flattened fields the crate builds for the formats and the subscriptions so far.
    copies: u64,
    /// Where the current section ends (None: at the end of the file).
    end: Option<u64>,
    /// The sections of appended data still to read, the next last.
    sections: Vec<(u64, Option<u64>)>,
    offsets_known: bool,
    /// The file offset of the current message.
    pos: u64,
}

impl Walker<'_, '_> {
    fn io(&self, e: std::io::Error) -> FileError {
        FileError::new(self.path, "", format!("cannot read: {e}"))
    }

    /// A damaged message at byte `at`: in the data section it ends the readable data;
    /// before it, the file is unreadable.
    fn damaged<T: From<Ending>>(&self, at: u64, why: &str, in_data: bool) -> Result<T, FileError> {
        let why = format!(
            "message at byte {at}: {}",
            shown_up_to(why.lines().next().unwrap_or(""), 160)
        );
        if in_data {
            Ok(Ending::Malformed(why).into())
        } else {
            Err(FileError::new(
                self.path,
                "",
                format!("not a readable ULog file (its header or definitions are damaged): {why}"),
            ))
        }
    }

    /// Read the current section's messages into the parser.
    fn section(&mut self, stop: &dyn Fn() -> bool) -> Result<Section, FileError> {
        loop {
            if stop() {
                return Ok(Section::Stopped(Ending::Complete));
            }
            let room = self.end.map_or(u64::MAX, |e| e.saturating_sub(self.pos));
            if room == 0 {
                return Ok(Section::Ended { partial: false });
            }
            self.msg.resize(3, 0);
            let got = read_full(&mut self.r, &mut self.msg[..3]).map_err(|e| self.io(e))?;
            if got == 0 {
                return Ok(Section::Ended { partial: false });
            }
            if got < 3 {
                return Ok(Section::Ended { partial: true });
            }
            let size = u16::from_le_bytes([self.msg[0], self.msg[1]]) as usize;
            let typ = self.msg[2];
            if (3 + size) as u64 > room {
                return Ok(Section::Ended { partial: true });
            }
            self.msg.resize(3 + size, 0);
            if read_full(&mut self.r, &mut self.msg[3..]).map_err(|e| self.io(e))? < size {
                return Ok(Section::Ended { partial: true });
            }
            if let Some(why) = unsafe_for_parser(typ, &self.msg[3..]) {
                return self.damaged(self.pos, &why, self.parser.in_data());
            }
            self.count_copies(typ)?;
            if let Err(e) = self.parser.consume_bytes(&self.msg) {
                // Damage in the data section ends the readable data; before it, the file.
                return self.damaged(self.pos, &e.description, self.parser.in_data());
            }
            if typ == b'F' && !self.parser.in_data() {
                self.formats.add(&self.msg[3..]);
            }
            self.pos += self.msg.len() as u64;
            if typ == b'B' && !self.offsets_known && self.parser.header_complete() {
                self.read_offsets();
            }
        }
    }

    /// Count the flattened fields the current message (of type `typ`) makes the crate
    /// build, before it does: every format when it starts the data, a format's copy when
    /// it subscribes to it. `Err` past [`MAX_FIELD_COPIES`] or [`MAX_NESTING`].
    fn count_copies(&mut self, typ: u8) -> Result<(), FileError> {
        let pos = self.pos;
        if starts_data(typ) && !self.parser.in_data() && self.parser.header_complete() {
            let why = match self.formats.total() {
                Err(TooDeep) => Some(format!("formats nest deeper than {MAX_NESTING} levels")),
                Ok(c) if c > MAX_FIELD_COPIES => Some(format!(
                    "the formats declare about {c} fields (nested arrays counted), more than {MAX_FIELD_COPIES}"
                )),
                Ok(c) => {
                    self.copies = c;
                    None
                }
            };
            if let Some(why) = why {
                return Err(FileError::new(
                    self.path,
                    "",
                    format!("message at byte {pos} starts the data, but {why}"),
                ));
            }
        }
        if typ == b'A' && self.parser.header_complete() {
            // Each subscription copies its format's flattened fields.
            let name = String::from_utf8_lossy(&self.msg[6..]).into_owned();
            let c = self.formats.cost(&name).unwrap_or(u64::MAX);
            self.copies = self.copies.saturating_add(c);
            if self.copies > MAX_FIELD_COPIES {
                return Err(FileError::new(
                    self.path,
                    "",
                    format!(
                        "message at byte {pos}: the subscriptions copy more than {MAX_FIELD_COPIES} fields (formats subscribed too many times)"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The sections of appended data, from the flag bits: the main section ends at the
    /// first appended-data offset, each appended section at the next one (or at the end
    /// of the file).
    fn read_offsets(&mut self) {
        self.offsets_known = true;
        let offsets: Vec<u64> = self
            .parser
            .appended_offsets()
            .iter()
            .copied()
            .filter(|&o| o != 0)
            .collect();
        if let Some(&first) = offsets.first() {
            self.end = Some(first);
            for (i, &o) in offsets.iter().enumerate() {
                self.sections.push((o, offsets.get(i + 1).copied()));
            }
            self.sections.reverse();
        }
    }
}

impl From<Ending> for Section {
    fn from(e: Ending) -> Section {
        Section::Stopped(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flattening_cost_counts_nested_and_zero_sized_arrays() {
        let mut f = Formats::default();
        f.add(b"e:");
        f.add(b"a:e[32767] x;float[2] y;");
        f.add(b"b:a[32767] z;");
        f.add(b"c:uint64_t timestamp;float[-3] w;");
        assert_eq!(f.cost("a").ok(), Some(32767 + 2));
        assert_eq!(f.cost("b").ok(), Some(32767 * (1 + 32769)));
        assert_eq!(f.cost("c").ok(), Some(1));
        // Undefined and circular formats cost one step: the crate stops there.
        f.add(b"d:d[5] self;nosuch[3] n;");
        assert_eq!(f.cost("d").ok(), Some(5 * 2 + 3 * 2));
    }

    #[test]
    fn a_chain_of_formats_deeper_than_the_limit_is_too_deep() {
        let mut f = Formats::default();
        f.add(b"f0:float x;");
        for k in 1..=MAX_NESTING + 2 {
            f.add(format!("f{k}:f{} a;", k - 1).as_bytes());
        }
        assert!(f.cost(&format!("f{}", MAX_NESTING + 2)).is_err());
        assert!(f.cost("f3").is_ok());
    }

    #[test]
    fn messages_the_crate_would_panic_on_are_named() {
        assert!(unsafe_for_parser(b'A', &[0, 1]).is_some());
        assert!(unsafe_for_parser(b'A', &[0, 1, 0]).is_none());
        assert!(unsafe_for_parser(b'P', &[]).is_some());
        assert!(unsafe_for_parser(b'P', &[200, b'x']).is_some());
        assert!(unsafe_for_parser(b'P', b"\x01xabcd").is_none());
        assert!(unsafe_for_parser(b'D', &[]).is_none());
    }
}
