//! Sequential Monte Carlo on targets whose normalising constant, moments
//! and basin weights are known in closed form. Tolerances are multiples
//! of the run's own Monte Carlo standard error: for the evidence, the
//! larger of the incremental weights' and the populations' spread
//! (`Evidence::se`); for a moment or a weight, the spread of the
//! populations' estimates over √P (P independent populations). Seeds are
//! fixed.

use mrbp::sampler::smc::{self, Reference, SmcRun, SmcSettings};
use mrbp::sampler::{Elliptical, LogDensity, Moments};
use nalgebra::{DMatrix, DVector};

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// A Gaussian reference: mean `mean` in every coordinate, sd `sd`.
fn reference(d: usize, mean: f64, sd: f64) -> Reference {
    Reference {
        dist: Elliptical::new(Moments {
            mean: DVector::from_element(d, mean),
            cov: DMatrix::from_diagonal_element(d, d, sd * sd),
        })
        .unwrap(),
        df: None,
    }
}

fn run(
    target: &impl LogDensity,
    reference: &Reference,
    particles: usize,
    populations: usize,
) -> SmcRun {
    let settings = SmcSettings { particles, populations, seed: 11, ..SmcSettings::default() };
    smc::run(target, reference, &settings, Vec::new(), &mut (), &|| false).unwrap()
}

/// Each population's mean of `f` over its particles.
fn population_means(run: &SmcRun, f: impl Fn(&[f64]) -> f64) -> Vec<f64> {
    run.populations
        .iter()
        .map(|p| {
            let values: Vec<f64> = p.positions.chunks_exact(run.dim).map(&f).collect();
            values.iter().sum::<f64>() / values.len() as f64
        })
        .collect()
}

/// The mean of `f` over every particle and its Monte Carlo standard error
/// (the populations' spread over √P).
fn estimate(run: &SmcRun, f: impl Fn(&[f64]) -> f64) -> (f64, f64) {
    let m = population_means(run, f);
    let p = m.len() as f64;
    let mean = m.iter().sum::<f64>() / p;
    let var = m.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (p - 1.0);
    (mean, (var / p).sqrt())
}

/// The evidence within 3 of its standard errors and 0.2 nat of `truth`.
fn assert_evidence(run: &SmcRun, truth: f64, what: &str) {
    let e = &run.evidence;
    let err = e.log_z - truth;
    eprintln!(
        "{what}: ln Z {:.4} (truth {truth:.4}, error {err:+.4}); se from the weights {:.4}, from the spread {:.4}; {} temperatures",
        e.log_z,
        e.se_weights,
        e.se_spread,
        run.populations[0].stages.len()
    );
    for p in &run.populations {
        let stages: Vec<String> = p
            .stages
            .iter()
            .map(|s| {
                format!(
                    "β {:.2e} ess {:.0} steps {} acc {:.2}",
                    s.beta, s.ess, s.steps, s.acceptance
                )
            })
            .collect();
        eprintln!("  ln Ẑ {:.4}: {}", p.log_z, stages.join("; "));
    }
    assert!(err.abs() <= 3.0 * e.se() && err.abs() <= 0.2, "{what}: ln Z off by {err}");
}

/// ln p = c − ½ (x − μ)ᵀ Σ⁻¹ (x − μ): Z = e^c (2π)^{d/2} |Σ|^{1/2}.
struct Gaussian {
    c: f64,
    mu: DVector<f64>,
    precision: DMatrix<f64>,
}

impl LogDensity for Gaussian {
    fn dim(&self) -> usize {
        self.mu.len()
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        let r = DVector::from_column_slice(x) - &self.mu;
        self.c - 0.5 * r.dot(&(&self.precision * &r))
    }
}

