//! Shard files merged: each file's head read and checked against the others', the shares
//! put in order, and their chunks streamed into the one-process sums.

use std::path::Path;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde::Deserialize;

use super::format::{
    FORMAT, MAX_FILE, MergeProblem, MergeRefusal, ShardHead, ShardIndex, ShardSettings, VERSION,
};
use crate::cluster::SumsShape;
use crate::montecarlo::Share;
use crate::stats::Accumulator;

/// Open a shard file to read: a regular file of at most [`MAX_FILE`] bytes (checked on the
/// opened descriptor), noted as an input of this process.
fn open(path: &Path) -> Result<(std::fs::File, u64), MergeRefusal> {
    let file = crate::userfile::open(path)
        .map_err(|e| MergeRefusal::new(path, MergeProblem::Open(e.message)))?;
    crate::input::note_input(path);
    let len = file
        .metadata()
        .map_err(|e| MergeRefusal::new(path, MergeProblem::Unreadable(e.to_string())))?
        .len();
    if len > MAX_FILE {
        return Err(MergeRefusal::new(
            path,
            MergeProblem::TooLarge { limit: MAX_FILE },
        ));
    }
    Ok((file, len))
}

/// A shard file's head, its format and version checked. The file is streamed: the chunks'
/// sums are skipped without being held, so memory stays small whatever the file holds.
pub fn read_head(path: &Path) -> Result<ShardHead, MergeRefusal> {
    #[derive(Deserialize)]
    struct Head {
        format: Option<String>,
        version: Option<u32>,
        settings: Option<ShardSettings>,
        shard: Option<ShardIndex>,
    }
    let (file, _) = open(path)?;
    let reader = std::io::BufReader::with_capacity(1 << 16, file);
    let head: Head = serde_json::from_reader(reader)
        .map_err(|e| MergeRefusal::new(path, MergeProblem::NotJson(e.to_string())))?;
    if head.format.as_deref() != Some(FORMAT) {
        return Err(MergeRefusal::new(path, MergeProblem::Format));
    }
    if head.version != Some(VERSION) {
        return Err(MergeRefusal::new(
            path,
            MergeProblem::Version {
                found: head.version,
            },
        ));
    }
    let (Some(settings), Some(shard)) = (head.settings, head.shard) else {
        return Err(MergeRefusal::new(path, MergeProblem::Incomplete));
    };
    Ok(ShardHead {
        path: path.to_path_buf(),
        settings,
        shard,
    })
}

/// Check that `heads` are the shards of one check, every share of the count once, and
/// return them ordered by share. The count is bounded by the files given before anything
/// is sized by it.
pub fn plan(heads: &[ShardHead]) -> Result<Vec<&ShardHead>, MergeRefusal> {
    let Some(first) = heads.first() else {
        return Err(MergeRefusal::new(
            Path::new("autotune merge"),
            MergeProblem::NoFiles,
        ));
    };
    let s = &first.settings;
    let count = first.shard.count;
    for h in heads {
        if let Some(field) = first_difference(s, &h.settings) {
            return Err(MergeRefusal::new(
                &h.path,
                MergeProblem::Differs {
                    field,
                    first: first.path.clone(),
                },
            ));
        }
        if h.shard.count != count {
            return Err(MergeRefusal::new(
                &h.path,
                MergeProblem::OtherCount {
                    index: h.shard.index,
                    count: h.shard.count,
                    first: first.path.clone(),
                    first_count: count,
                },
            ));
        }
        if h.shard.index >= count {
            return Err(MergeRefusal::new(
                &h.path,
                MergeProblem::OutOfRange {
                    index: h.shard.index,
                    count,
                },
            ));
        }
    }
    // Each share once: the count cannot exceed the files given, or some share is missing.
    let mut ordered: Vec<&ShardHead> = heads.iter().collect();
    ordered.sort_by_key(|h| h.shard.index);
    for w in ordered.windows(2) {
        if w[0].shard.index == w[1].shard.index {
            return Err(MergeRefusal::new(
                &w[1].path,
                MergeProblem::Duplicate {
                    index: w[1].shard.index,
                    count,
                    other: w[0].path.clone(),
                },
            ));
        }
    }
    if let Some(missing) = (0..count).find(|&i| ordered.get(i).is_none_or(|h| h.shard.index != i)) {
        return Err(MergeRefusal::new(
            &first.path,
            MergeProblem::Missing {
                index: missing,
                count,
            },
        ));
    }
    Ok(ordered)
}

/// What one shard file's reader hands on: chunk `c`'s sums, or the end of the file with
/// the number of chunks it held, or why it stopped.
enum Read {
    Chunk(usize, Box<Accumulator>),
    End,
    Refused(MergeRefusal),
}

