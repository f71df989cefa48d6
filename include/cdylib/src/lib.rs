//! autotune's C ABI (`src/capi.rs`, declared in `include/autotune.h`) as a shared library:
//! the `#[no_mangle]` functions of the autotune library it links are its exports.
pub use autotune::internals::capi::*;