/// Σ = Q diag(λ) Qᵀ, λ log-spaced over [0.25, 25] (sd 0.5 to 5, condition
/// number 100), Q a fixed rotation; μᵢ = 1 + i / d.
fn correlated(d: usize, c: f64) -> (Gaussian, DMatrix<f64>) {
    use rand::RngExt;
    let mut rng = mrbp::rng::stream(5, &[]);
    let a = DMatrix::from_fn(d, d, |_, _| rng.random::<f64>() - 0.5);
    let q = a.qr().q();
    let lambda = DVector::from_fn(d, |i, _| 0.25 * 100f64.powf(i as f64 / (d - 1) as f64));
    let cov = &q * DMatrix::from_diagonal(&lambda) * q.transpose();
    let precision = cov.clone().try_inverse().unwrap();
    let mu = DVector::from_fn(d, |i, _| 1.0 + i as f64 / d as f64);
    (Gaussian { c, mu, precision }, cov)
}

fn log_z_gaussian(c: f64, cov: &DMatrix<f64>) -> f64 {
    let d = cov.nrows() as f64;
    c + 0.5 * d * LN_2PI + 0.5 * cov.determinant().ln()
}

/// A correlated Gaussian in 10 dimensions from a reference 4× wider than
/// its widest axis: the evidence, and every coordinate's mean and variance
/// within 5 Monte Carlo standard errors.
#[test]
fn correlated_gaussian_in_10_dimensions_evidence_and_moments() {
    let (target, cov) = correlated(10, -7.5);
    let run = run(&target, &reference(10, 0.0, 20.0), 512, 8);
    assert_evidence(&run, log_z_gaussian(-7.5, &cov), "Gaussian, d = 10");
    for i in 0..10 {
        let (m, se) = estimate(&run, |x| x[i]);
        assert!(
            (m - target.mu[i]).abs() <= 5.0 * se,
            "mean {i}: {m} ± {se}, truth {}",
            target.mu[i]
        );
        let (v, se) = estimate(&run, |x| (x[i] - target.mu[i]).powi(2));
        assert!(
            (v - cov[(i, i)]).abs() <= 5.0 * se,
            "variance {i}: {v} ± {se}, truth {}",
            cov[(i, i)]
        );
    }
    for i in 0..10 {
        let rhat = run.rhat(|x| x[i]);
        assert!(rhat < 1.01, "R̂ of coordinate {i} across the populations: {rhat}");
    }
}

/// The same in 40 dimensions, from a reference shaped as a Laplace
/// approximation that missed: its covariance the target's times 1.5², its
/// mean half the widest sd off in every coordinate. The evidence and three
/// coordinates' means.
#[test]
#[ignore = "slow tier: 40 s (2.6 million proposals, whose fitting and drawing in 40 dimensions cost more than this target)"]
fn correlated_gaussian_in_40_dimensions_evidence() {
    let (target, cov) = correlated(40, 12.0);
    let missed = Reference {
        dist: Elliptical::new(Moments { mean: target.mu.add_scalar(2.5), cov: &cov * 2.25 })
            .unwrap(),
        df: None,
    };
    let run = run(&target, &missed, 512, 8);
    assert_evidence(&run, log_z_gaussian(12.0, &cov), "Gaussian, d = 40");
    for i in [0, 20, 39] {
        let (m, se) = estimate(&run, |x| x[i]);
        assert!(
            (m - target.mu[i]).abs() <= 5.0 * se,
            "mean {i}: {m} ± {se}, truth {}",
            target.mu[i]
        );
    }
}

/// 0.3 N(−m, I) + 0.7 N(m, 0.5² I) in 4 dimensions, m = (3, 3, 3, 3)
/// (the basins 12 sd apart, no walker crosses), times e^c: Z = e^c. The
/// evidence and the heavier basin's share within 3 Monte Carlo standard
/// errors.
struct TwoBasins {
    c: f64,
}

impl LogDensity for TwoBasins {
    fn dim(&self) -> usize {
        4
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        let d = 4.0;
        let light =
            0.3f64.ln() - 0.5 * d * LN_2PI - 0.5 * x.iter().map(|v| (v + 3.0).powi(2)).sum::<f64>();
        let heavy = 0.7f64.ln()
            - 0.5 * d * LN_2PI
            - d * 0.5f64.ln()
            - 0.5 * x.iter().map(|v| ((v - 3.0) / 0.5).powi(2)).sum::<f64>();
        self.c + mrbp::numeric::log_sum_exp(&[light, heavy])
    }
}

