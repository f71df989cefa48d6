//! The sums' fields in wire order: the one list that encoding and decoding both walk.

use crate::stats::Accumulator;

// Each list of fields in wire order, once: as mutable borrows for decoding and as shared
// ones for encoding (`$borrow` is `&mut` or `&`), so that the two orders cannot differ.
macro_rules! vectors_of {
    ($a:ident, $($borrow:tt)+) => {
    [
        ("nees_sum", false, $($borrow)+ $a.nees_sum),
        ("nees_sq", false, $($borrow)+ $a.nees_sq),
        ("nees_dof", false, $($borrow)+ $a.nees_dof),
        ("nees_count", true, $($borrow)+ $a.nees_count),
        ("nis_sum", false, $($borrow)+ $a.nis_sum),
        ("nis_sq", false, $($borrow)+ $a.nis_sq),
        ("nis_dof", false, $($borrow)+ $a.nis_dof),
        ("nis_count", true, $($borrow)+ $a.nis_count),
        ("state_comp_total", false, $($borrow)+ $a.state_comp_total),
        ("state_comp_samples", true, $($borrow)+ $a.state_comp_samples),
        ("state_comp_run_sum", false, $($borrow)+ $a.state_comp_run_sum),
        ("state_comp_run_sq", false, $($borrow)+ $a.state_comp_run_sq),
        ("state_comp_null_var", false, $($borrow)+ $a.state_comp_null_var),
        ("state_mean_total", false, $($borrow)+ $a.state_mean_total),
        ("state_mean_samples", true, $($borrow)+ $a.state_mean_samples),
        ("state_mean_run_sq", false, $($borrow)+ $a.state_mean_run_sq),
        ("state_mean_null_var", false, $($borrow)+ $a.state_mean_null_var),
        ("meas_mean_total", false, $($borrow)+ $a.meas_mean_total),
        ("meas_mean_run_sq", false, $($borrow)+ $a.meas_mean_run_sq),
        ("meas_comp_total", false, $($borrow)+ $a.meas_comp_total),
        ("meas_comp_samples", true, $($borrow)+ $a.meas_comp_samples),
        ("meas_comp_run_sum", false, $($borrow)+ $a.meas_comp_run_sum),
        ("meas_comp_run_sq", false, $($borrow)+ $a.meas_comp_run_sq),
        ("white_ab", false, $($borrow)+ $a.white_ab),
        ("white_a2", false, $($borrow)+ $a.white_a2),
        ("white_b2", false, $($borrow)+ $a.white_b2),
        ("white_pairs", true, $($borrow)+ $a.white_pairs),
    ]
    };
}

macro_rules! scalars_of {
    ($a:ident, $($borrow:tt)+) => {

    [
        ("nees_null_var", $($borrow)+ $a.nees_null_var),
        ("nees_run_total", $($borrow)+ $a.nees_run_total),
        ("nees_run_total_sq", $($borrow)+ $a.nees_run_total_sq),
    ]
    };
}

macro_rules! counts_of {
    ($a:ident, $($borrow:tt)+) => {

    [
        ("runs", $($borrow)+ $a.runs),
        ("null_var_runs", $($borrow)+ $a.null_var_runs),
        ("error_map_missing", $($borrow)+ $a.error_map_missing),
        ("nees_total_runs", $($borrow)+ $a.nees_total_runs),
        ("comp_null_var_runs", $($borrow)+ $a.comp_null_var_runs),
        ("diverged_runs", $($borrow)+ $a.diverged_runs),
        ("ill_conditioned_runs", $($borrow)+ $a.ill_conditioned_runs),
        ("truth_overflow_runs", $($borrow)+ $a.truth_overflow_runs),
    ]
    };
}

/// The per-step, component and whiteness vectors, in wire order, with their names (for
/// errors) and whether they count samples (whole numbers).
pub(super) fn vectors(a: &mut Accumulator) -> [(&'static str, bool, &mut Vec<f64>); 27] {
    vectors_of!(a, &mut)
}

/// [`vectors`], to read.
pub(super) fn vectors_ref(a: &Accumulator) -> [(&'static str, bool, &Vec<f64>); 27] {
    vectors_of!(a, &)
}

/// The scalar sums, in wire order.
pub(super) fn scalars(a: &mut Accumulator) -> [(&'static str, &mut f64); 3] {
    scalars_of!(a, &mut)
}

/// [`scalars`], to read.
pub(super) fn scalars_ref(a: &Accumulator) -> [(&'static str, &f64); 3] {
    scalars_of!(a, &)
}

/// The counts of runs, in wire order (`runs` first).
pub(super) fn counts(a: &mut Accumulator) -> [(&'static str, &mut usize); 8] {
    counts_of!(a, &mut)
}

/// [`counts`], to read.
pub(super) fn counts_ref(a: &Accumulator) -> [(&'static str, &usize); 8] {
    counts_of!(a, &)
}
