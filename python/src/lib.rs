//! `autotune._native`: autotune's worker library for Python (`autotune.Chunk`), a thin
//! layer over `autotune::WorkerChunk`. The Python package (`python/autotune/`) builds
//! `serve` on it.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use autotune::WorkerChunk;

fn value_error(e: impl ToString) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The records of one request's runs, summed in this process: give each run's e and P and
/// each measurement's ν and S (or arrays in the NumPy records layout), then print
/// `answer()`.
#[pyclass(module = "autotune._native")]
struct Chunk {
    inner: Option<WorkerChunk>,
}

impl Chunk {
    fn live(&mut self) -> PyResult<&mut WorkerChunk> {
        self.inner
            .as_mut()
            .ok_or_else(|| value_error("this chunk was answered already"))
    }
}

#[pymethods]
impl Chunk {
    /// The chunk a request line (as read from stdin) asks for; ValueError if it cannot be
    /// answered with sums.
    #[new]
    fn new(request: &str) -> PyResult<Self> {
        let inner = WorkerChunk::from_request(request).map_err(value_error)?;
        Ok(Chunk { inner: Some(inner) })
    }

    /// The request's id.
    #[getter]
    fn id(&mut self) -> PyResult<u64> {
        Ok(self.live()?.id())
    }

    /// The runs asked for, (a, b): runs a, a+1, …, b−1.
    #[getter]
    fn runs(&mut self) -> PyResult<(usize, usize)> {
        let r = self.live()?.runs();
        Ok((r.start, r.end))
    }

    /// T, the steps per run.
    #[getter]
    fn steps(&mut self) -> PyResult<usize> {
        Ok(self.live()?.steps())
    }

    /// Run `run`'s estimation error e = x − x̂ (n numbers) and covariance P (n² numbers,
    /// row-major) after step `step` (1-based).
    fn state(&mut self, run: usize, step: usize, e: Vec<f64>, p: Vec<f64>) -> PyResult<()> {
        let c = self.live()?;
        let n = c.state_dim();
        if e.len() != n || p.len() != n * n {
            return Err(value_error(format!(
                "e has {} numbers and P {}: expected {n} and {}",
                e.len(),
                p.len(),
                n * n
            )));
        }
        c.state(run, step, e, p).map_err(value_error)
    }

    /// Run `run`'s innovation ν (m numbers) and its covariance S (m², row-major) from sensor
    /// `name` at step `step`; a sensor that did not measure is not given.
    fn sensor(
        &mut self,
        run: usize,
        step: usize,
        name: &str,
        nu: Vec<f64>,
        s: Vec<f64>,
    ) -> PyResult<()> {
        let c = self.live()?;
        let m = c
            .sensor_dim(name)
            .ok_or_else(|| value_error(format!("no sensor {name:?} in the request's layout")))?;
        if nu.len() != m || s.len() != m * m {
            return Err(value_error(format!(
                "nu_{name} has {} numbers and S_{name} {}: expected {m} and {}",
                nu.len(),
                s.len(),
                m * m
            )));
        }
        c.sensor(run, step, name, nu, s).map_err(value_error)
    }

    /// Run `run`'s filter broke down at step `step`: the run ends there.
    fn diverged(&mut self, run: usize, step: usize, reason: &str) -> PyResult<()> {
        self.live()?
            .diverged(run, step, reason)
            .map_err(value_error)
    }

    /// One array of the NumPy records layout (`e`, `P`, `nu_<s>`, `S_<s>`, `diverged`, …),
    /// its first axis the runs asked for: `shape`, and `data` its float64 numbers in C
    /// order, little-endian (`numpy.ascontiguousarray(a, "<f8").tobytes()`).
    fn array(&mut self, name: &str, shape: Vec<usize>, data: &[u8]) -> PyResult<()> {
        let words = data.chunks_exact(8);
        if !words.remainder().is_empty() {
            return Err(value_error(format!(
                "array {name}: {} bytes is not a whole number of float64",
                data.len()
            )));
        }
        let numbers = words
            .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
            .collect();
        self.live()?
            .add_array(name, shape, numbers)
            .map_err(value_error)
    }

    /// The answer line (no newline): print it on stdout and flush. The chunk is used up.
    fn answer(&mut self) -> PyResult<String> {
        let c = self
            .inner
            .take()
            .ok_or_else(|| value_error("this chunk was answered already"))?;
        c.answer().map_err(value_error)
    }
}

/// autotune's worker library.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Chunk>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
