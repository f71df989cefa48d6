//! A chunk's sums on the wire: what a worker that computes the statistics in its own process
//! (through this library, its C ABI or its Python package) answers instead of records.
//!
//! The sums are the [`Accumulator`] the records path would have built from the same records,
//! with each run's fingerprint for the seed-contract check; every number travels as its IEEE
//! bits (little-endian, base64 in the JSON answer), so autotune merges exactly what the
//! worker summed and the statistics equal the records path's bit for bit. A sums answer is
//! an untrusted input like a records file: [`decode`] checks its shapes against the
//! request, and that its numbers could have come from records (finite, counts whole and
//! within the runs asked for), before autotune merges it.
//!
//! MPI ranks send each other the same sums packed ([`encode_packed_into`]): a vector that
//! is the square of the one before it, or whole numbers, goes short, to the same bits.

use base64::Engine;
use base64::engine::general_purpose::STANDARD;

use crate::stats::{Accumulator, Divergence, StopCause};

mod error;
mod fields;
mod packing;
mod reader;

pub use error::WireError;
use fields::{counts, counts_ref, scalars, scalars_ref, vectors, vectors_ref};
use reader::Reader;

/// The first bytes of an encoded chunk: the format and its version.
const MAGIC: &[u8; 8] = b"ATSUMS2\0";
/// The packed form's ([`encode_packed_into`]): never read where the plain one is expected.
const MAGIC_PACKED: &[u8; 8] = b"ATSUMP2\0";

/// Longest divergence reason carried, in bytes (the records path keeps a worker's words
/// whole, but a reason is shown on one line of a report).
const MAX_REASON: usize = 1000;

/// What a sums answer must match: the request it answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkShape {
    /// The runs asked for, [a, b).
    pub runs: std::ops::Range<usize>,
    /// T.
    pub steps: usize,
    /// Whiteness lags.
    pub lags: usize,
    /// State components the sums keep.
    pub n_x: usize,
    /// Measurement components the sums keep.
    pub n_z: usize,
}

/// A chunk's sums and its runs' fingerprints (run a + i at index i).
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkSums {
    /// The sums, as the records path builds them.
    pub sums: Accumulator,
    /// Each run's fingerprint, in run order.
    pub prints: Vec<u64>,
}

fn cause_byte(c: StopCause) -> u8 {
    match c {
        StopCause::Diverged => 0,
        StopCause::IllConditioned => 1,
        StopCause::TruthOverflow => 2,
    }
}

fn cause_of(b: u8) -> Option<StopCause> {
    match b {
        0 => Some(StopCause::Diverged),
        1 => Some(StopCause::IllConditioned),
        2 => Some(StopCause::TruthOverflow),
        _ => None,
    }
}

/// `chunk` of the runs `shape.runs` as the base64 text of a sums answer.
pub fn encode(chunk: &ChunkSums, shape: &ChunkShape) -> String {
    STANDARD.encode(encode_bytes(chunk, shape))
}

/// [`encode`] before base64.
pub fn encode_bytes(chunk: &ChunkSums, shape: &ChunkShape) -> Vec<u8> {
    let mut out = Vec::new();
    encode_into(&mut out, &chunk.sums, &chunk.prints, shape);
    out
}

/// Appends the bytes of [`encode_bytes`] for `sums` and the runs' fingerprints `prints` to
/// `out`, grown once: an MPI rank writes each of its runs' sums into one answer, without
/// copying a run's sums on the way.
pub fn encode_into(out: &mut Vec<u8>, sums: &Accumulator, prints: &[u64], shape: &ChunkShape) {
    write(out, sums, prints, shape, false);
}

/// [`encode_into`] in the packed form that MPI ranks of one job send each other: each
/// vector is sent whole, as the square of the vector before it (a single run's `nees_sq` is
/// its `nees_sum` squared), or as whole numbers of one or two bytes (counts, degrees of
/// freedom), whichever gives back its bits exactly. A run's own sums pack to about a third.
/// Read with [`decode_packed_bytes`]; shard files and workers keep the plain form.
pub fn encode_packed_into(
    out: &mut Vec<u8>,
    sums: &Accumulator,
    prints: &[u64],
    shape: &ChunkShape,
) {
    write(out, sums, prints, shape, true);
}

