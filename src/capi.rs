//! The C ABI of a worker that sums its own records (`include/autotune.h`, generated from
//! this file by cbindgen; build the shared library with
//! `cargo build --release -p autotune-cdylib`). A C or C++ worker hands each request
//! line to [`autotune_chunk_new`], gives every run's e and P and every measurement's ν and S
//! as it computes them, and prints the line [`autotune_chunk_answer`] returns: the request's
//! sums, O(T·(n+m)) numbers instead of the records' O(N·T·n²), equal bit for bit to what
//! autotune would have summed from a records file.
//!
//! Every function checks its pointers and never unwinds into C: a failure returns -1 (or
//! NULL) and leaves its message, one line, in [`autotune_last_error`].

use std::cell::RefCell;
use std::ffi::{CStr, CString, c_char, c_int};
use std::panic::{AssertUnwindSafe, catch_unwind};

use crate::external::WorkerChunk;

/// One request's runs being summed (opaque to C).
pub struct AutotuneChunk {
    chunk: WorkerChunk,
    /// The first failure: later calls and the answer are refused with it.
    failed: Option<String>,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(message: &str) {
    // A message with a NUL byte is cut there rather than lost.
    let cut = message.split('\0').next().unwrap_or_default();
    let text = CString::new(cut).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
}

/// Run `body`, turning an error or a panic into `on_error` and the thread's last error.
fn guarded<T>(on_error: T, body: impl FnOnce() -> Result<T, String>) -> T {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(v)) => v,
        Ok(Err(message)) => {
            set_error(&message);
            on_error
        }
        Err(_) => {
            set_error("internal error (a panic inside autotune's library)");
            on_error
        }
    }
}

/// A C string argument, or the error naming it.
///
/// # Safety
/// `s` is NULL or a NUL-terminated string.
unsafe fn text<'a>(s: *const c_char, what: &str) -> Result<&'a str, String> {
    if s.is_null() {
        return Err(format!("{what} is NULL"));
    }
    // SAFETY: the caller passes a NUL-terminated string.
    unsafe { CStr::from_ptr(s) }
        .to_str()
        .map_err(|_| format!("{what} is not UTF-8"))
}

/// `len` numbers at `p`, or the error naming them.
///
/// # Safety
/// `p` is NULL or points to `len` doubles.
unsafe fn numbers(p: *const f64, len: usize, what: &str) -> Result<Vec<f64>, String> {
    if p.is_null() {
        return Err(format!("{what} is NULL"));
    }
    // SAFETY: the caller passes `len` doubles.
    Ok(unsafe { std::slice::from_raw_parts(p, len) }.to_vec())
}

impl AutotuneChunk {
    /// The chunk behind a C pointer.
    ///
    /// # Safety
    /// `c` is NULL or from [`autotune_chunk_new`], not yet freed.
    unsafe fn from_ptr<'a>(c: *mut AutotuneChunk) -> Result<&'a mut AutotuneChunk, String> {
        // SAFETY: the caller passes a live chunk or NULL.
        let c = unsafe { c.as_mut() }.ok_or_else(|| "the chunk is NULL".to_string())?;
        match &c.failed {
            Some(why) => Err(format!("an earlier call failed: {why}")),
            None => Ok(c),
        }
    }

    /// Keep the first failure of the chunk's records, and give it back.
    fn fail(&mut self, why: impl ToString) -> String {
        self.failed.get_or_insert(why.to_string()).clone()
    }
}

/// Start the sums of the request `request` (the JSON line autotune wrote to the worker's
/// stdin, with or without its newline). NULL when it cannot be answered with sums (see
/// [`autotune_last_error`]): answer that request with records instead.
///
/// # Safety
/// `request` is a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_new(request: *const c_char) -> *mut AutotuneChunk {
    guarded(std::ptr::null_mut(), || {
        // SAFETY: forwarded from the caller.
        let line = unsafe { text(request, "request") }?;
        let chunk = WorkerChunk::from_request(line).map_err(|e| e.to_string())?;
        Ok(Box::into_raw(Box::new(AutotuneChunk {
            chunk,
            failed: None,
        })))
    })
}

