// A linear model built in Rust, tuned from a guess 10× off, and its result checked on
// several seeds: `cargo run --release --example tune_linear`. The crate's documentation runs
// it as a doc test, so it compiles against the documented API alone.

use autotune::prelude::*;
use nalgebra::{DMatrix, DVector};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // A target at nearly constant velocity, its position measured every second. The
    // truth: acceleration variance 0.5 (m/s²)², sensor variance 1 m².
    let model = LinearExperiment::builder("cv1d")
        .transition(DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]))
        .observation(DMatrix::from_row_slice(1, 2, &[1.0, 0.0]))
        .initial(DVector::zeros(2), DMatrix::identity(2, 2))
        .truth_noise(dwna_block(1.0) * 0.5, DMatrix::identity(1, 1))
        // The filter's guesses, 10× off: Q(θ) = θ₀ · DWNA, R(θ) = θ₁.
        .process_noise(
            ParamDef::new("q_accel", 5.0).unit("(m/s²)²"),
            dwna_block(1.0),
        )
        .measurement_noise(
            ParamDef::new("r_pos", 10.0).unit("m²"),
            DMatrix::identity(1, 1),
        )
        .states(["pos", "vel"])
        .measurements(["pos"])
        .montecarlo(McConfig::new(100, 100)?.with_seed(1))
        .build()?;

    let tuned = model.tuner(TuneSettings::default()).run(&Silent)?;
    println!(
        "q_accel = {:.3}, r_pos = {:.3}",
        tuned.tuned[0], tuned.tuned[1]
    );

    // One seed is one draw of a random test; ten say whether a failure was bad luck.
    let checks = check_seeds(&model, &tuned.tuned, model.mc(), Truth::Known, 10)?;
    println!(
        "{} of 10 seeds pass (a consistent filter: at least {})",
        checks.passed(),
        checks.band_low()
    );
    assert!(checks.passes());
    Ok(())
}