#[test]
fn two_basins_of_unequal_mass_evidence_and_weights() {
    let run = run(&TwoBasins { c: 4.0 }, &reference(4, 0.0, 6.0), 512, 8);
    assert_evidence(&run, 4.0, "two basins");
    let (share, se) = estimate(&run, |x| if x[0] > 0.0 { 1.0 } else { 0.0 });
    eprintln!("the heavier basin's share {share:.4} ± {se:.4} (truth 0.7)");
    assert!((share - 0.7).abs() <= 3.0 * se && se < 0.05, "share {share} ± {se}");
    let (m, se) = estimate(&run, |x| x[1]);
    // the mean: 0.3 (−3) + 0.7 (3) = 1.2
    assert!((m - 1.2).abs() <= 5.0 * se, "mean {m} ± {se}");
}

/// A banana: x₀ ~ N(0, 1.5²), x₁ | x₀ ~ N(x₀² − 2.25, 0.5²), and two
/// more coordinates N(0, 1); the map to independent coordinates has
/// Jacobian 1, so Z = e^c (2π)² · 1.5 · 0.5. E x₁ = 0, Var x₁ = 2 · 1.5⁴ +
/// 0.5² = 10.375.
struct Banana {
    c: f64,
}

impl LogDensity for Banana {
    fn dim(&self) -> usize {
        4
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        self.c
            - 0.5 * (x[0] / 1.5).powi(2)
            - 0.5 * ((x[1] - x[0] * x[0] + 2.25) / 0.5).powi(2)
            - 0.5 * (x[2] * x[2] + x[3] * x[3])
    }
}

#[test]
fn banana_evidence_and_moments() {
    let c = -3.0;
    let run = run(&Banana { c }, &reference(4, 0.0, 5.0), 512, 8);
    assert_evidence(&run, c + 2.0 * LN_2PI + (1.5f64 * 0.5).ln(), "banana");
    let (m, se) = estimate(&run, |x| x[1]);
    assert!(m.abs() <= 5.0 * se, "E x₁ {m} ± {se}");
    let (v, se) = estimate(&run, |x| x[1] * x[1]);
    assert!((v - 10.375).abs() <= 5.0 * se, "Var x₁ {v} ± {se}, truth 10.375");
    let (v, se) = estimate(&run, |x| x[0] * x[0]);
    assert!((v - 2.25).abs() <= 5.0 * se, "Var x₀ {v} ± {se}, truth 2.25");
}