/// The packing of `v`, whose predecessor in wire order is `before`: the smallest that gives
/// back every bit.
fn packing_of(v: &[f64], before: Option<&Vec<f64>>) -> u8 {
    let same = |x: f64, y: f64| x.to_bits() == y.to_bits();
    if let Some(b) = before
        && b.len() == v.len()
        && v.iter().zip(b).all(|(&x, &y)| same(x, y * y))
    {
        packing::SQUARE
    } else if v.iter().all(|&x| same(x, f64::from(x as u8))) {
        packing::BYTES
    } else if v.iter().all(|&x| same(x, f64::from(x as u16))) {
        packing::PAIRS
    } else {
        packing::WHOLE
    }
}

fn write(out: &mut Vec<u8>, sums: &Accumulator, prints: &[u64], shape: &ChunkShape, packed: bool) {
    // The divergences kept (rare) and a packed form's tags may grow it again.
    out.reserve(min_len(shape).unwrap_or(0));
    let u = |out: &mut Vec<u8>, x: usize| out.extend_from_slice(&(x as u64).to_le_bytes());
    out.extend_from_slice(if packed { MAGIC_PACKED } else { MAGIC });
    for x in [
        shape.runs.start,
        shape.runs.end,
        shape.steps,
        shape.lags,
        shape.n_x,
        shape.n_z,
    ] {
        u(out, x);
    }
    let vs = vectors_ref(sums);
    for (i, (_, _, v)) in vs.iter().enumerate() {
        let tag = if packed {
            let tag = packing_of(v, i.checked_sub(1).map(|b| vs[b].2));
            out.push(tag);
            tag
        } else {
            packing::WHOLE
        };
        for &x in v.iter() {
            match tag {
                packing::SQUARE => {}
                packing::BYTES => out.push(x as u8),
                packing::PAIRS => out.extend_from_slice(&(x as u16).to_le_bytes()),
                _ => out.extend_from_slice(&x.to_bits().to_le_bytes()),
            }
        }
    }
    for (_, x) in scalars_ref(sums) {
        out.extend_from_slice(&x.to_bits().to_le_bytes());
    }
    for (_, x) in counts_ref(sums) {
        u(out, *x);
    }
    for x in &sums.meas_comp_runs {
        u(out, *x);
    }
    u(out, sums.divergences.len());
    for d in &sums.divergences {
        u(out, d.run);
        u(out, d.step);
        out.push(cause_byte(d.cause));
        let reason = &d.reason.as_bytes()[..floor_char(&d.reason, MAX_REASON)];
        u(out, reason.len());
        out.extend_from_slice(reason);
    }
    for p in prints {
        out.extend_from_slice(&p.to_le_bytes());
    }
}

/// The largest index ≤ `at` on a character boundary of `s`.
fn floor_char(s: &str, at: usize) -> usize {
    (0..=at.min(s.len()))
        .rev()
        .find(|&i| s.is_char_boundary(i))
        .unwrap_or(0)
}

/// The sums of a base64 sums answer, checked against `want` (the request it answers).
pub fn decode(text: &str, want: &ChunkShape) -> Result<ChunkSums, WireError> {
    let bytes = STANDARD
        .decode(text)
        .map_err(|e| WireError::Base64(e.to_string()))?;
    decode_bytes(&bytes, want)
}

/// The fewest bytes an encoded chunk of shape `want` can have (no divergence kept), `None`
/// where that overflows: the magic and header, the 27 vectors (T each for the 8 per-step
/// sums, n_x for 9, n_z for 6, L n_z for 4 whiteness sums), 3 scalars, 8 counts, n_z
/// per-component run counts, the count of divergences kept and a fingerprint per run.
pub fn min_len(want: &ChunkShape) -> Option<usize> {
    let words = [
        8usize.checked_mul(want.steps)?,
        9usize.checked_mul(want.n_x)?,
        7usize.checked_mul(want.n_z)?,
        want.lags.checked_mul(want.n_z)?.checked_mul(4)?,
        6 + 3 + 8 + 1,
        want.runs.len(),
    ];
    let words = words.iter().try_fold(0usize, |a, &w| a.checked_add(w))?;
    words.checked_mul(8)?.checked_add(MAGIC.len())
}

/// [`decode`] after base64. Nothing is allocated by a size the bytes do not back: they are
/// first checked to be at least [`min_len`] of the shape asked for.
pub fn decode_bytes(bytes: &[u8], want: &ChunkShape) -> Result<ChunkSums, WireError> {
    read(bytes, want, false)
}

