//! Simulation-based calibration (Talts et al. 2018) of the whole
//! calibration, on a reduced problem that runs in minutes: for each
//! replicate, draw θ and σ from the prior, make a virtual campaign with them
//! (one crank revolution at 200 rpm, 1 kHz, 1 A: 300 samples), calibrate it
//! with the same prior, and record the rank of each true value among L
//! nearly independent posterior draws (thinned by ⌈τ_max⌉). If the
//! posterior is right, every rank is uniform on 0..=L. Prints the χ² test
//! of uniformity over 10 bins per parameter and draws the rank histograms
//! into `docs/sbc.svg`/`.png`.
//!
//!     cargo run --release --example sbc -- [N] [DISPLACEMENT_NOISE_M]
//!
//! N defaults to 200, the displacement noise to 0 (with noise, the
//! default errors-in-variables likelihood is what is checked; the figure
//! then goes to `docs/sbc_eiv`). The prior is the default one narrowed to a realistic
//! box — log-normal about the 1 A reference parameters, sd 0.2 in ln θ,
//! truncated at ±2 sd — and σ log-uniform on [200, 600] Pa; data and
//! calibration use the same, as SBC requires.

use mrbp::calibrate::{calibrate, CalibrationSettings};
use mrbp::data::Campaign;
use mrbp::model::{Params, PARAM_NAMES};
use mrbp::plot::{self, Chart, Figure, Series, GREY, PALETTE};
use mrbp::posterior::Prior;
use mrbp::synth::{write_campaign, StandLaw, SynthSettings};
use rand::RngExt;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Posterior draws each true value is ranked among.
const L: usize = 99;
const BINS: usize = 10;
const SD_LOG: f64 = 0.2;
const SIGMA_PA: (f64, f64) = (200.0, 600.0);

fn main() -> mrbp::Result<()> {
    let n: u64 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(200);
    let noise_x: f64 = std::env::args().nth(2).and_then(|a| a.parse().ok()).unwrap_or(0.0);
    let reference = Params::reference_1a().to_array();
    let priors: [Prior; 7] = std::array::from_fn(|i| {
        let m = reference[i];
        let spread = (2.0 * SD_LOG).exp();
        Prior::LogNormal { median: m, sd_log: SD_LOG, lower: m / spread, upper: m * spread }
    });
    let mut settings = CalibrationSettings::default();
    for (name, prior) in PARAM_NAMES.iter().zip(priors) {
        settings.prior.insert(name.to_string(), prior);
    }
    settings.sigma_bounds_pa = SIGMA_PA;
    let mut ranks = vec![Vec::new(); 7];
    let (mut failed, mut seconds) = (0, 0.0);
    for rep in 0..n {
        let mut rng = mrbp::rng::stream(2018, &[rep]);
        // θ from the truncated log-normal by rejection, σ log-uniform
        let theta: [f64; 7] = std::array::from_fn(|i| loop {
            let z: f64 = rng.sample(rand_distr::StandardNormal);
            if z.abs() <= 2.0 {
                break reference[i] * (SD_LOG * z).exp();
            }
        });
        let sigma = (SIGMA_PA.0.ln() + rng.random::<f64>() * (SIGMA_PA.1 / SIGMA_PA.0).ln()).exp();
        let dir = tempfile::tempdir().expect("temporary folder");
        let synth = SynthSettings {
            law: StandLaw { at_1a: Params::from_array(theta), saturation_a: 1.0 },
            currents_a: vec![1.0],
            rpms: vec![200.0],
            cycles: 1.0,
            rate_hz: 1000.0,
            noise_force_n: sigma * 0.05,
            noise_displacement_m: noise_x,
            seed: 5000 + rep,
            ..SynthSettings::default()
        };
        write_campaign(&synth, dir.path())?;
        let campaign = Campaign::load(&dir.path().join("campaign.toml"))?;
        settings.sampler.seed = rep + 1;
        let cal = match calibrate(&campaign, &settings) {
            Ok(cal) => cal,
            Err(e) => {
                eprintln!("replicate {rep}: {e} (θ / reference: {:?}, σ {sigma:.0} Pa)", theta.iter().zip(&reference).map(|(t, r)| (t / r * 100.0).round() / 100.0).collect::<Vec<f64>>());
                failed += 1;
                continue;
            }
        };
        seconds += cal.seconds();
        let d = &cal.diagnostics;
        let thin = d.tau_max.ceil().max(1.0) as usize;
        let positions = cal.sample.positions(d.burn_in, thin, L);
        for (i, name) in PARAM_NAMES.iter().enumerate() {
            let draws = cal.sample.values(name, &positions).expect("a B-P parameter");
            // rank on 0..=L, scaled when fewer than L draws were available
            let below = draws.iter().filter(|v| **v < theta[i]).count();
            ranks[i].push(below as f64 / draws.len() as f64);
        }
        if (rep + 1) % 20 == 0 {
            eprintln!("{} replicates, {:.1} s per calibration", rep + 1, seconds / (rep + 1 - failed) as f64);
        }
    }
    let kept = ranks[0].len();
    println!("SBC: displacement noise {noise_x:e} m, {kept} replicates ({failed} failed), {L} draws each, {BINS} bins, {:.1} s per calibration\n", seconds / kept.max(1) as f64);
    println!("| parameter | counts per bin | χ² ({} dof) | p |", BINS - 1);
    println!("|---|---|---|---|");
    let expected = kept as f64 / BINS as f64;
    let chi2 = ChiSquared::new((BINS - 1) as f64).expect("positive dof");
    let mut panels = Vec::new();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        let mut counts = [0usize; BINS];
        for r in &ranks[i] {
            counts[((r * BINS as f64) as usize).min(BINS - 1)] += 1;
        }
        let stat: f64 = counts.iter().map(|c| (*c as f64 - expected).powi(2) / expected).sum();
        let p = 1.0 - chi2.cdf(stat);
        println!("| {name} | {} | {stat:.1} | {p:.3} |", counts.map(|c| c.to_string()).join(" "));
        let edges: Vec<f64> = (0..=BINS).map(|b| b as f64 / BINS as f64).collect();
        let mut c = Chart::new(format!("{name}: p = {p:.2}"), "rank / L", "replicates");
        c.series.push(Series::bars(None, PALETTE[0], edges, counts.map(|c| c as f64).to_vec()));
        // the band a uniform histogram stays in 99 % of the time per bin (binomial)
        let sd = (kept as f64 * (1.0 / BINS as f64) * (1.0 - 1.0 / BINS as f64)).sqrt();
        for level in [expected - 2.58 * sd, expected, expected + 2.58 * sd] {
            c.series.push(Series::dashed(None, GREY, vec![0.0, 1.0], vec![level, level]));
        }
        c.legend = false;
        panels.push(c);
    }
    let stem = if noise_x > 0.0 { "docs/sbc_eiv" } else { "docs/sbc" };
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(stem);
    plot::save(&Figure::grid(panels, 4), &out)?;
    println!("\nwrote {}.svg and .png", out.display());
    Ok(())
}