/// The first run the request asks for (runs are [first, end)).
///
/// # Safety
/// `c` is from [`autotune_chunk_new`], not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_first_run(c: *const AutotuneChunk) -> usize {
    // SAFETY: the caller passes a live chunk or NULL.
    unsafe { c.as_ref() }.map_or(0, |c| c.chunk.runs().start)
}

/// One past the last run the request asks for.
///
/// # Safety
/// `c` is from [`autotune_chunk_new`], not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_run_end(c: *const AutotuneChunk) -> usize {
    // SAFETY: the caller passes a live chunk or NULL.
    unsafe { c.as_ref() }.map_or(0, |c| c.chunk.runs().end)
}

/// T, the steps per run the request asks for.
///
/// # Safety
/// `c` is from [`autotune_chunk_new`], not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_steps(c: *const AutotuneChunk) -> usize {
    // SAFETY: the caller passes a live chunk or NULL.
    unsafe { c.as_ref() }.map_or(0, |c| c.chunk.steps())
}

/// Run `run`'s estimation error `e` = x − x̂ (n doubles) and covariance `p` (n × n,
/// row-major) after step `step` (1-based). Each run's steps come in order, 1 to T. 0, or -1
/// on failure.
///
/// # Safety
/// `c` is from [`autotune_chunk_new`]; `e` and `p` point to n and n² doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_state(
    c: *mut AutotuneChunk,
    run: usize,
    step: usize,
    e: *const f64,
    p: *const f64,
) -> c_int {
    guarded(-1, || {
        // SAFETY: forwarded from the caller.
        let c = unsafe { AutotuneChunk::from_ptr(c) }?;
        let n = c.chunk.state_dim();
        // SAFETY: forwarded from the caller (n and n² doubles).
        let (e, p) = unsafe { (numbers(e, n, "e")?, numbers(p, n * n, "P")?) };
        c.chunk.state(run, step, e, p).map_err(|e| c.fail(e))?;
        Ok(0)
    })
}

/// Run `run`'s innovation `nu` (m doubles) and its covariance `s` (m × m, row-major) from
/// sensor `sensor` (its name in the problem's `[external] sensors`) at step `step`; a
/// sensor that did not measure at a step is simply not given. 0, or -1 on failure.
///
/// # Safety
/// `c` is from [`autotune_chunk_new`]; `sensor` is a NUL-terminated string; `nu` and `s`
/// point to m and m² doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_sensor(
    c: *mut AutotuneChunk,
    run: usize,
    step: usize,
    sensor: *const c_char,
    nu: *const f64,
    s: *const f64,
) -> c_int {
    guarded(-1, || {
        // SAFETY: forwarded from the caller.
        let c = unsafe { AutotuneChunk::from_ptr(c) }?;
        // SAFETY: forwarded from the caller.
        let name = unsafe { text(sensor, "sensor") }?;
        let m = c
            .chunk
            .sensor_dim(name)
            .ok_or_else(|| format!("no sensor {name:?} in the request's layout"))?;
        // SAFETY: forwarded from the caller (m and m² doubles).
        let (nu, s) = unsafe { (numbers(nu, m, "nu")?, numbers(s, m * m, "S")?) };
        c.chunk
            .sensor(run, step, name, nu, s)
            .map_err(|e| c.fail(e))?;
        Ok(0)
    })
}

/// Run `run`'s filter broke down at step `step`, for `reason`: the run ends there (its
/// later steps are not given). 0, or -1 on failure.
///
/// # Safety
/// `c` is from [`autotune_chunk_new`]; `reason` is a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_diverged(
    c: *mut AutotuneChunk,
    run: usize,
    step: usize,
    reason: *const c_char,
) -> c_int {
    guarded(-1, || {
        // SAFETY: forwarded from the caller.
        let c = unsafe { AutotuneChunk::from_ptr(c) }?;
        // SAFETY: forwarded from the caller.
        let why = unsafe { text(reason, "reason") }?;
        c.chunk.diverged(run, step, why).map_err(|e| c.fail(e))?;
        Ok(0)
    })
}

