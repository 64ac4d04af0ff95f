//! Replicate study of the Bayesian calibration: N noise realisations of a
//! virtual 1 A campaign with known parameters (one crank revolution per run
//! at 100, 200, 400 rpm, 2 kHz, the bundled noise levels), each calibrated
//! with the default settings. Reports how often the 90 % credible interval
//! [q05, q95] holds the truth, and the largest |mean − truth|/sd.
//!
//!     cargo run --release --example calibration_coverage -- [N]
//!
//! N defaults to 20. docs/calibration.md shows its output.

use mrbp::calibrate::calibrate;
use mrbp::data::Campaign;
use mrbp::model::{Params, PARAM_NAMES};
use mrbp::calibrate::CalibrationSettings;
use mrbp::synth::{write_campaign, SynthSettings};

fn main() -> mrbp::Result<()> {
    let n: u64 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(20);
    let truth = Params::reference_1a().to_array();
    let mut inside = [0usize; 7];
    let mut worst_z = [0.0f64; 7];
    let mut seconds = 0.0;
    println!("| seed | {} | steps | R̂ max | ESS min |", PARAM_NAMES.map(|p| format!("z {p}")).join(" | "));
    println!("|---|{}---|---|---|", "---|".repeat(7));
    for seed in 1..=n {
        let dir = tempfile::tempdir().expect("temporary folder");
        let synth = SynthSettings { currents_a: vec![1.0], cycles: 1.0, rate_hz: 2000.0, seed: 1000 + seed, ..SynthSettings::default() };
        write_campaign(&synth, dir.path())?;
        let campaign = Campaign::load(&dir.path().join("campaign.toml"))?;
        let mut settings = CalibrationSettings::default();
        settings.sampler.seed = seed;
        let cal = calibrate(&campaign, &settings)?;
        seconds += cal.seconds();
        let d = &cal.diagnostics;
        let mut zs = Vec::new();
        for i in 0..7 {
            let p = &d.coordinates[i];
            if p.q05 <= truth[i] && truth[i] <= p.q95 {
                inside[i] += 1;
            }
            let z = (p.mean - truth[i]) / p.sd;
            worst_z[i] = worst_z[i].max(z.abs());
            zs.push(format!("{z:+.2}"));
        }
        let rhat = d.max_rhat();
        println!("| {seed} | {} | {} | {rhat:.4} | {:.0} |", zs.join(" | "), d.steps, d.min_ess());
    }
    let total: usize = inside.iter().sum();
    println!("\nCoverage of the 90 % intervals over {n} realisations:\n");
    println!("| | {} | all |", PARAM_NAMES.join(" | "));
    println!("|---|{}---|", "---|".repeat(7));
    println!(
        "| inside [q05, q95] | {} | {:.0} % |",
        inside.map(|c| format!("{:.0} %", 100.0 * c as f64 / n as f64)).join(" | "),
        100.0 * total as f64 / (7 * n) as f64
    );
    println!("| largest abs(z) | {} | |", worst_z.map(|z| format!("{z:.2}")).join(" | "));
    println!("\nmean wall time per calibration: {:.1} s", seconds / n as f64);
    Ok(())
}
