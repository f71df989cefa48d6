//! Fingerprints of runs' records, for the seed-contract check: equal records give equal
//! fingerprints. The hash is FNV-1a's step (xor, then multiply by the 64-bit FNV prime)
//! applied to the records' numbers as whole 64-bit words (bytes only for text), a fixed
//! function rather than the standard library's unspecified one, so that a worker
//! fingerprinting its own runs through this library (in a sums answer) agrees with autotune
//! fingerprinting records, whatever Rust built either. A word at a time, not a byte: a
//! worker fingerprints every step of every run it sums, and byte-wise FNV took a quarter of
//! that time.

use std::hash::Hasher;

use super::{SensorRecord, StateRecord, StepRecord};

/// The 64-bit FNV prime.
const PRIME: u64 = 0x0000_0100_0000_01b3;

/// 64-bit FNV-1a on bytes, and its step on whole words for `write_u64` and `write_u8`.
struct Fnv(u64);

impl Hasher for Fnv {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0 ^ u64::from(*b)).wrapping_mul(PRIME);
        }
    }

    fn write_u8(&mut self, x: u8) {
        self.0 = (self.0 ^ u64::from(x)).wrapping_mul(PRIME);
    }

    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0 ^ x).wrapping_mul(PRIME);
    }
}

/// The fingerprint of a run after record `r`, the run's fingerprint before it being `prev`
/// (`None` at its first record).
pub(crate) fn chain(prev: Option<u64>, r: &StepRecord) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    match prev {
        None => h.write_u8(0),
        Some(p) => {
            h.write_u8(1);
            h.write_u64(p);
        }
    }
    let floats = |h: &mut Fnv, v: &[f64]| {
        h.write_u64(v.len() as u64);
        for x in v {
            h.write_u64(x.to_bits());
        }
    };
    h.write_u64(r.step as u64);
    match &r.state {
        None => h.write_u8(0),
        Some(StateRecord::Raw { e, p }) => {
            h.write_u8(1);
            floats(&mut h, e);
            floats(&mut h, p);
        }
        Some(StateRecord::Normalized { nees, dof, e2p }) => {
            h.write_u8(2);
            floats(&mut h, &[*nees, *dof]);
            floats(&mut h, e2p.as_deref().unwrap_or(&[]));
        }
    }
    for (k, s) in &r.sensors {
        h.write_u64(*k as u64);
        match s {
            SensorRecord::Raw { nu, s } => {
                h.write_u8(1);
                floats(&mut h, nu);
                floats(&mut h, s);
            }
            SensorRecord::Normalized { nis, dof, u } => {
                h.write_u8(2);
                floats(&mut h, &[*nis, *dof]);
                floats(&mut h, u.as_deref().unwrap_or(&[]));
            }
        }
    }
    match &r.diverged {
        None => h.write_u8(0),
        Some(why) => {
            h.write_u8(1);
            h.write_u64(why.len() as u64);
            h.write(why.as_bytes());
        }
    }
    h.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// FNV-1a's published test vectors (the empty input and "a"), so the function is the
    /// specified one and a worker built elsewhere agrees.
    /// The word step's value for the input below, computed by Python's integers.
    const WORD_STEP: u64 = 0x889b_e307_b544_f397;

    #[test]
    fn fnv_is_the_published_function() {
        let mut h = Fnv(0xcbf2_9ce4_8422_2325);
        assert_eq!(h.finish(), 0xcbf2_9ce4_8422_2325);
        h.write(b"a");
        assert_eq!(h.finish(), 0xaf63_dc4c_8601_ec8c);
        // A word in one step: (0xaf63dc4c8601ec8c ^ 2^63 + 1) * prime mod 2^64, from Python.
        h.write_u64((1 << 63) + 1);
        assert_eq!(h.finish(), WORD_STEP);
    }

    #[test]
    fn a_changed_bit_or_order_changes_the_print() {
        let mut a = StepRecord::new(0, 1);
        a.state = Some(StateRecord::Raw {
            e: vec![1.0, 2.0],
            p: vec![1.0, 0.0, 0.0, 1.0],
        });
        let mut b = a.clone();
        if let Some(StateRecord::Raw { e, .. }) = &mut b.state {
            e[1] = f64::from_bits(2.0f64.to_bits() + 1);
        }
        assert_ne!(chain(None, &a), chain(None, &b));
        assert_ne!(chain(None, &a), chain(Some(chain(None, &a)), &a));
        assert_eq!(chain(None, &a), chain(None, &a.clone()));
    }
}
