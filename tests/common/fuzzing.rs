//! What the fuzzers (`tests/fuzz/loaders.rs`, `tests/fuzz/fieldlog.rs`, `tests/fuzz/inputs.rs`)
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

/// One `.npy` file, before it is written: its header's fields as text (so that they can be
/// made absurd) and its numbers.
#[derive(Clone)]
pub struct Npy {
    pub name: String,
    pub descr: String,
    pub fortran: bool,
    pub shape: Vec<String>,
    /// The shape the numbers have (C order); the data is written in Fortran order when
    /// `fortran` is set and `shape` is still this.
    pub true_shape: Vec<usize>,
    pub values: Vec<f64>,
}

impl Npy {
    pub fn new(name: &str, shape: &[usize], values: Vec<f64>) -> Npy {
        Npy {
            name: name.into(),
            descr: "<f8".into(),
            fortran: false,
            shape: shape.iter().map(|d| d.to_string()).collect(),
            true_shape: shape.to_vec(),
            values,
        }
    }

    /// The header: format 1.0, the header dict padded with spaces to 64 bytes.
    pub fn header(&self) -> Vec<u8> {
        let shape = match self.shape.len() {
            1 => format!("({},)", self.shape[0]),
            _ => format!("({})", self.shape.join(", ")),
        };
        let mut header = format!(
            "{{'descr': '{}', 'fortran_order': {}, 'shape': {shape}, }}",
            self.descr,
            if self.fortran { "True" } else { "False" }
        );
        while (10 + header.len() + 1) % 64 != 0 {
            header.push(' ');
        }
        header.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend((header.len() as u16).to_le_bytes());
        out.extend(header.as_bytes());
        out
    }

    /// The file's bytes: the header, then the numbers in the header's `descr` (in Fortran
    /// order when `fortran` is set and the shape is still the numbers' own).
    pub fn bytes(&self) -> Vec<u8> {
        let mut out = self.header();
        let same: bool = self
            .shape
            .iter()
            .map(|d| d.parse::<usize>().ok())
            .eq(self.true_shape.iter().map(|&d| Some(d)));
        let whole = self.values.len() == self.true_shape.iter().product::<usize>();
        let values = if self.fortran && same && whole {
            fortran(&self.true_shape, &self.values)
        } else {
            self.values.clone()
        };
        for v in values {
            match self.descr.as_str() {
                "<f4" => out.extend((v as f32).to_le_bytes()),
                ">f8" => out.extend(v.to_be_bytes()),
                "<i8" => out.extend((v as i64).to_le_bytes()),
                "<i4" => out.extend((v as i32).to_le_bytes()),
                "|u1" => out.push(v as u8),
                _ => out.extend(v.to_le_bytes()),
            }
        }
        out
    }
}

/// `values` (C order, of `shape`) in Fortran order.
pub fn fortran(shape: &[usize], values: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; values.len()];
    for (c, &v) in values.iter().enumerate() {
        // The multi-index of C offset c, then its Fortran offset.
        let mut rest = c;
        let mut idx = vec![0; shape.len()];
        for a in (0..shape.len()).rev() {
            idx[a] = rest % shape[a];
            rest /= shape[a];
        }
        let (mut off, mut stride) = (0, 1);
        for (i, d) in idx.iter().zip(shape) {
            off += i * stride;
            stride *= d;
        }
        out[off] = v;
    }
    out
}

/// Byte-level damage to a binary file: a byte changed, bytes deleted or inserted, the
/// file cut short.
pub fn mutate_bytes(b: &mut Vec<u8>, rng: &mut Rng) {
    if b.is_empty() {
        b.push(0);
        return;
    }
    match rng.below(4) {
        0 => {
            let i = rng.below(b.len());
            b[i] = rng.next() as u8;
        }
        1 => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(16);
            b.drain(i..(i + n).min(b.len()));
        }
        2 => {
            let i = rng.below(b.len());
            let n = 1 + rng.below(16);
            let junk: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
            b.splice(i..i, junk);
        }
        _ => b.truncate(rng.below(b.len())),
    }
}

/// Start `cmd` with its address space limited to `address_space` bytes (beyond, an
/// allocation fails and the process aborts, instead of the machine swapping), its stdout
/// and stderr drained by threads: the child and the two drains.
pub fn spawn_limited(
    cmd: &mut std::process::Command,
    address_space: u64,
) -> (
    std::process::Child,
    std::thread::JoinHandle<Vec<u8>>,
    std::thread::JoinHandle<Vec<u8>>,
) {
    use std::os::unix::process::CommandExt as _;
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: address_space as libc::rlim_t,
                rlim_max: address_space as libc::rlim_t,
            };
            libc::setrlimit(libc::RLIMIT_AS, &lim);
            Ok(())
        });
    }
    let mut child = cmd.spawn().unwrap();
    let drain = |mut r: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    };
    let out = drain(Box::new(child.stdout.take().unwrap()));
    let err = drain(Box::new(child.stderr.take().unwrap()));
    (child, out, err)
}

/// Byte ranges of the numbers in `text`.
pub fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'));
        if starts {
            let s = if i > 0 && b[i - 1] == b'-' { i - 1 } else { i };
            let mut e = i;
            while e < b.len() && (b[e].is_ascii_alphanumeric() || b"._+-".contains(&b[e])) {
                e += 1;
            }
            spans.push((s, e));
            i = e;
        } else {
            i += 1;
        }
    }
    spans
}
