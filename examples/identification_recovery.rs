//! Recovery of the seven B-P parameters by the deterministic identification
//! on virtual campaigns with known parameters (the 1 A reference set:
//! 100, 200, 400 rpm, two revolutions each), at several sampling rates and
//! sensor noise levels.
//!
//!     cargo run --release --example identification_recovery
//!
//! Prints Markdown tables; docs/identification.md shows their output.
//! Noise-free rows give the signed error; noisy rows the median and the
//! largest |error| over 10 noise realisations.

use mrbp::data::Campaign;
use mrbp::identify::{identify_current, IdentifySettings};
use mrbp::model::{Params, PARAM_NAMES};
use mrbp::synth::{write_campaign, SynthSettings};

/// Relative errors of the combined estimate (before clamping) and the
/// number of warnings.
fn errors(rate: f64, noise_f: f64, noise_x: f64, seed: u64) -> mrbp::Result<(Vec<f64>, usize)> {
    let truth = Params::reference_1a();
    let dir = tempfile::tempdir().expect("temporary folder");
    let settings = SynthSettings {
        currents_a: vec![1.0],
        rate_hz: rate,
        noise_force_n: noise_f,
        noise_displacement_m: noise_x,
        seed,
        ..SynthSettings::default()
    };
    write_campaign(&settings, dir.path())?;
    let campaign = Campaign::load(&dir.path().join("campaign.toml"))?;
    let id = identify_current(&campaign, 1.0, &IdentifySettings::default());
    let e = id.raw.iter().zip(truth.to_array()).map(|(e, t)| (e - t) / t).collect();
    let warnings = id.warnings.len() + id.runs.iter().map(|r| r.warnings.len()).sum::<usize>();
    Ok((e, warnings))
}

fn main() -> mrbp::Result<()> {
    println!("Noise-free records: (estimate − truth)/truth\n");
    println!("| rate (kHz) | {} |", PARAM_NAMES.join(" | "));
    println!("|---|{}", "---|".repeat(7));
    for rate in [10_000.0, 5_000.0, 2_000.0] {
        let (e, _) = errors(rate, 0.0, 0.0, 1)?;
        let cells: Vec<String> = e.iter().map(|v| format!("{:+.1} %", 100.0 * v)).collect();
        println!("| {} | {} |", rate / 1000.0, cells.join(" | "));
    }
    println!("\nNoisy records, 10 noise realisations: median |error| (largest |error|)\n");
    println!("| rate (kHz) | force noise (N) | displacement noise (µm) | {} | realisations with warnings |", PARAM_NAMES.join(" | "));
    println!("|---|---|---|{}---|", "---|".repeat(7));
    for (rate, noise_f, noise_x) in [
        (10_000.0, 15.0, 2.0e-6),
        (5_000.0, 15.0, 2.0e-6),
        (5_000.0, 5.0, 0.5e-6),
        (5_000.0, 50.0, 5.0e-6),
    ] {
        let mut all: Vec<Vec<f64>> = vec![vec![]; 7];
        let mut warned = 0;
        for seed in 1..=10 {
            let (e, w) = errors(rate, noise_f, noise_x, seed)?;
            for (k, v) in e.iter().enumerate() {
                all[k].push(v.abs());
            }
            warned += (w > 0) as usize;
        }
        let cells: Vec<String> = all
            .iter_mut()
            .map(|v| {
                v.sort_by(f64::total_cmp);
                let med = 0.5 * (v[4] + v[5]);
                format!("{:.0} % ({:.0} %)", 100.0 * med, 100.0 * v[9])
            })
            .collect();
        println!(
            "| {} | {} | {} | {} | {warned}/10 |",
            rate / 1000.0,
            noise_f,
            noise_x * 1e6,
            cells.join(" | ")
        );
    }
    Ok(())
}