/// The merged sums of the shards `ordered` (one per share, in share order, as [`plan`]
/// returns them), whose settings give `shape`: chunk c from share c mod n, merged in chunk
/// order into fresh sums, which is what one process computes, bit for bit.
///
/// Each file is streamed by a reader thread of its own that decodes one chunk at a time
/// and hands it on through a channel of one: memory stays at about one chunk per file (a
/// wave), whatever the files hold. A chunk's text is read only up to the longest its shape
/// can encode to, and decoded only when its shape's bytes are there, so nothing is sized by
/// a number the file declares but does not back. The merged sums are allocated once the
/// first chunk has shown that its shape is real.
pub fn merge_stream(
    ordered: &[&ShardHead],
    shape_of: &ShardSettings,
) -> Result<Accumulator, MergeRefusal> {
    let shape = shape_of.shape();
    let count = ordered.len();
    std::thread::scope(|scope| {
        let mut readers = Vec::with_capacity(count);
        for h in ordered {
            let (tx, rx) = std::sync::mpsc::sync_channel::<Read>(1);
            let share = Share::new(h.shard.index, count)
                .map_err(|e| MergeRefusal::new(&h.path, MergeProblem::Share(e)))?;
            let shape = &shape;
            std::thread::Builder::new()
                .stack_size(1 << 20)
                .spawn_scoped(scope, move || stream_chunks(h, share, shape, &tx))
                .map_err(|e| MergeRefusal::new(&h.path, MergeProblem::Reader(e.to_string())))?;
            readers.push((h, rx));
        }
        let mut merged: Option<Accumulator> = None;
        let chunks = shape.chunks();
        for c in 0..chunks {
            let (h, rx) = &readers[c % count];
            match rx.recv() {
                Ok(Read::Chunk(got, sums)) if got == c => {
                    merged.get_or_insert_with(|| shape.empty()).merge(&sums);
                }
                Ok(Read::Chunk(got, _)) => {
                    return Err(MergeRefusal::new(
                        &h.path,
                        MergeProblem::OutOfOrder { got, want: c },
                    ));
                }
                Ok(Read::End) | Err(_) => {
                    return Err(MergeRefusal::new(&h.path, MergeProblem::Truncated(c)));
                }
                Ok(Read::Refused(r)) => return Err(r),
            }
        }
        for (h, rx) in &readers {
            match rx.recv() {
                Ok(Read::End) => {}
                Ok(Read::Refused(r)) => return Err(r),
                Ok(Read::Chunk(c, _)) => {
                    return Err(MergeRefusal::new(
                        &h.path,
                        MergeProblem::Extra { chunk: c, chunks },
                    ));
                }
                Err(_) => {
                    return Err(MergeRefusal::new(&h.path, MergeProblem::Stopped));
                }
            }
        }
        merged.ok_or_else(|| MergeRefusal::new(&ordered[0].path, MergeProblem::NoChunks))
    })
}

/// A reader that counts what is read through it against a budget the caller resets: the
/// longest text one chunk may take.
struct Budget<R> {
    inner: R,
    left: std::rc::Rc<std::cell::Cell<u64>>,
}

impl<R: std::io::Read> std::io::Read for Budget<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self.left.get();
        if left == 0 {
            return Err(std::io::Error::other(
                "a chunk's sums are longer than its shape allows",
            ));
        }
        let n = buf.len().min(usize::try_from(left).unwrap_or(usize::MAX));
        let got = self.inner.read(&mut buf[..n])?;
        self.left.set(left - got as u64);
        Ok(got)
    }
}

/// The longest base64 text chunk `c` of `shape` can take (every divergence kept, with its
/// longest reason), with room for the JSON around it; `None` where it overflows.
fn longest_chunk_text(shape: &SumsShape, c: usize) -> Option<u64> {
    let least = crate::records::min_sums_len(&shape.chunk(c))?;
    // Each of at most 64 kept divergences: run, step, cause, reason length, reason.
    let most = least.checked_add(64 * (8 + 8 + 1 + 8 + 1000))?;
    (most.checked_add(2)? / 3)
        .checked_mul(4)?
        .checked_add(4096)
        .map(|x| x as u64)
}

