//! No build step. This script is here for its build-dependency (Cargo.toml): syn with the
//! features pyo3's macros enable, so that the Python package's build (python/) resolves
//! every shared crate as this package does and reuses what `cargo build --release` compiled
//! instead of compiling the library again. As a build-dependency, syn is compiled once, for
//! the host, as the proc-macros' syn already is.
fn main() {
    println!("cargo::rerun-if-changed=build.rs");
}