/// The sums of [`encode_packed_into`]'s bytes, checked as [`decode_bytes`] checks, except
/// that no least length is asked before the reads (a packed vector may take no bytes).
pub fn decode_packed_bytes(bytes: &[u8], want: &ChunkShape) -> Result<ChunkSums, WireError> {
    read(bytes, want, true)
}

/// [`decode_packed_bytes`] into `into`, whose allocations are kept when it has `want`'s
/// shape (rank 0 of an MPI job reads every run of every rank into one), and the runs'
/// fingerprints. On an error `into` holds part of the answer.
pub fn decode_packed_bytes_into(
    bytes: &[u8],
    want: &ChunkShape,
    into: &mut Accumulator,
) -> Result<Vec<u64>, WireError> {
    read_into(bytes, want, true, into)
}

fn read(bytes: &[u8], want: &ChunkShape, packed: bool) -> Result<ChunkSums, WireError> {
    let mut sums = Accumulator::new(want.steps, want.n_x, want.n_z, want.lags);
    let prints = read_into(bytes, want, packed, &mut sums)?;
    Ok(ChunkSums { sums, prints })
}

fn read_into(
    bytes: &[u8],
    want: &ChunkShape,
    packed: bool,
    a: &mut Accumulator,
) -> Result<Vec<u64>, WireError> {
    // Every field is read below but the shape and the divergences, which are appended.
    let shaped = a.steps == want.steps
        && a.lags == want.lags
        && a.state_comp_total.len() == want.n_x
        && a.meas_comp_runs.len() == want.n_z;
    if !shaped {
        *a = Accumulator::new(want.steps, want.n_x, want.n_z, want.lags);
    }
    a.divergences.clear();
    let mut r = Reader { bytes, at: 0 };
    let magic = if packed { MAGIC_PACKED } else { MAGIC };
    if r.take(magic.len()).map_err(|_| WireError::Magic)? != magic {
        return Err(WireError::Magic);
    }
    let header = [
        ("first run", want.runs.start),
        ("run end", want.runs.end),
        ("steps", want.steps),
        ("lags", want.lags),
        ("state components", want.n_x),
        ("measurement components", want.n_z),
    ];
    for (what, expected) in header {
        let got = r.u64()?;
        if got != expected as u64 {
            return Err(WireError::Shape {
                what,
                got: usize::try_from(got).unwrap_or(usize::MAX),
                want: expected,
            });
        }
    }
    // A packed vector may take no bytes at all, so only the plain form has a least length.
    // The packed form passes between the ranks of one job, whose rank 0 asked for `want`
    // and holds sums of that shape already; every read is checked either way.
    let least = if packed {
        Some(magic.len())
    } else {
        min_len(want)
    };
    if least.is_none_or(|least| bytes.len() < least) {
        return Err(WireError::Truncated(bytes.len()));
    }
    let runs = want.runs.len();
    // Whole counts of samples are at most one per run and step (per lag for whiteness).
    let most = (runs as f64) * (want.steps as f64);
    let mut vs = vectors(a);
    for i in 0..vs.len() {
        let (before, rest) = vs.split_at_mut(i);
        let (what, whole, v) = &mut rest[0];
        let tag = if packed {
            r.take(1)?[0]
        } else {
            packing::WHOLE
        };
        let square_of = match (tag, before.last()) {
            (packing::SQUARE, Some((_, _, b))) if b.len() == v.len() => Some(&**b),
            (packing::SQUARE, _) | (4.., _) => {
                return Err(WireError::Impossible {
                    what,
                    value: format!("packed as {tag}"),
                });
            }
            _ => None,
        };
        r.vector(tag, square_of.map(Vec::as_slice), v)?;
        // Bytes and pairs are finite whole numbers already. Whole within 0..=most (below
        // 2^53) is `x as u64` giving x back: `fract` costs a software `trunc` on baseline
        // x86-64, a call per value of every run rank 0 reads.
        let bad = match (*whole, tag) {
            (false, packing::BYTES | packing::PAIRS) => None,
            (false, _) => v.iter().position(|x| !x.is_finite()),
            (true, _) => v
                .iter()
                .position(|&x| !((0.0..=most).contains(&x) && x as u64 as f64 == x)),
        };
        if let Some(k) = bad {
            return Err(WireError::Impossible {
                what,
                value: v[k].to_string(),
            });
        }
    }
    for (what, x) in scalars(a) {
        *x = r.f64()?;
        if !x.is_finite() {
            return Err(WireError::Impossible {
                what,
                value: x.to_string(),
            });
        }
    }
    for (what, x) in counts(a) {
        *x = r.size(what, runs)?;
    }
    if a.runs != runs {
        return Err(WireError::Shape {
            what: "runs summed",
            got: a.runs,
            want: runs,
        });
    }
    for x in a.meas_comp_runs.iter_mut() {
        *x = r.size("meas_comp_runs", runs)?;
    }
    let kept = r.size("divergences kept", a.diverged_runs)?;
    for i in 0..kept {
        let run = r.size("divergence run", usize::MAX)?;
        let step = r.size("divergence step", usize::MAX)?;
        let cause = cause_of(r.take(1)?[0]);
        let len = r.size("divergence reason length", MAX_REASON)?;
        let reason = std::str::from_utf8(r.take(len)?).ok().map(str::to_string);
        match (cause, reason) {
            (Some(cause), Some(reason))
                if want.runs.contains(&run) && (1..=want.steps).contains(&step) =>
            {
                a.divergences.push(Divergence {
                    run,
                    step,
                    cause,
                    reason,
                });
            }
            _ => return Err(WireError::Divergence(i)),
        }
    }
    let prints = (0..runs).map(|_| r.u64()).collect::<Result<Vec<_>, _>>()?;
    if r.at != bytes.len() {
        return Err(WireError::Trailing(bytes.len() - r.at));
    }
    Ok(prints)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape() -> ChunkShape {
        ChunkShape {
            runs: 64..128,
            steps: 5,
            lags: 2,
            n_x: 3,
            n_z: 2,
        }
    }

    /// Sums with every field set to something of its own, and two divergences.
    fn filled() -> ChunkSums {
        let s = shape();
        let mut a = Accumulator::new(s.steps, s.n_x, s.n_z, s.lags);
        let mut x: f64 = 0.25;
        for (_, whole, v) in vectors(&mut a) {
            for y in v.iter_mut() {
                x += 1.0;
                *y = if whole { x.floor() } else { x * 1.000_000_1 };
            }
        }
        for (i, (_, y)) in scalars(&mut a).into_iter().enumerate() {
            *y = -1.5 - i as f64;
        }
        for (_, y) in counts(&mut a) {
            *y = 2;
        }
        a.runs = 64;
        a.meas_comp_runs = vec![64, 7];
        a.record_stop(70, 3, StopCause::IllConditioned, "P ill-conditioned".into());
        a.record_stop(99, 5, StopCause::Diverged, "ν is NaN".into());
        ChunkSums {
            sums: a,
            prints: (0..64)
                .map(|i| 0x9e37_79b9_7f4a_7c15u64.wrapping_mul(i + 1))
                .collect(),
        }
    }

    #[test]
    fn a_chunk_comes_back_bit_for_bit() {
        let c = filled();
        let back = decode(&encode(&c, &shape()), &shape()).unwrap();
        assert_eq!(format!("{back:?}"), format!("{c:?}"));
    }

    #[test]
    fn sums_appended_to_an_answer_follow_its_bytes_and_decode_alone() {
        // An MPI answer holds several runs' sums one after another, each written in place.
        let c = filled();
        let mut out = b"before".to_vec();
        encode_into(&mut out, &c.sums, &c.prints, &shape());
        assert_eq!(&out[..6], b"before");
        assert_eq!(out[6..], encode_bytes(&c, &shape())[..]);
        let back = decode_bytes(&out[6..], &shape()).unwrap();
        assert_eq!(format!("{back:?}"), format!("{c:?}"));
    }

    #[test]
    fn a_chunk_for_another_request_is_refused_with_the_size_named() {
        let text = encode(&filled(), &shape());
        for (other, what) in [
            (
                ChunkShape {
                    runs: 0..64,
                    ..shape()
                },
                "first run",
            ),
            (
                ChunkShape {
                    steps: 6,
                    ..shape()
                },
                "steps",
            ),
            (ChunkShape { lags: 3, ..shape() }, "lags"),
            (ChunkShape { n_z: 1, ..shape() }, "measurement components"),
        ] {
            let e = decode(&text, &other).unwrap_err();
            assert!(
                matches!(e, WireError::Shape { what: w, .. } if w == what),
                "{e}"
            );
        }
    }

    /// [`filled`] with what a packed form sends small: `nees_sq` the square of `nees_sum`,
    /// counts under 256 and degrees of freedom under 65536.
    fn packable() -> ChunkSums {
        let mut c = filled();
        let a = &mut c.sums;
        a.nees_sq = a.nees_sum.iter().map(|x| x * x).collect();
        a.nees_count = (0..a.nees_count.len()).map(|k| (k % 2) as f64).collect();
        a.nis_dof = (0..a.nis_dof.len()).map(|k| 300.0 + k as f64).collect();
        c
    }

    #[test]
    fn packed_sums_send_squares_and_small_counts_short_and_come_back_bit_for_bit() {
        let c = packable();
        let a = &c.sums;
        assert_eq!(packing_of(&a.nees_sq, Some(&a.nees_sum)), packing::SQUARE);
        assert_eq!(packing_of(&a.nees_count, None), packing::BYTES);
        assert_eq!(packing_of(&a.nis_dof, None), packing::PAIRS);
        assert_eq!(packing_of(&a.nis_sum, Some(&a.nees_count)), packing::WHOLE);
        let (mut packed, mut plain) = (Vec::new(), Vec::new());
        encode_packed_into(&mut packed, a, &c.prints, &shape());
        encode_into(&mut plain, a, &c.prints, &shape());
        // Each vector's values take 8 bytes plain, and 0, 1, 2 or 8 packed, after a tag.
        let vs = vectors_ref(a);
        let saved: usize = (0..vs.len())
            .map(|i| {
                let v = vs[i].2;
                let size = match packing_of(v, i.checked_sub(1).map(|b| vs[b].2)) {
                    packing::SQUARE => 0,
                    packing::BYTES => 1,
                    packing::PAIRS => 2,
                    _ => 8,
                };
                v.len() * (8 - size)
            })
            .sum();
        assert_eq!(plain.len() + 27 - packed.len(), saved);
        assert!(saved >= shape().steps * (8 + 7 + 6));
        let back = decode_packed_bytes(&packed, &shape()).unwrap();
        assert_eq!(format!("{back:?}"), format!("{c:?}"));
        // Neither form is read as the other.
        assert_eq!(
            decode_bytes(&packed, &shape()).unwrap_err(),
            WireError::Magic
        );
        assert_eq!(
            decode_packed_bytes(&plain, &shape()).unwrap_err(),
            WireError::Magic
        );
    }

    /// Read into sums that already hold another answer (and into sums of another shape), a
    /// packed answer comes back as read into fresh sums: every field is overwritten and the
    /// divergences are not appended to the last answer's.
    #[test]
    fn packed_sums_read_into_kept_sums_come_back_as_read_fresh() {
        let c = packable();
        let mut other = Accumulator::new(5, 3, 2, 2);
        for (_, _, v) in vectors(&mut other) {
            v.iter_mut().for_each(|y| *y = 3.0);
        }
        for (_, y) in scalars(&mut other) {
            *y = 7.5;
        }
        other.runs = 64;
        other.meas_comp_runs = vec![1, 2];
        other.record_stop(65, 1, StopCause::Diverged, "another".into());
        let bytes = |sums: &Accumulator| {
            let mut out = Vec::new();
            encode_packed_into(&mut out, sums, &c.prints, &shape());
            out
        };
        let fresh = format!(
            "{:?}",
            decode_packed_bytes(&bytes(&c.sums), &shape()).unwrap()
        );
        let read = |into: &mut Accumulator| {
            let prints = decode_packed_bytes_into(&bytes(&c.sums), &shape(), into).unwrap();
            let sums = into.clone();
            format!("{:?}", ChunkSums { sums, prints })
        };
        // Only its lags differ from the answer's: it is made anew, not read into.
        let mut into = Accumulator::new(5, 3, 2, 0);
        assert_eq!(read(&mut into), fresh);
        let kept = into.nees_sum.as_ptr();
        for first in [bytes(&other), bytes(&c.sums)] {
            decode_packed_bytes_into(&first, &shape(), &mut into).unwrap();
            assert_eq!(read(&mut into), fresh);
            assert_eq!(
                into.nees_sum.as_ptr(),
                kept,
                "sums of the shape keep their vectors"
            );
        }
        // A whole count sent as two bytes is still held to the runs and steps asked for
        // (64 × 5).
        let mut big = c.sums.clone();
        big.nees_count[0] = 321.0;
        assert_eq!(
            packing_of(&big.nees_count, Some(&big.nees_dof)),
            packing::PAIRS
        );
        let e = decode_packed_bytes_into(&bytes(&big), &shape(), &mut into).unwrap_err();
        assert!(e.to_string().contains("nees_count is 321"), "{e}");
    }

    #[test]
    fn damaged_packed_sums_are_refused_never_a_panic() {
        let c = packable();
        let mut bytes = Vec::new();
        encode_packed_into(&mut bytes, &c.sums, &c.prints, &shape());
        for cut in 0..bytes.len() {
            let e = decode_packed_bytes(&bytes[..cut], &shape()).unwrap_err();
            assert!(
                matches!(e, WireError::Truncated(_) | WireError::Magic),
                "cut at {cut}: {e}"
            );
        }
        for at in 0..bytes.len() {
            for flip in [0x01u8, 0x80, 0xff] {
                let mut b = bytes.clone();
                b[at] ^= flip;
                let _ = decode_packed_bytes(&b, &shape());
            }
        }
        // The first vector's tag (after the magic and the six sizes): a square with no
        // vector before it, and a packing that does not exist.
        let tag = MAGIC_PACKED.len() + 6 * 8;
        assert_eq!(bytes[tag], packing::WHOLE);
        for bad in [packing::SQUARE, 4, 0xff] {
            let mut b = bytes.clone();
            b[tag] = bad;
            let e = decode_packed_bytes(&b, &shape()).unwrap_err();
            assert!(
                matches!(
                    e,
                    WireError::Impossible {
                        what: "nees_sum",
                        ..
                    }
                ),
                "{bad}: {e}"
            );
        }
    }

    /// Every byte changed, and every length cut, gives an error or sums that pass the checks,
    /// never a panic; the counts a byte flip makes impossible are refused by name.
    #[test]
    fn damaged_bytes_are_refused_never_a_panic() {
        let text = encode(&filled(), &shape());
        let bytes = STANDARD.decode(&text).unwrap();
        for cut in 0..bytes.len() {
            let e = decode(&STANDARD.encode(&bytes[..cut]), &shape()).unwrap_err();
            assert!(
                matches!(e, WireError::Truncated(_) | WireError::Magic),
                "cut at {cut}: {e}"
            );
        }
        let mut refused = 0;
        for at in 0..bytes.len() {
            for flip in [0x01u8, 0x80, 0xff] {
                let mut b = bytes.clone();
                b[at] ^= flip;
                refused += usize::from(decode(&STANDARD.encode(&b), &shape()).is_err());
            }
        }
        // Most flips land in sums whose value any records could give; the header, counts,
        // divergences and the top bits of whole counts are checked.
        assert!(
            refused > bytes.len() / 4,
            "{refused} of {} refused",
            3 * bytes.len()
        );
        let mut b = bytes.clone();
        b.extend_from_slice(&[0; 3]);
        assert_eq!(
            decode(&STANDARD.encode(&b), &shape()).unwrap_err(),
            WireError::Trailing(3)
        );
    }

    #[test]
    fn impossible_numbers_are_refused_by_name() {
        let spoil = |f: &dyn Fn(&mut Accumulator)| {
            let mut c = filled();
            f(&mut c.sums);
            decode(&encode(&c, &shape()), &shape())
                .unwrap_err()
                .to_string()
        };
        assert!(spoil(&|a| a.nis_sum[2] = f64::NAN).contains("nis_sum is NaN"));
        assert!(spoil(&|a| a.nees_count[0] = 0.5).contains("nees_count is 0.5"));
        assert!(spoil(&|a| a.white_pairs[1] = -1.0).contains("white_pairs is -1"));
        assert!(spoil(&|a| a.white_pairs[1] = 321.0).contains("white_pairs is 321"));
        assert!(spoil(&|a| a.nees_run_total = f64::INFINITY).contains("nees_run_total"));
        assert!(spoil(&|a| a.diverged_runs = 65).contains("diverged_runs is 65"));
        assert!(spoil(&|a| a.runs = 63).contains("runs summed is 63"));
        assert!(spoil(&|a| a.meas_comp_runs[1] = 65).contains("meas_comp_runs is 65"));
        assert!(spoil(&|a| a.divergences[0].run = 3).contains("divergence 0"));
        assert!(spoil(&|a| a.divergences[1].step = 0).contains("divergence 1"));
        assert!(spoil(&|a| a.diverged_runs = 1).contains("divergences kept is 2"));
    }
}
