//! What the fuzzers (`tests/fuzz.rs`, `tests/fuzz_fieldlog.rs`, `tests/fuzz_inputs.rs`)
//! share: their random numbers, their settings, and a look at a child's memory. Included
//! with `#[path]`, so that the other tests do not compile it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// splitmix64: small, fast, and the same on every platform, so that a seed reproduces a
/// failure anywhere.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in 0..n (0 when n is 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() <= p
    }
    pub fn pick<'a, T>(&mut self, v: &'a [T]) -> &'a T {
        &v[self.below(v.len())]
    }
    /// A standard normal draw (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u = self.unit().max(1e-300);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

/// The run's budget (`AUTOTUNE_FUZZ_SECONDS`, default 8), seed (`AUTOTUNE_FUZZ_SEED`,
/// default 1) and an emptied directory `name` for failing inputs, under the cargo target's
/// temporary directory.
pub fn settings(name: &str) -> (f64, u64, PathBuf) {
    let seconds: f64 = std::env::var("AUTOTUNE_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(8.0);
    let seed: u64 = std::env::var("AUTOTUNE_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let failures_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&failures_dir);
    std::fs::create_dir_all(&failures_dir).unwrap();
    (seconds, seed, failures_dir)
}

/// A `kB` line of `/proc/<pid>/status` (`VmRSS`, `VmHWM`). A child's peak memory must be
/// read there while it runs: its `ru_maxrss` would count the memory of the test process it
/// was forked from.
pub fn proc_status_kb(pid: impl std::fmt::Display, key: &str) -> Option<u64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}
