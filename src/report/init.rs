//! What `init` prints: the starter it wrote and what to do next.

use std::path::Path;

/// The two lines `init` prints for the starter at `path`: a built-in `model`'s, or the
/// `[external]` worker's (`None`).
pub fn init_text(path: &Path, model: Option<&str>) -> String {
    match model {
        None => format!(
            "wrote {} (external worker starter; docs/src/workers.md describes the protocol)\n\
             next: point [external] command at your worker, name its sensors, states and \
             parameters, then run `autotune check` and `autotune tune` on it\n",
            path.display()
        ),
        Some(model) => format!(
            "wrote {} ({model} starter; its filter parameters equal the truth's noise, so \
             `autotune check` passes on it as written)\n\
             next: describe your system in [truth], replace the [params] values with your \
             filter's, then run `autotune check` and `autotune tune` on it\n",
            path.display()
        ),
    }
}
