//! Replicate study of the Bayesian calibration: N noise realisations of a
//! virtual 1 A campaign with known parameters (one crank revolution per run
//! at 100, 200, 400 rpm, 2 kHz, 15 N force noise), each calibrated with the
//! default settings. Reports per parameter how often the central 50 % and
//! 90 % credible intervals hold the truth, with the binomial standard error
//! of that share, and the largest |mean − truth|/sd.
//!
//!     cargo run --release --example calibration_coverage -- [N] [DISPLACEMENT_NOISE_M] [SMOOTH_MS] [eiv]
//!
//! N defaults to 40, the displacement noise to the bundled 2e-6 m, the
//! strain smoothing to the default 2 ms; the likelihood takes the strain
//! as exact unless `eiv` (the default of mrbp) is given. docs/calibration.md
//! shows its output.

use mrbp::calibrate::calibrate;
use mrbp::calibrate::CalibrationSettings;
use mrbp::data::Campaign;
use mrbp::model::{Params, PARAM_NAMES};
use mrbp::sampler::quantile;
use mrbp::synth::{write_campaign, SynthSettings};

fn main() -> mrbp::Result<()> {
    let arg = |i: usize| std::env::args().nth(i);
    let n: u64 = arg(1).and_then(|a| a.parse().ok()).unwrap_or(40);
    let noise_x: f64 = arg(2).and_then(|a| a.parse().ok()).unwrap_or(2e-6);
    let smooth_ms: f64 = arg(3).and_then(|a| a.parse().ok()).unwrap_or(2.0);
    let eiv = arg(4).as_deref() == Some("eiv");
    let truth = Params::reference_1a().to_array();
    let mut inside50 = [0usize; 7];
    let mut inside90 = [0usize; 7];
    let mut worst_z = [0.0f64; 7];
    let mut seconds = 0.0;
    println!("displacement noise {noise_x:e} m, strain smoothing {smooth_ms} ms, errors in variables {eiv}, {n} replicates\n");
    println!("| seed | {} | steps | R̂ max | ESS min |", PARAM_NAMES.map(|p| format!("z {p}")).join(" | "));
    println!("|---|{}---|---|---|", "---|".repeat(7));
    for seed in 1..=n {
        let dir = tempfile::tempdir().expect("temporary folder");
        let synth = SynthSettings {
            currents_a: vec![1.0],
            cycles: 1.0,
            rate_hz: 2000.0,
            noise_displacement_m: noise_x,
            seed: 1000 + seed,
            ..SynthSettings::default()
        };
        write_campaign(&synth, dir.path())?;
        let campaign = Campaign::load(&dir.path().join("campaign.toml"))?;
        let mut settings = CalibrationSettings::default();
        settings.sampler.seed = seed;
        settings.likelihood.smooth_strain_ms = smooth_ms;
        settings.likelihood.errors_in_variables = eiv;
        let cal = calibrate(&campaign, &settings)?;
        seconds += cal.seconds();
        let d = &cal.diagnostics;
        let positions = cal.sample.positions(d.burn_in, 1, usize::MAX);
        let mut zs = Vec::new();
        for i in 0..7 {
            let draws = cal.sample.values(PARAM_NAMES[i], &positions).expect("a B-P parameter");
            let within = |lo: f64, hi: f64| quantile(&draws, lo) <= truth[i] && truth[i] <= quantile(&draws, hi);
            inside50[i] += within(0.25, 0.75) as usize;
            inside90[i] += within(0.05, 0.95) as usize;
            let p = &d.coordinates[i];
            let z = (p.mean - truth[i]) / p.sd;
            worst_z[i] = worst_z[i].max(z.abs());
            zs.push(format!("{z:+.2}"));
        }
        println!("| {seed} | {} | {} | {:.4} | {:.0} |", zs.join(" | "), d.steps, d.max_rhat(), d.min_ess());
    }
    // share ± binomial standard error √(p(1−p)/n) at the nominal p
    let row = |counts: &[usize; 7], nominal: f64| {
        let se = (nominal * (1.0 - nominal) / n as f64).sqrt();
        let cells = counts.map(|c| format!("{:.0} %", 100.0 * c as f64 / n as f64)).join(" | ");
        let all: usize = counts.iter().sum();
        format!("| {:.0} % interval (nominal ± 1 se: {:.0} ± {:.0} %) | {cells} | {:.0} % |", 100.0 * nominal, 100.0 * nominal, 100.0 * se, 100.0 * all as f64 / (7 * n) as f64)
    };
    println!("\nCoverage over {n} realisations:\n");
    println!("| | {} | all |", PARAM_NAMES.join(" | "));
    println!("|---|{}---|", "---|".repeat(7));
    println!("{}", row(&inside50, 0.5));
    println!("{}", row(&inside90, 0.9));
    println!("| largest abs(z) | {} | |", worst_z.map(|z| format!("{z:.2}")).join(" | "));
    println!("\nmean wall time per calibration: {:.1} s", seconds / n as f64);
    Ok(())
}