/// Bridge sampling (`sampler::bridge`) on the same known targets, from
/// exact draws (so that its error is the estimator's alone): 3 000 draws
/// to fit the Gaussian proposal, 3 000 to bridge with, as many proposed.
/// The evidence within 3 of its standard errors and 0.2 nat, as asked of
/// sequential Monte Carlo; the two basins' proposal is one Gaussian over
/// both, the banana's a Gaussian over a curved ridge: the cases where a
/// bridge's proposal is furthest from its target.
#[test]
fn bridge_sampling_from_exact_draws_gives_the_known_evidence() {
    use mrbp::sampler::bridge::log_evidence;
    use rand::RngExt;
    use rand_distr::StandardNormal;
    let n = 3000;
    let mut rng = mrbp::rng::stream(21, &[]);
    let normal = |rng: &mut rand_chacha::ChaCha8Rng| -> f64 { rng.sample(StandardNormal) };
    // the correlated Gaussian: μ + L z
    let (target, cov) = correlated(10, -7.5);
    let l = cov.clone().cholesky().unwrap().l();
    let gaussian = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f64> {
        (0..2 * n)
            .flat_map(|_| {
                let z = DVector::from_fn(10, |_, _| normal(rng));
                (&target.mu + &l * z).iter().copied().collect::<Vec<_>>()
            })
            .collect()
    };
    let points = gaussian(&mut rng);
    let (fit, draws) = points.split_at(n * 10);
    let b = log_evidence(&target, fit, draws, n as f64, &mut rng).unwrap();
    let truth = log_z_gaussian(-7.5, &cov);
    eprintln!("Gaussian, d = 10: bridge {:.4} ± {:.4}, truth {truth:.4}", b.log_z, b.se);
    assert!((b.log_z - truth).abs() <= (3.0 * b.se).min(0.2), "{b:?} against {truth}");
    // two basins: the heavier with probability 0.7
    let basins: Vec<f64> = (0..2 * n)
        .flat_map(|_| {
            let heavy = rng.random::<f64>() < 0.7;
            (0..4)
                .map(|_| {
                    let z = normal(&mut rng);
                    if heavy {
                        3.0 + 0.5 * z
                    } else {
                        -3.0 + z
                    }
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let (fit, draws) = basins.split_at(n * 4);
    let b = log_evidence(&TwoBasins { c: 4.0 }, fit, draws, n as f64, &mut rng).unwrap();
    eprintln!("two basins: bridge {:.4} ± {:.4}, truth 4", b.log_z, b.se);
    assert!((b.log_z - 4.0).abs() <= (3.0 * b.se).min(0.2), "{b:?}");
    // the banana: x₀ ~ N(0, 1.5²), x₁ = x₀² − 2.25 + 0.5 z
    let banana: Vec<f64> = (0..2 * n)
        .flat_map(|_| {
            let x0 = 1.5 * normal(&mut rng);
            vec![x0, x0 * x0 - 2.25 + 0.5 * normal(&mut rng), normal(&mut rng), normal(&mut rng)]
        })
        .collect();
    let (fit, draws) = banana.split_at(n * 4);
    let c = -3.0;
    let b = log_evidence(&Banana { c }, fit, draws, n as f64, &mut rng).unwrap();
    let truth = c + 2.0 * LN_2PI + (1.5f64 * 0.5).ln();
    eprintln!("banana: bridge {:.4} ± {:.4}, truth {truth:.4}", b.log_z, b.se);
    assert!((b.log_z - truth).abs() <= (3.0 * b.se).min(0.2), "{b:?} against {truth}");
}

/// The same seed gives the same particles and evidence bit for bit with
/// one thread or two.
#[test]
fn the_same_seed_gives_the_same_run_whatever_the_threads() {
    let runs: Vec<SmcRun> = [1, 2]
        .iter()
        .map(|&threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| run(&Banana { c: 0.0 }, &reference(4, 0.0, 5.0), 64, 2))
        })
        .collect();
    assert_eq!(runs[0], runs[1]);
}

/// `--sampler smc` on a virtual 1 A campaign (one crank revolution at
/// each speed): every population reaches β = 1, their estimates of the
/// posterior's integral agree within 4 of their standard errors, the
/// posterior means agree with the ensemble sampler's alone within 0.2 sd
/// (each mean's Monte Carlo error is about sd/√ESS ≈ 0.03 sd with ESS ≥
/// 400 in each), and the log evidence agrees with an independent
/// computation, the Laplace approximation's (ln p at the mode, plus
/// d/2 ln 2π, ½ ln |Σ| and the same normalising constants), within 0.5 nat: the
/// posterior is near Gaussian (2–3 temperatures from a Student-t about
/// it), and the two differ by its departure from a Gaussian, not by
/// Monte Carlo error (se ≈ 0.03).
#[test]
fn a_calibration_sampled_by_smc_agrees_with_the_ensemble_sampler_and_laplace() {
    use mrbp::calibrate::{calibrate, CalibrationSettings, SamplerMethod};
    let (_dir, campaign) = crate::common::virtual_campaign(&crate::common::one_revolution());
    let with = |method| {
        let mut s = CalibrationSettings::default();
        s.sampler.method = method;
        s.sampler.walkers = 64;
        s.sampler.seed = 3;
        calibrate(&campaign, &s).unwrap()
    };
    let (calibrated, ensemble) = (with(SamplerMethod::Smc), with(SamplerMethod::Ensemble));
    let (smc, ensemble) = (&calibrated.calibration, &ensemble.calibration);
    let record = smc.record.smc.as_ref().expect("an [smc] record");
    assert!(
        record.temperatures.iter().all(|t| t.last() == Some(&1.0)),
        "{:?}",
        record.temperatures
    );
    let spread =
        record.per_population.iter().fold(0.0f64, |m, v| m.max((v - record.log_integral).abs()));
    let se = record.se_weights.max(record.se_spread) * (record.per_population.len() as f64).sqrt();
    assert!(spread <= 4.0 * se, "populations' ln ∫ p spread by {spread}, each's se {se}");
    assert!(ensemble.record.smc.is_none());
    for (a, b) in smc.summary.iter().zip(&ensemble.summary) {
        let gap = (a.mean - b.mean).abs() / b.sd;
        assert!(
            gap < 0.2,
            "{}: smc {} ensemble {} (sd {}): {gap} sd apart",
            a.parameter,
            a.mean,
            b.mean,
            b.sd
        );
    }
    let posterior = &calibrated.start.posterior;
    let laplace = mrbp::posterior::laplace::at_mode(posterior, &calibrated.start.map);
    let d = laplace.dim() as f64;
    let by_laplace = posterior.log_density(laplace.mean.as_slice())
        + 0.5 * d * LN_2PI
        + laplace.half_log_det()
        + posterior.log_evidence_offset();
    eprintln!(
        "log evidence: smc {:.3} (se {:.3}), Laplace {by_laplace:.3}; temperatures {:?}",
        record.log_evidence,
        record.se_weights.max(record.se_spread),
        record.temperatures
    );
    assert!(
        (record.log_evidence - by_laplace).abs() < 0.5,
        "smc {} Laplace {by_laplace}",
        record.log_evidence
    );
    // the ensemble sampler's chains give the same evidence by bridge
    // sampling: within 3 combined standard errors
    let bridge = mrbp::calibrate::evidence::by_bridge(ensemble, &campaign).unwrap();
    let se = bridge.se.hypot(record.se_weights.max(record.se_spread));
    eprintln!(
        "bridge sampling from the ensemble's chains: {:.3} ± {:.3}",
        bridge.log_evidence, bridge.se
    );
    assert!(
        (bridge.log_evidence - record.log_evidence).abs() <= 3.0 * se,
        "bridge {} ± {}, smc {}",
        bridge.log_evidence,
        bridge.se,
        record.log_evidence
    );
    assert!(!bridge.pseudo);
}

/// ln p = c − ½|x|² where |x₀| < 4, and −1e80 (finite, astronomically
/// small, as a law's extreme parameters make a likelihood) beyond: a
/// fifth of the reference's draws lie there, so the first temperature is
/// forced to a step of about 1e-80. The evidence, c + 2 ln 2π + ln(Φ(4) −
/// Φ(−4)), within 3 standard errors and 0.2 nat: ln p is evaluated again
/// rather than recovered from ln π_β by dividing by such a β.
struct Walled {
    c: f64,
}

impl LogDensity for Walled {
    fn dim(&self) -> usize {
        4
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        if x[0].abs() < 4.0 {
            self.c - 0.5 * x.iter().map(|v| v * v).sum::<f64>()
        } else {
            -1e80
        }
    }
}

#[test]
fn a_first_step_forced_tiny_keeps_the_evidence() {
    let run = run(&Walled { c: 2.0 }, &reference(4, 0.0, 3.0), 256, 8);
    let first = run.populations[0].stages[0].beta;
    assert!(first < 1e-60, "the first temperature {first}");
    // Φ(4) − Φ(−4) = 1 − 6.334e-5
    assert_evidence(&run, 2.0 + 2.0 * LN_2PI + (1.0 - 6.334e-5f64).ln(), "walled Gaussian");
}

/// `mrbp sample --sampler smc`: config.toml keeps the method, the progress
/// tells each temperature, calibration.toml's `[smc]` has the log evidence,
/// and summary.parquet's metadata the same value; an ensemble calibration
/// has neither.
#[test]
fn sample_with_smc_writes_the_evidence_into_both_files() {
    use crate::common::{arg, ok, said, synth_small};
    use mrbp::store::parquet::parquet_meta;
    let dir = tempfile::tempdir().unwrap();
    let manifest = synth_small(dir.path(), "1.0");
    let out = dir.path().join("smc");
    let o = ok(&["sample", arg(&manifest), "--sampler", "smc", "--out", arg(&out)]);
    assert!(said(&o).contains("sequential Monte Carlo, population 4: β = 1.0000"), "{}", said(&o));
    let config = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(config.contains("method = \"smc\""), "{config}");
    // the populations' checkpoint has done its job with the calibration
    assert!(!out.join("smc.checkpoint").exists() && !out.join("sampler.checkpoint").exists());
    let record: toml::Value =
        toml::from_str(&std::fs::read_to_string(out.join("calibration.toml")).unwrap()).unwrap();
    let evidence = record["smc"]["log_evidence"].as_float().unwrap();
    let summary = out.join("summary.parquet");
    let meta = parquet_meta(&summary, mrbp::store::summary::LOG_EVIDENCE).unwrap().unwrap();
    assert_eq!(meta.parse::<f64>().unwrap(), evidence);
    assert!(parquet_meta(&summary, mrbp::store::summary::EVIDENCE_OF).unwrap().is_some());
    // the printed summary and the report say it, with the same digits
    let line = format!("log evidence {evidence:.2} ± ");
    assert!(said(&o).contains(&line), "{line} in {}", said(&o));
    ok(&["report", arg(&out)]);
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(page.contains("Sequential Monte Carlo and the log evidence"));
    assert!(page.contains(&line), "{line} in the report");
    let plain = dir.path().join("ensemble");
    ok(&["sample", arg(&manifest), "--out", arg(&plain)]);
    let record = std::fs::read_to_string(plain.join("calibration.toml")).unwrap();
    assert!(!record.contains("[smc]"));
    assert!(parquet_meta(&plain.join("summary.parquet"), mrbp::store::summary::LOG_EVIDENCE)
        .unwrap()
        .is_none());
    // `mrbp evidence`: sequential Monte Carlo's where it sampled, else by
    // bridge sampling from the chains, the two within 3 combined se
    let o = ok(&["evidence", arg(&out), arg(&plain)]);
    let printed = said(&o);
    let lines: Vec<&str> = printed.lines().collect();
    assert_eq!(lines.len(), 2, "{printed}");
    assert!(lines[0].contains(&format!("log evidence {evidence:.3} ± ")), "{}", lines[0]);
    assert!(
        lines[0].contains("(sequential Monte Carlo)") && lines[1].contains("(bridge sampling from")
    );
    let number = |line: &str, after: &str| -> f64 {
        let rest = &line[line.find(after).unwrap() + after.len()..];
        rest.split_whitespace().next().unwrap().parse().unwrap()
    };
    let (smc, smc_se) = (number(lines[0], "log evidence "), number(lines[0], "± "));
    let (bridged, bridged_se) = (number(lines[1], "log evidence "), number(lines[1], "± "));
    assert!((smc - bridged).abs() <= 3.0 * smc_se.hypot(bridged_se), "{printed}");
    // a folder that holds no calibration: a clear error, status 2
    let o = crate::common::mrbp(&["evidence", arg(dir.path())]);
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
}

/// `compare` of two calibrations of the same runs by sequential Monte
/// Carlo, Gaussian and Student-t noise: each one's log evidence, and the
/// log Bayes factor between them, equal to the difference of their
/// calibration.toml's.
#[test]
fn compare_shows_the_log_bayes_factor_of_the_same_runs() {
    use crate::common::{arg, ok, synth_small};
    let dir = tempfile::tempdir().unwrap();
    let manifest = synth_small(dir.path(), "1.0");
    let evidence = |name: &str| {
        let record = std::fs::read_to_string(dir.path().join(name).join("calibration.toml"));
        let record: toml::Value = toml::from_str(&record.unwrap()).unwrap();
        record["smc"]["log_evidence"].as_float().unwrap()
    };
    for noise in ["gaussian", "student-t"] {
        let out = dir.path().join(noise);
        ok(&["sample", arg(&manifest), "--sampler", "smc", "--noise", noise, "--out", arg(&out)]);
    }
    let out = dir.path().join("both");
    ok(&[
        "compare",
        arg(&dir.path().join("gaussian")),
        arg(&dir.path().join("student-t")),
        "--out",
        arg(&out),
    ]);
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    let d = evidence("gaussian") - evidence("student-t");
    let line = format!("(the same runs): log Bayes factor {:.2} ± ", d.abs());
    assert!(page.contains(&line), "{line} not in the comparison report");
    assert!(page.contains(&format!("{:.2} ± ", evidence("gaussian"))));
    // the same model sampled by the ensemble sampler: its evidence by
    // bridge sampling (marked b), and a log Bayes factor against SMC's of
    // the same model within 3 of its standard errors of 0
    let plain = dir.path().join("ensemble");
    ok(&["sample", arg(&manifest), "--noise", "gaussian", "--out", arg(&plain)]);
    let out = dir.path().join("same");
    ok(&["compare", arg(&dir.path().join("gaussian")), arg(&plain), "--out", arg(&out)]);
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(page.contains(" b</td>"), "the bridge's evidence is marked");
    let at = page.find("(the same runs): log Bayes factor ").expect("a Bayes factor");
    // "… log Bayes factor 0.01 ± 0.03.</p>"
    let number = |w: &str| -> f64 {
        let digits: String = w.chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
        digits.trim_end_matches('.').parse().unwrap()
    };
    let words: Vec<&str> = page[at..].split_whitespace().skip(6).take(3).collect();
    let numbers = [number(words[0]), number(words[2])];
    assert!(numbers[0] <= 3.0 * numbers[1], "log Bayes factor {} ± {}", numbers[0], numbers[1]);
}

/// Stops a run after its first population, as Ctrl-C between populations
/// does (the observers before it have been told the population).
struct StopAfterFirst;

impl mrbp::sampler::Observer for StopAfterFirst {
    fn populated(
        &mut self,
        done: usize,
        _write: &dyn Fn(&std::path::Path) -> mrbp::error::Result<()>,
    ) -> mrbp::error::Result<()> {
        match done {
            1 => Err(mrbp::error::Error::Interrupted("stopped after population 1".into())),
            _ => Ok(()),
        }
    }
}

/// A run stopped after its first population and given that population
/// back goes on to the run never stopped, bit for bit (a population is a
/// function of the target, reference, settings and its index alone); the
/// checkpoint file is refused for a run of another seed or reference.
#[test]
fn an_smc_run_stopped_after_a_population_goes_on_to_the_same_run() {
    struct Saved(Vec<smc::Population>, Option<smc::checkpoint::Key>);
    impl smc::SmcObserver for Saved {
        fn populated(
            &mut self,
            key: &smc::checkpoint::Key,
            done: &[smc::Population],
        ) -> mrbp::error::Result<()> {
            (self.0, self.1) = (done.to_vec(), Some(key.clone()));
            match done.len() {
                1 => Err(mrbp::error::Error::Interrupted("stop".into())),
                _ => Ok(()),
            }
        }
    }
    let (target, reference) = (Banana { c: 0.5 }, reference(4, 0.0, 5.0));
    let settings = SmcSettings { particles: 64, populations: 3, seed: 5, ..SmcSettings::default() };
    let whole = smc::run(&target, &reference, &settings, Vec::new(), &mut (), &|| false).unwrap();
    let mut saved = Saved(Vec::new(), None);
    let stopped = smc::run(&target, &reference, &settings, Vec::new(), &mut saved, &|| false);
    assert!(matches!(stopped, Err(mrbp::error::Error::Interrupted(_))));
    assert_eq!(saved.0.len(), 1);
    // through the file, as a resumed calibration reads it
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(mrbp::sampler::checkpoint::SMC_FILE);
    let key = saved.1.unwrap();
    smc::checkpoint::save(&path, &key, &saved.0).unwrap();
    let back = smc::checkpoint::load(&path, &key).unwrap();
    let resumed = smc::run(&target, &reference, &settings, back, &mut (), &|| false).unwrap();
    assert_eq!(resumed, whole);
    let other_seed =
        smc::checkpoint::Key::of(4, &reference, &SmcSettings { seed: 6, ..settings.clone() });
    assert!(smc::checkpoint::load(&path, &other_seed).is_err());
    let other_start = smc::checkpoint::Key::of(4, &self::reference(4, 0.1, 5.0), &settings);
    let refused = smc::checkpoint::load(&path, &other_start).unwrap_err().to_string();
    assert!(refused.contains("another start or other settings"), "{refused}");
}

/// `--sampler smc` stopped after its first population (the sampler's
/// checkpointer saves the populations beside its own file) and resumed
/// from that folder gives the chains of a calibration never stopped.
#[test]
fn a_calibration_stopped_during_smc_resumes_to_the_same_chains() {
    use mrbp::calibrate::{calibrate, sample, start, CalibrationSettings, SamplerMethod};
    use mrbp::sampler::Checkpointer;
    let (_dir, campaign) = crate::common::virtual_campaign(&crate::common::one_revolution());
    let mut s = CalibrationSettings::default();
    s.sampler.method = SamplerMethod::Smc;
    (s.sampler.walkers, s.sampler.seed, s.sampler.steps) = (64, 3, 20);
    let whole = calibrate(&campaign, &s).unwrap().chains;
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("sampler.checkpoint");
    let mut saver = Checkpointer { path: path.clone(), every: 10, stop: || false };
    let stopped = sample(
        &campaign,
        start(&campaign, &s, &mut |_| {}).unwrap(),
        None,
        &mut [&mut saver, &mut StopAfterFirst],
    );
    assert!(matches!(stopped, Err(mrbp::error::Error::Interrupted(_))));
    assert!(!path.exists(), "stopped before the sampler's first step");
    assert!(mrbp::sampler::checkpoint::smc_beside(&path).exists());
    let resumed =
        sample(&campaign, start(&campaign, &s, &mut |_| {}).unwrap(), Some(&path), &mut [])
            .unwrap()
            .chains;
    assert_eq!(resumed, whole);
}

/// `--loo-refit` samples every held-out posterior afresh, and by the
/// calibration's own sampler: with `--sampler smc`, sequential Monte Carlo
/// from each held-out posterior's Laplace approximation first (its
/// temperature lines printed for every refit). Both samplers reach the
/// same held-out posteriors: each run's share inside its band within 0.05
/// and the median's RMS error within 5 % of the other's (the held-out
/// predictions from 400 draws each: their Monte Carlo error is a few
/// tenths of a per cent of the noise).
#[test]
fn leave_one_out_refits_every_run_by_the_calibration_s_sampler() {
    use crate::common::{arg, ok, said};
    use mrbp::store::parquet::{f64_column, read_parquet, str_column};
    let dir = tempfile::tempdir().unwrap();
    let manifest = crate::common::synth_runs(dir.path(), "1.0", "100,200,400");
    let held_out = |sampler: &str| {
        let out = dir.path().join(sampler);
        let o = ok(&[
            "run",
            arg(&manifest),
            "--out",
            arg(&out),
            "--sampler",
            sampler,
            "--leave-one-out",
            "--loo-refit",
        ]);
        let path = out.join("I1.0A").join("loo.parquet");
        let loo = read_parquet(&path).unwrap();
        let by = str_column(&loo, "held_out_by", &path).unwrap();
        assert_eq!(by, ["sampling"; 3], "{sampler}");
        let rhat = f64_column(&loo, "max_r_hat", &path).unwrap();
        assert!(rhat.iter().all(|r| *r < 1.01), "{sampler}: {rhat:?}");
        (
            said(&o),
            f64_column(&loo, "inside_p95", &path).unwrap(),
            f64_column(&loo, "rmse_q50_pa", &path).unwrap(),
        )
    };
    let (printed, inside_smc, rmse_smc) = held_out("smc");
    assert_eq!(
        printed.matches("every held-out run refitted (--loo-refit)").count(),
        3,
        "{printed}"
    );
    // the calibration's four populations and each refit's four reach β = 1
    assert_eq!(printed.matches(": β = 1.0000").count(), 16, "{printed}");
    let (_, inside, rmse) = held_out("ensemble");
    for k in 0..3 {
        assert!((inside_smc[k] - inside[k]).abs() < 0.05, "{inside_smc:?} {inside:?}");
        assert!((rmse_smc[k] / rmse[k] - 1.0).abs() < 0.05, "{rmse_smc:?} {rmse:?}");
    }
}