/// One array in the NumPy layout of docs/src/records.md (`e`, `P`, `nu_<sensor>`,
/// `S_<sensor>`, `diverged`, …), of `ndim` axes `shape`, its first axis the runs asked
/// for, `data` in C order: the alternative to giving the records step by step. 0, or -1.
///
/// # Safety
/// `c` is from [`autotune_chunk_new`]; `name` is a NUL-terminated string; `shape` points
/// to `ndim` sizes and `data` to their product of doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_array(
    c: *mut AutotuneChunk,
    name: *const c_char,
    shape: *const usize,
    ndim: usize,
    data: *const f64,
) -> c_int {
    guarded(-1, || {
        // SAFETY: forwarded from the caller.
        let c = unsafe { AutotuneChunk::from_ptr(c) }?;
        // SAFETY: forwarded from the caller.
        let name = unsafe { text(name, "name") }?;
        if ndim > 4 || (ndim > 0 && shape.is_null()) {
            return Err(format!(
                "array {name}: {ndim} axes (at most 4), or shape NULL"
            ));
        }
        let shape = if ndim == 0 {
            Vec::new()
        } else {
            // SAFETY: `ndim` sizes, as the caller promises.
            unsafe { std::slice::from_raw_parts(shape, ndim) }.to_vec()
        };
        let len = shape
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .ok_or_else(|| format!("array {name}: shape {shape:?} overflows"))?;
        // SAFETY: forwarded from the caller (the shape's product of doubles).
        let data = unsafe { numbers(data, len, name) }?;
        c.chunk
            .add_array(name, shape, data)
            .map_err(|e| c.fail(e))?;
        Ok(0)
    })
}

/// The answer line for the request (`{"id":…,"sums":"…"}`, NUL-terminated, no newline):
/// print it, with a newline, on stdout, and free it with [`autotune_string_free`]. The
/// chunk is freed, whatever the outcome. NULL on failure (a run missing, a step out of
/// order, an earlier failed call): then answer `{"id": …, "error": …}` with
/// [`autotune_last_error`].
///
/// # Safety
/// `c` is from [`autotune_chunk_new`], not yet freed; it is not used again.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_answer(c: *mut AutotuneChunk) -> *mut c_char {
    guarded(std::ptr::null_mut(), || {
        if c.is_null() {
            return Err("the chunk is NULL".into());
        }
        // SAFETY: a live chunk from autotune_chunk_new, given up by the caller.
        let c = unsafe { Box::from_raw(c) };
        if let Some(why) = c.failed {
            return Err(why);
        }
        let line = c.chunk.answer().map_err(|e| e.to_string())?;
        Ok(CString::new(line)
            .expect("an answer line has no NUL")
            .into_raw())
    })
}

/// Free a chunk without answering (NULL is ignored).
///
/// # Safety
/// `c` is NULL or from [`autotune_chunk_new`], not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_chunk_free(c: *mut AutotuneChunk) {
    if !c.is_null() {
        // SAFETY: a live chunk, given up by the caller.
        drop(unsafe { Box::from_raw(c) });
    }
}

/// Free a string this library returned (NULL is ignored).
///
/// # Safety
/// `s` is NULL or from [`autotune_chunk_answer`], not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn autotune_string_free(s: *mut c_char) {
    if !s.is_null() {
        // SAFETY: a string of ours, given up by the caller.
        drop(unsafe { CString::from_raw(s) });
    }
}

/// The message of this thread's last failure, one line (empty if none); valid until the
/// thread's next failing call.
#[unsafe(no_mangle)]
pub extern "C" fn autotune_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}
