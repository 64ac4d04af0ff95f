//! Benchmarks of the loops that decide mrbp's run time. Run with
//! `cargo bench` (or `just bench`); the figures go into docs/performance.md.

use std::hint::black_box;
use std::time::Instant;

use mrbp::model::{Integrator, Params, Scheme};
use mrbp::sampler::{Elliptical, LogDensity, Moments, Move, RunControl, Sampler, SamplerSettings};

/// Best of `repeats` timings of `f`, in seconds.
fn best_of(repeats: usize, mut f: impl FnMut()) -> f64 {
    (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn crank_history(n: usize, rate_hz: f64, rpm: f64) -> (Vec<f64>, Vec<f64>) {
    let crank = mrbp::synth::Crank::default();
    let t: Vec<f64> = (0..n).map(|k| k as f64 / rate_hz).collect();
    let g = t.iter().map(|&t| crank.displacement(rpm, t) / 1e-3).collect();
    (t, g)
}

fn euler() {
    println!("## Euler integrator (one thread)\n");
    println!("| scheme | sample rate | sub-steps | ns per sample interval | M Euler steps/s |");
    println!("|---|---|---|---|---|");
    let p = Params::reference_1a();
    for (rate, rpm) in [(5000.0, 100.0), (10000.0, 400.0)] {
        let (t, g) = crank_history(6000, rate, rpm);
        for (scheme, extrapolate) in
            [(Scheme::Explicit, false), (Scheme::LinearlyImplicit, false), (Scheme::Explicit, true)]
        {
            for substeps in [1, 4] {
                let integ = Integrator { scheme, substeps, extrapolate, ..Integrator::default() };
                let secs = best_of(20, || {
                    let mut acc = 0.0;
                    integ.run_with(&p, &t, &g, Default::default(), |_, s| acc += s.tau).unwrap();
                    black_box(acc);
                });
                let per = secs / (t.len() - 1) as f64;
                let euler_steps = if extrapolate { 3 * substeps } else { substeps } as f64;
                println!(
                    "| {scheme:?}{} | {rate} Hz, {rpm} rpm | {substeps} | {:.1} | {:.1} |",
                    if extrapolate { " + Richardson" } else { "" },
                    per * 1e9,
                    euler_steps * 1e-6 / per
                );
            }
        }
    }
    println!();
}

struct Cheap;
impl LogDensity for Cheap {
    fn dim(&self) -> usize {
        10
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        -0.5 * x.iter().map(|v| v * v).sum::<f64>()
    }
}

fn sampler_overhead() {
    println!("## Sampler overhead (cheap 10-D target, all threads)\n");
    let init: Vec<Vec<f64>> =
        (0..128).map(|c| (0..10).map(|i| ((c * 10 + i) as f64).sin()).collect()).collect();
    let steps = 2000;
    let secs = best_of(3, || {
        let mut s = Sampler::new(&Cheap, SamplerSettings::default(), &init).unwrap();
        s.run(&RunControl::fixed(steps), &mut []).unwrap();
        black_box(s.chains.positions.len());
    });
    let per = secs / (steps * 128) as f64;
    println!("| moves | walker-steps | ns per walker-step |");
    println!("|---|---|---|");
    println!("| stretch | {} | {:.0} |", steps * 128, per * 1e9);
    let mixtures = [
        (
            "DE 0.8 + snooker 0.2",
            vec![(Move::differential_evolution(), 0.8), (Move::snooker(), 0.2)],
        ),
        (
            "independence 0.9 + DE 0.1",
            vec![(Move::independence(), 0.9), (Move::differential_evolution(), 0.1)],
        ),
        (
            "anchored 0.9 + DE 0.1 (the default)",
            vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
        ),
    ];
    // the anchored move's reference: the target itself, N(0, I)
    let reference = Elliptical::new(Moments {
        mean: nalgebra::DVector::zeros(10),
        cov: nalgebra::DMatrix::identity(10, 10),
    })
    .unwrap();
    for (name, moves) in mixtures {
        let settings = SamplerSettings { moves, ..SamplerSettings::default() };
        let secs = best_of(3, || {
            let mut s = Sampler::new(&Cheap, settings.clone(), &init)
                .unwrap()
                .with_reference(reference.clone());
            s.run(&RunControl::fixed(steps), &mut []).unwrap();
            black_box(s.chains.positions.len());
        });
        println!("| {name} | {} | {:.0} |", steps * 128, secs / (steps * 128) as f64 * 1e9);
    }
    let secs = best_of(3, || {
        let mut s = Sampler::new(&Cheap, SamplerSettings::default(), &init).unwrap();
        s.run(&RunControl::fixed(steps), &mut []).unwrap();
        black_box(s.diagnostics());
    });
    println!(
        "\nDiagnostics of 128 chains × {steps} steps × 10 coordinates (with sampling): {:.2} s\n",
        secs
    );
}

/// Max |τ − τ_ref| of the integrators against a reference 256 times finer,
/// on one crank revolution at 100 rpm sampled at 5 kHz (the bundled runs),
/// with the 1 A parameters and with a stiff set (G ten times larger, n = 3).
fn convergence() {
    println!("## Convergence against a fine-step reference\n");
    let (t, g) = crank_history(3001, 5000.0, 100.0);
    let mut stiff = Params::reference_1a();
    stiff.g *= 10.0;
    stiff.n = 3.0;
    for (name, p) in [("1 A reference", Params::reference_1a()), ("stiff: 10 G, n = 3", stiff)] {
        let solve = |scheme, substeps, extrapolate| {
            Integrator {
                scheme,
                substeps,
                extrapolate,
                max_substeps: 100_000,
                ..Integrator::default()
            }
            .run(&p, &t, &g)
            .unwrap()
            .tau
        };
        let run = |scheme, substeps| solve(scheme, substeps, false);
        let reference = solve(Scheme::Explicit, 256, true);
        let peak = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        println!("{name}: peak τ = {:.0} Pa\n", peak);
        println!("| sub-steps per sample | explicit: max error (Pa) | ratio | linearly implicit: max error (Pa) | ratio |");
        println!("|---|---|---|---|---|");
        let mut last = (f64::NAN, f64::NAN);
        for m in [1, 2, 4, 8, 16] {
            let err = |scheme| {
                run(scheme, m)
                    .iter()
                    .zip(&reference)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            };
            let (e, li) = (err(Scheme::Explicit), err(Scheme::LinearlyImplicit));
            println!("| {m} | {e:.2} | {:.2} | {li:.2} | {:.2} |", last.0 / e, last.1 / li);
            last = (e, li);
        }
        println!("\nRichardson-extrapolated (m and 2m sub-steps), max and RMS error (Pa):\n");
        println!("| m | explicit: max | RMS | linearly implicit: max | RMS |");
        println!("|---|---|---|---|---|");
        for m in [1, 2, 4, 8] {
            let err = |scheme| {
                let d: Vec<f64> =
                    solve(scheme, m, true).iter().zip(&reference).map(|(a, b)| a - b).collect();
                (
                    d.iter().fold(0.0f64, |x, v| x.max(v.abs())),
                    (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt(),
                )
            };
            let (e, li) = (err(Scheme::Explicit), err(Scheme::LinearlyImplicit));
            println!("| {m} | {:.2} | {:.3} | {:.2} | {:.3} |", e.0, e.1, li.0, li.1);
        }
        println!();
    }
}

/// The B-P log-density over the bundled 1 A runs, evaluated as the sampler
/// does (batches of 8 walkers, all threads).
fn likelihood() {
    use mrbp::calibrate::CalibrationSettings;
    use rayon::prelude::*;
    println!("## Log-density of the bundled 1 A runs (3 runs, 10 500 sample intervals)\n");
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let campaign =
        mrbp::data::Campaign::load(&repo.join("data/campaign.toml")).unwrap().at_current(1.0);
    let settings = CalibrationSettings::default();
    let intervals: usize = campaign.runs.iter().map(|r| r.shear.len() - 1).sum();
    println!("| integrator | threads | walkers per batch | log-densities/s | M walker-steps/s |");
    println!("|---|---|---|---|---|");
    for (extrapolate, substeps) in [(false, 1), (true, 1), (true, 2)] {
        let integ = Integrator { extrapolate, substeps, ..Integrator::default() };
        let post = settings.posterior(&campaign, integ);
        let d = post.dim();
        let p = Params::reference_1a().to_array();
        let points: Vec<f64> = (0..96)
            .flat_map(|w| {
                let mut si = p.to_vec();
                si[0] *= 1.0 + 1e-3 * (w as f64).sin();
                si.extend([400.0; 3]);
                post.layout.from_si(&si)
            })
            .collect();
        assert!(
            post.log_density(&points[..d]).is_finite(),
            "the benchmark's points lie in the support"
        );
        for (threads, batch) in [(1, 1), (1, 8), (2, 8)] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let secs = best_of(3, || {
                pool.install(|| {
                    let mut out = vec![0.0; 96];
                    points
                        .par_chunks(d * batch)
                        .zip(out.par_chunks_mut(batch))
                        .for_each(|(x, o)| post.log_density_batch(x, o));
                    black_box(out);
                })
            });
            let evals = 96.0 / secs;
            let steps_per_eval =
                intervals as f64 * substeps as f64 * if extrapolate { 3.0 } else { 1.0 };
            println!(
                "| Euler{} × {substeps} | {threads} | {batch} | {evals:.0} | {:.1} |",
                if extrapolate { " + Richardson" } else { "" },
                evals * steps_per_eval * 1e-6
            );
        }
    }
    println!();
}

/// The log-density at a calibration's start, as the sampler calls it (96
/// walkers about the MAP, spread by the Laplace sds, batches of eight),
/// on the bundled virtual and the measured 1 A records: the integrator the
/// step rule chose, the Euler steps one log-density takes there (counted,
/// with the sub-steps the stability control adds), and their rate.
fn likelihood_at_start() {
    use mrbp::calibrate::CalibrationSettings;
    use rayon::prelude::*;
    println!("## Log-density at the start of a 1 A calibration (default settings, the step rule's integrator)\n");
    println!("| records | samples | integrator | Euler steps per log-density (nominal, counted) | threads | log-densities/s | M walker-steps/s (counted) |");
    println!("|---|---|---|---|---|---|---|");
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for (name, manifest) in [
        ("bundled virtual", "data/campaign.toml"),
        ("measured (utfsm-mts)", "data/utfsm-mts/campaign.toml"),
    ] {
        let campaign = mrbp::data::Campaign::load(&repo.join(manifest)).unwrap().at_current(1.0);
        let start =
            mrbp::calibrate::start::start(&campaign, &CalibrationSettings::default(), &mut |_| {})
                .unwrap();
        let post = &start.posterior;
        let d = post.dim();
        let nt = start.map.cov.nrows();
        let sd: Vec<f64> =
            (0..d).map(|i| if i < nt { start.map.cov[(i, i)].sqrt() } else { 0.0 }).collect();
        let points: Vec<f64> = (0..96)
            .flat_map(|w| {
                (0..d)
                    .map(|i| start.map.x[i] + 0.5 * sd[i] * ((w * (i + 1)) as f64).sin())
                    .collect::<Vec<f64>>()
            })
            .collect();
        let counted: u64 =
            points.chunks(d).map(|x| mrbp::posterior::map::euler_steps(post, x)).sum::<u64>() / 96;
        let samples: usize = campaign.runs.iter().map(|r| r.shear.len()).sum();
        let integ = &post.integrator;
        let nominal = (samples - campaign.runs.len()) as u64
            * integ.substeps as u64
            * if integ.extrapolate { 3 } else { 1 };
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let secs = best_of(3, || {
                pool.install(|| {
                    let mut out = vec![0.0; 96];
                    points
                        .par_chunks(d * mrbp::model::LANES)
                        .zip(out.par_chunks_mut(mrbp::model::LANES))
                        .for_each(|(x, o)| post.log_density_batch(x, o));
                    black_box(out);
                })
            });
            let evals = 96.0 / secs;
            println!(
                "| {name} | {samples} | {:?} × {} | {nominal}, {counted} | {threads} | {evals:.0} | {:.1} |",
                integ.scheme,
                integ.substeps,
                evals * counted as f64 * 1e-6
            );
        }
    }
    println!();
}

/// One current of three campaigns calibrated with the default settings, to
/// R̂ < 1.01 and ESS ≥ 400: the bundled virtual campaign (1 A), a fresh
/// `mrbp synth` campaign at 2 kHz with 20 N force noise (1 A), and the
/// bundled measured campaign (1 A).
fn calibration() {
    use mrbp::calibrate::{calibrate, CalibrationSettings};
    use mrbp::data::Campaign;
    use mrbp::synth::{write_campaign, SynthSettings};
    println!(
        "## One current calibrated to R̂ < 1.01 and ESS ≥ 400 (default settings, all threads)\n"
    );
    println!("| campaign | runs | samples | wall (s) | of which start (s) | steps × walkers | acceptance | min bulk ESS | min tail ESS | max R̂ | ESS/s (min over θ) | M walker-steps/s |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let fresh = tempfile::tempdir().unwrap();
    let synth = SynthSettings {
        currents_a: vec![1.0],
        rate_hz: 2000.0,
        noise_force_n: 20.0,
        seed: 99,
        ..SynthSettings::default()
    };
    write_campaign(&synth, fresh.path()).unwrap();
    let campaigns = [
        ("bundled virtual", repo.join("data/campaign.toml")),
        ("fresh synth, 2 kHz", fresh.path().join("campaign.toml")),
        ("bundled measured (utfsm-mts)", repo.join("data/utfsm-mts/campaign.toml")),
    ];
    for (name, manifest) in campaigns {
        let campaign = Campaign::load(&manifest).unwrap().at_current(1.0);
        let cal = calibrate(&campaign, &CalibrationSettings::default()).unwrap();
        let d = &cal.diagnostics;
        let nt = cal.start.posterior.layout.theta.len();
        let min_bulk = d.coordinates[..nt].iter().map(|c| c.ess_bulk).fold(f64::INFINITY, f64::min);
        let samples: usize = campaign.runs.iter().map(|r| r.shear.len()).sum();
        let chains = cal.chains.chains();
        let evals = (d.steps * chains) as f64;
        let integ = &cal.start.posterior.integrator;
        let euler_per_interval = integ.substeps as f64 * if integ.extrapolate { 3.0 } else { 1.0 };
        let acceptance = d.acceptance.iter().sum::<f64>() / d.acceptance.len() as f64;
        println!(
            "| {name} | {} | {samples} | {:.1} | {:.1} | {} × {chains} | {acceptance:.2} | {:.0} | {:.0} | {:.4} | {:.0} | {:.0} |",
            campaign.runs.len(),
            cal.calibration.seconds(),
            cal.start.seconds,
            d.steps,
            min_bulk,
            d.min_ess(),
            d.max_rhat(),
            min_bulk / cal.calibration.seconds(),
            evals * samples as f64 * euler_per_interval / cal.calibration.record.seconds_sampling * 1e-6
        );
    }
    println!();
}

/// One integration of each damper law along the measured 1 A records (four
/// runs, 1 kHz), eight parameter sets a call (the lanes) about the law's
/// first start, one thread: what a log-density of each law costs.
fn laws() {
    use mrbp::data::{Campaign, RecordPart, RunData};
    use mrbp::laws::LawKind;
    println!("## Damper laws along the measured 1 A records (eight lanes, one thread)\n");
    println!("| law | sub-steps | extrapolated | ms per integration of the four runs (per lane) | evaluations (Euler-step equivalents) per lane | M per s |");
    println!("|---|---|---|---|---|---|");
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let campaign =
        Campaign::load(&repo.join("data/utfsm-mts/campaign.toml")).unwrap().at_current(1.0);
    let runs: Vec<RunData> =
        campaign.runs.iter().map(|r| RunData::from_run(r, RecordPart::WholeRecord, 2.0)).collect();
    for kind in LawKind::ALL {
        let law = kind.law();
        let start = law.starts(&runs)[0];
        let lanes: [mrbp::laws::LawValues; mrbp::model::LANES] = std::array::from_fn(|lane| {
            let mut q = start;
            q[lane % law.parameters().len()] *= 1.0 + 0.01 * lane as f64;
            mrbp::laws::clamped(law, q)
        });
        for substeps in [1, 4] {
            let integ = Integrator { substeps, extrapolate: true, ..Integrator::default() };
            let secs = best_of(3, || {
                let mut acc = 0.0;
                for run in &runs {
                    let _ = law.run_lanes(&integ, &lanes, run, &mut |_, s| acc += s[0]);
                }
                black_box(acc);
            });
            let steps: u64 = runs.iter().map(|r| law.euler_steps(&integ, &start, r)).sum();
            let per_lane = secs / mrbp::model::LANES as f64;
            println!(
                "| {} | {substeps} | yes | {:.2} | {steps} | {:.1} |",
                kind.name(),
                per_lane * 1e3,
                steps as f64 * 1e-6 / per_lane
            );
        }
    }
    println!();
}

fn main() {
    let only = std::env::args().nth(1).filter(|a| !a.starts_with('-'));
    let want = |name: &str| only.as_deref().is_none_or(|o| name.contains(o));
    if want("euler") {
        euler();
    }
    if want("convergence") {
        convergence();
    }
    if want("likelihood") {
        likelihood();
    }
    if want("sampler") {
        sampler_overhead();
    }
    if want("start") {
        likelihood_at_start();
    }
    if want("laws") {
        laws();
    }
    if want("calibration") {
        calibration();
    }
}