/// Stream `h`'s chunks into `tx`: each checked to be the share's next chunk of the check,
/// its text bounded by its shape's longest, decoded against its shape.
fn stream_chunks(
    h: &ShardHead,
    share: Share,
    shape: &SumsShape,
    tx: &std::sync::mpsc::SyncSender<Read>,
) {
    use serde::de::{self, DeserializeSeed, MapAccess, SeqAccess, Visitor};
    let refuse = |why: String| {
        let _ = tx.send(Read::Refused(MergeRefusal::new(
            &h.path,
            MergeProblem::Chunks(why),
        )));
    };
    let file = match open(&h.path) {
        Ok((f, _)) => f,
        Err(r) => return drop(tx.send(Read::Refused(r))),
    };
    // The head was read before: the budget covers it until the chunks start.
    let left = std::rc::Rc::new(std::cell::Cell::new(MAX_FILE));
    let reader = Budget {
        inner: std::io::BufReader::with_capacity(1 << 16, file),
        left: left.clone(),
    };

    struct Ctx<'a> {
        h: &'a ShardHead,
        share: Share,
        shape: &'a SumsShape,
        tx: &'a std::sync::mpsc::SyncSender<Read>,
        left: std::rc::Rc<std::cell::Cell<u64>>,
    }
    struct File<'a>(&'a Ctx<'a>);
    struct Chunks<'a>(&'a Ctx<'a>);
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Chunk {
        chunk: usize,
        sums: String,
    }
    impl<'de> Visitor<'de> for File<'_> {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a shard file")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
            let (mut settings, mut shard) = (None::<ShardSettings>, None::<ShardIndex>);
            while let Some(key) = map.next_key::<String>()? {
                match key.as_str() {
                    "chunks" => map.next_value_seed(Chunks(self.0))?,
                    "settings" => settings = Some(map.next_value()?),
                    "shard" => shard = Some(map.next_value()?),
                    _ => {
                        map.next_value::<de::IgnoredAny>()?;
                    }
                }
            }
            // The file must still be the one whose head was read.
            if settings.as_ref() != Some(&self.0.h.settings) || shard != Some(self.0.h.shard) {
                return Err(de::Error::custom("the file changed while it was merged"));
            }
            Ok(())
        }
    }
    impl<'de> DeserializeSeed<'de> for File<'_> {
        type Value = ();
        fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_map(self)
        }
    }
    impl<'de> DeserializeSeed<'de> for Chunks<'_> {
        type Value = ();
        fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_seq(self)
        }
    }
    impl<'de> Visitor<'de> for Chunks<'_> {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a list of chunks")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            let cx = self.0;
            let count = cx.share.count();
            // The share's chunks, ascending: index, index + n, …
            let mut next = cx.share.index();
            loop {
                let budget =
                    longest_chunk_text(cx.shape, next.min(cx.shape.chunks().saturating_sub(1)))
                        .unwrap_or(0);
                cx.left.set(budget);
                let Some(chunk) = seq.next_element::<Chunk>()? else {
                    break;
                };
                if chunk.chunk != next {
                    return Err(de::Error::custom(
                        if cx.share.owns_chunk(chunk.chunk) && chunk.chunk < cx.shape.chunks() {
                            format!(
                                "chunk {} comes where chunk {next} belongs (chunks ascend, each once)",
                                chunk.chunk
                            )
                        } else {
                            format!(
                                "chunk {} is not shard {}/{count}'s",
                                chunk.chunk,
                                cx.share.index()
                            )
                        },
                    ));
                }
                if chunk.chunk >= cx.shape.chunks() {
                    return Err(de::Error::custom(format!(
                        "chunk {} is not one of the check's {} chunks",
                        chunk.chunk,
                        cx.shape.chunks()
                    )));
                }
                let bytes = STANDARD.decode(&chunk.sums).map_err(|e| {
                    de::Error::custom(format!("chunk {}: not base64: {e}", chunk.chunk))
                })?;
                drop(chunk.sums);
                let sums = cx
                    .shape
                    .decode(next, &bytes)
                    .map_err(|e| de::Error::custom(format!("chunk {next}: {e}")))?;
                if cx.tx.send(Read::Chunk(next, Box::new(sums))).is_err() {
                    return Err(de::Error::custom("stopped"));
                }
                next += count;
            }
            cx.left.set(MAX_FILE);
            Ok(())
        }
    }

    let cx = Ctx {
        h,
        share,
        shape,
        tx,
        left,
    };
    let mut de = serde_json::Deserializer::from_reader(reader);
    match File(&cx).deserialize(&mut de).and_then(|()| de.end()) {
        Ok(()) => drop(tx.send(Read::End)),
        Err(e) => refuse(e.to_string()),
    }
}

/// The first setting in which `b` differs from `a`, by the name the file gives it.
pub(super) fn first_difference(a: &ShardSettings, b: &ShardSettings) -> Option<&'static str> {
    let fields: [(&'static str, bool); 15] = [
        ("problem", a.problem == b.problem),
        ("file", a.file == b.file),
        ("sha256 (the problem file's digest)", a.sha256 == b.sha256),
        ("params", a.params == b.params),
        ("runs", a.runs == b.runs),
        ("steps", a.steps == b.steps),
        ("seed", a.seed == b.seed),
        ("alpha", a.alpha == b.alpha),
        ("lags", a.lags == b.lags),
        ("gate", a.gate == b.gate),
        ("engine", a.engine == b.engine),
        ("nis_only", a.nis_only == b.nis_only),
        ("n_x", a.n_x == b.n_x),
        ("n_z", a.n_z == b.n_z),
        ("settings", a == b),
    ];
    fields.iter().find(|(_, same)| !same).map(|(f, _)| *f)
}
