//! The adjusted likelihood (`[likelihood] memory = "adjusted"`): the
//! likelihood evaluated at x* = c + C (x − c) in the sampler's θ
//! coordinates, its curvature at the independent posterior's mode set to
//! H V⁻¹ H, V the covariance of its score given the residuals' memory.

use crate::common::{ok, one_revolution, virtual_campaign, with_smooth_force};
use mrbp::calibrate::{start, CalibrationSettings};
use mrbp::data::Campaign;
use mrbp::model::{Integrator, Params, LANES};
use mrbp::posterior::{run_log_likelihood, LaneParams, Memory, MemoryAdjustment};
use mrbp::sampler::LogDensity;
use mrbp::synth::SynthSettings;

/// One crank revolution per crank speed at 2 kHz, 1 A, with a smooth
/// random force of `smooth_n` (N, 20 ms time scale) the law does not have;
/// the displacement exact where there is none (the smoothed strain's noise
/// is correlated over the smoothing window).
fn campaign(seed: u64, smooth_n: f64) -> (tempfile::TempDir, Campaign) {
    let exact = SynthSettings { seed, ..one_revolution() };
    let noise_displacement_m = if smooth_n == 0.0 { 0.0 } else { exact.noise_displacement_m };
    virtual_campaign(&with_smooth_force(SynthSettings { noise_displacement_m, ..exact }, smooth_n))
}

fn adjusted() -> CalibrationSettings {
    let mut s = CalibrationSettings::default();
    s.likelihood.memory = Memory::Adjusted;
    s
}

/// The adjusted log-density is the prior at θ plus each run's
/// log-likelihood at θ*: the coordinates c + C (x − c) computed here from
/// the stored centre and matrix, the law integrated with their parameters
/// directly.
#[test]
fn the_likelihood_is_evaluated_at_the_moved_parameters() {
    let (_dir, campaign) = campaign(3, 0.0);
    let map = start(&campaign, &CalibrationSettings::default(), &mut |_| {}).unwrap().map;
    let mut settings = adjusted();
    let independent = settings.posterior(&campaign, Integrator::default());
    let centre: Vec<f64> = map.x[..7].iter().map(|v| v + 0.01).collect();
    // a matrix far from the identity, with every entry set
    let matrix: Vec<Vec<f64>> = (0..7)
        .map(|i| {
            (0..7)
                .map(|j| if i == j { 0.4 + 0.05 * i as f64 } else { 0.01 * (i as f64 - j as f64) })
                .collect()
        })
        .collect();
    let adjustment = MemoryAdjustment {
        runs: campaign.runs.iter().map(|r| r.id().to_string()).collect(),
        coordinates: independent.layout.theta_names().to_vec(),
        reference_work_pa: independent.layout.reference_work(),
        centre: centre.clone(),
        matrix: matrix.clone(),
        inflation: vec![1.0; 7],
    };
    settings.likelihood.memory_adjustment = Some(adjustment);
    let post = settings.posterior(&campaign, Integrator::default());
    // a point a little away from the MAP
    let mut x = map.x.clone();
    for (i, v) in x.iter_mut().take(7).enumerate() {
        *v += 0.002 * (i as f64 - 3.0);
    }
    let moved: Vec<f64> = (0..7)
        .map(|i| centre[i] + (0..7).map(|j| matrix[i][j] * (x[j] - centre[j])).sum::<f64>())
        .collect();
    let log_theta = post.layout.log_theta(&moved);
    let params = Params::from_array(std::array::from_fn(|i| log_theta[i].exp()));
    let own: f64 = post
        .runs
        .iter()
        .enumerate()
        .map(|(j, run)| {
            let l = &post.layout;
            let coordinates = std::array::from_fn(|_| l.noise_values(&x, j));
            let terms = std::array::from_fn(|_| l.terms(&x, j));
            run_log_likelihood(
                post.noise.as_ref(),
                &post.integrator,
                run,
                &LaneParams::bodner_partom(&[params; LANES]),
                &coordinates,
                terms,
            )[0]
            .unwrap()
        })
        .sum();
    let want = post.log_prior(&x) + own;
    let got = post.log_density(&x);
    assert!(
        (got - want).abs() < 1e-8 * want.abs(),
        "adjusted log-density {got}, prior plus the runs at θ* {want}"
    );
    // the premise: θ* is not θ, and the likelihood there differs
    assert!((independent.log_density(&x) - got).abs() > 1.0);
}

/// Where the residuals are white (the law and sensor noise, the strain
/// exact) no direction is inflated by more than sampling noise: Sokal's
/// window stops after about 5 lags, whose correlations on 1200–4800 white
/// samples each scatter by 0.015–0.03, so an inflation above 1.3 is ten of
/// their sds (measured: 1.01 at most, six directions at the floor 1). With
/// a smooth 80 N force of 20 ms the law lacks, every direction is
/// inflated (the residuals' memory times are tens of samples; measured
/// 6.4–45), by less than the number of samples, and the "too narrow"
/// warning is not given.
#[test]
fn only_residuals_with_memory_are_adjusted() {
    let (_w, white) = campaign(11, 0.0);
    let s = start(&white, &adjusted(), &mut |_| {}).unwrap();
    let a = s.settings.likelihood.memory_adjustment.clone().expect("measured");
    assert!(
        a.inflation.iter().all(|v| (1.0..1.3).contains(v)),
        "white residuals: inflation {:?}",
        a.inflation
    );
    assert_eq!(a.runs.len(), white.runs.len());

    let (_s, smooth) = campaign(11, 80.0);
    let s = start(&smooth, &adjusted(), &mut |_| {}).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let a = s.settings.likelihood.memory_adjustment.clone().expect("measured");
    let samples: usize = s.posterior.runs.iter().map(|r| r.tau.len()).sum();
    assert!(
        a.inflation[0] > 10.0 && a.inflation.iter().all(|v| (2.0..samples as f64).contains(v)),
        "smooth force: inflation {:?}",
        a.inflation
    );
}

/// What the adjustment is for: the posterior sd of ln θ should be the
/// scatter of the estimate over records of the same stand, with a new path
/// of the smooth force each time. Over 30 such campaigns (the same
/// truth, the force and sensor noise drawn afresh), the sd of the
/// independent posterior's mode (ln θ) against the root mean square of the
/// adjusted posterior's sds (its Laplace approximation at the mode, by
/// Newton's method on the log-density). Measured: adjusted / scatter 1.36
/// (G), 1.10, 0.94, 1.01 (R0, R1, D1), 1.03 (n); the independent
/// posterior's 0.13–0.53. The bounds 0.65–1.6: a scatter from 30
/// replicates has a relative se of 13 %, so 0.65 is 2.7 se below a ratio
/// of 1. m1 and m2 are not held to it: on one revolution their estimates
/// are heavy-tailed in ln θ (a few replicates far out set the scatter;
/// adjusted / scatter 0.54 and 0.74, independent 0.10 and 0.25).
#[test]
#[ignore = "slow tier: a replicate study of the adjusted likelihood"]
fn the_adjusted_sds_are_the_scatter_of_the_estimate() {
    use mrbp::posterior::{laplace, map, Posterior};
    use mrbp::sampler::Elliptical;
    use rand_distr::{Distribution, StandardNormal};
    // the sd of each ln θ under a Gaussian approximation, from its draws
    let sds = |e: &Elliptical, p: &Posterior, seed: u64| -> Vec<f64> {
        let mut rng = mrbp::rng::stream(seed, &[9]);
        let draws: Vec<Vec<f64>> = (0..4000)
            .map(|_| {
                let z: Vec<f64> = (0..e.dim()).map(|_| StandardNormal.sample(&mut rng)).collect();
                p.layout.log_theta(&e.point(&z, 1.0))
            })
            .collect();
        (0..7).map(|i| sd(&draws.iter().map(|d| d[i]).collect::<Vec<f64>>())).collect()
    };
    let (mut centres, mut adjusted_sds, mut independent_sds) = (Vec::new(), Vec::new(), Vec::new());
    for seed in 101..=130u64 {
        let (_d, c) = campaign(seed, 80.0);
        let s = start(&c, &adjusted(), &mut |_| {}).unwrap();
        let a = s.settings.likelihood.memory_adjustment.clone().expect("measured");
        centres.push(s.posterior.layout.log_theta(&a.centre));
        adjusted_sds.push(sds(&laplace::at_mode(&s.posterior, &s.map), &s.posterior, seed));
        let independent = CalibrationSettings::default().posterior(&c, s.posterior.integrator);
        let at = map::refine(&independent, &s.map.x[..independent.layout.fitted.len()]).unwrap();
        independent_sds.push(sds(&laplace::at_mode(&independent, &at), &independent, seed));
    }
    let rms = |v: &[Vec<f64>], i: usize| {
        (v.iter().map(|s| s[i] * s[i]).sum::<f64>() / v.len() as f64).sqrt()
    };
    for (i, name) in ["G", "R0", "R1", "D1", "m1", "m2", "n"].iter().enumerate() {
        let scatter = sd(&centres.iter().map(|c| c[i]).collect::<Vec<f64>>());
        let (adjusted, independent) =
            (rms(&adjusted_sds, i) / scatter, rms(&independent_sds, i) / scatter);
        // the premise: independent noise is too sure of every parameter
        assert!(independent < 0.6, "{name}: independent sd / scatter {independent:.2}");
        if !["m1", "m2"].contains(name) {
            assert!(
                (0.65..1.6).contains(&adjusted),
                "{name}: adjusted sd / scatter {adjusted:.2} (independent {independent:.2})"
            );
        }
    }
}

/// The sample sd.
fn sd(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() as f64 - 1.0)).sqrt()
}

/// A stored adjustment that does not fit is refused with a message that
/// names it: a matrix of another size than its centre, an inflation below
/// 1, or a centre of another size than the model's parameter set.
#[test]
fn a_malformed_adjustment_is_refused() {
    let names: Vec<String> =
        ["ln G", "a", "b", "c", "d", "e", "f"].iter().map(|s| s.to_string()).collect();
    let good = MemoryAdjustment {
        runs: vec!["a".into()],
        coordinates: names,
        reference_work_pa: Some(1e6),
        centre: vec![0.0; 7],
        matrix: vec![vec![0.0; 7]; 7],
        inflation: vec![1.0; 7],
    };
    let with = |a: MemoryAdjustment| {
        let mut s = adjusted();
        s.likelihood.memory_adjustment = Some(a);
        s.check()
    };
    assert!(with(good.clone()).is_ok());
    let cases = [
        MemoryAdjustment { matrix: vec![vec![0.0; 6]; 7], ..good.clone() },
        MemoryAdjustment { inflation: vec![0.5; 7], ..good.clone() },
        MemoryAdjustment {
            centre: vec![0.0; 3],
            matrix: vec![vec![0.0; 3]; 3],
            coordinates: good.coordinates[..3].to_vec(),
            ..good.clone()
        },
        MemoryAdjustment { centre: vec![f64::NAN; 7], ..good.clone() },
        MemoryAdjustment { coordinates: good.coordinates[..6].to_vec(), ..good.clone() },
        MemoryAdjustment { reference_work_pa: Some(-1.0), ..good.clone() },
    ];
    for bad in cases {
        let err = with(bad.clone()).expect_err("refused");
        assert!(err.contains("memory_adjustment"), "{err}");
    }
    // an adjustment is only read with memory = "adjusted"
    let mut tempered = CalibrationSettings::default();
    tempered.likelihood.memory = Memory::Tempered;
    tempered.likelihood.memory_adjustment = Some(MemoryAdjustment {
        centre: vec![0.0; 3],
        matrix: vec![vec![0.0; 3]; 3],
        coordinates: good.coordinates[..3].to_vec(),
        ..good
    });
    assert!(tempered.check().is_ok());
}

/// Leave-one-out under the adjusted likelihood predicts each run as a new
/// test: `mrbp run --memory adjusted --leave-one-out` on records with the
/// smooth force, each run's held-out posterior centred on the kept runs'
/// own peak. Measured on seeds 21–26: held out, a run's 95 % predictive
/// band holds 75–99 % of its samples, 87–94 % on average over a
/// campaign's three runs, 2–4 points more than the independent model's
/// held-out bands on the same records (the band is mostly the noise; on
/// one revolution the 20 ms force's misses come in long runs, hence the
/// scatter). Seed 21: 96.2, 98.5, 87.3 % (independent 92.2, 96.2, 87.3).
/// The bounds: every run ≥ 80 %, the average ≥ 88 % and not more than 3
/// points below the independent model's. Held-out posteriors centred on
/// the full calibration's mode (before 2026-11-27) were pushed away by the
/// run left out, its pull amplified by C⁻¹: 35–65 % inside on measured
/// records.
#[test]
#[ignore = "slow tier: leave-one-out with the adjusted likelihood"]
fn held_out_runs_fall_inside_their_bands() {
    use mrbp::store::{f64_column, read_parquet, str_column};
    let (dir, _c) = campaign(21, 80.0);
    let manifest = dir.path().join("campaign.toml");
    let held_out = |memory: &str| {
        let out = tempfile::tempdir().unwrap();
        ok(&[
            "run",
            manifest.to_str().unwrap(),
            "--out",
            out.path().to_str().unwrap(),
            "--memory",
            memory,
            "--leave-one-out",
        ]);
        let path = out.path().join("I1.0A").join("loo.parquet");
        let loo = read_parquet(&path).unwrap();
        let inside = f64_column(&loo, "inside_p95", &path).unwrap();
        let by = str_column(&loo, "held_out_by", &path).unwrap();
        let runs = str_column(&loo, "run", &path).unwrap();
        assert_eq!(inside.len(), 3);
        (runs, inside, by)
    };
    let (runs, inside, by) = held_out("adjusted");
    for ((run, share), by) in runs.iter().zip(&inside).zip(&by) {
        // the full posterior's draws do not weigh an adjusted held-out posterior
        assert_ne!(by, "reweighting", "{run}");
        assert!(
            *share >= 0.80,
            "{run} held out: {:.1} % inside its 95 % band ({by})",
            100.0 * share
        );
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let independent = mean(&held_out("independent").1);
    let adjusted = mean(&inside);
    assert!(
        adjusted >= 0.88 && adjusted >= independent - 0.03,
        "held out: {:.1} % inside on average (independent {:.1} %)",
        100.0 * adjusted,
        100.0 * independent
    );
}

/// `memory = "auto"` (the default) chooses by the MAP residuals: on
/// records with a smooth force the law lacks (lag-1 autocorrelation of the
/// residuals above 0.9) the adjusted likelihood, and beside its intervals
/// those of the same records taken as independent; on records without one
/// (white residuals) the independent likelihood, with no columns beside.
/// The independent intervals beside come from the Laplace approximation at
/// the independent posterior's mode; checked here against an independent
/// computation, the sampled posterior of `--memory independent` on the
/// same records: every law parameter's sd within 25 % of the sampled one
/// (4 000 Laplace draws, ESS ≥ 400 sampled: sd's Monte Carlo error about
/// 4 %; the rest is the posterior's departure from Gaussian), and the
/// adjusted intervals wider than them, by more than 1.2× in at least one
/// parameter (measured: 1.6–4.3×, seed 21).
#[test]
fn auto_memory_adjusts_records_with_memory_and_shows_the_independent_intervals_beside() {
    use mrbp::store::{column_names, f64_column, read_parquet, str_column};
    let (dir, _c) = campaign(21, 80.0);
    let (white_dir, _w) = campaign(21, 0.0);
    let sample = |data: &std::path::Path, extra: &[&str]| {
        let out = tempfile::tempdir().unwrap();
        let manifest = data.join("campaign.toml");
        let mut args = vec!["sample", manifest.to_str().unwrap(), "--out"];
        args.push(out.path().to_str().unwrap());
        args.extend(extra);
        let printed = String::from_utf8_lossy(&ok(&args).stdout).to_string();
        (out, printed)
    };
    let (auto, printed) = sample(dir.path(), &[]);
    let config = std::fs::read_to_string(auto.path().join("config.toml")).unwrap();
    assert!(config.contains("memory = \"adjusted\""), "{config}");
    assert!(printed.contains("memory: the MAP residuals have memory"), "{printed}");
    assert!(printed.contains("these records, if the residuals were independent"), "{printed}");
    assert!(!printed.contains("too narrow by about"), "the warning gives way: {printed}");
    let path = auto.path().join("summary.parquet");
    let df = read_parquet(&path).unwrap();
    let names = str_column(&df, "parameter", &path).unwrap();
    let holds = str_column(&df, "holds_for", &path).unwrap();
    assert!(holds[0].contains("memory allowed for (adjusted likelihood)"), "{}", holds[0]);
    let col = |n: &str| f64_column(&df, n, &path).unwrap();
    let (q05, q95, isd, i05, i95) = (
        col("q05"),
        col("q95"),
        col("independent_sd"),
        col("independent_q05"),
        col("independent_q95"),
    );

    let (plain, printed) = sample(dir.path(), &["--memory", "independent"]);
    assert!(printed.contains("too narrow by about"), "{printed}");
    let path = plain.path().join("summary.parquet");
    let df = read_parquet(&path).unwrap();
    assert!(str_column(&df, "holds_for", &path).unwrap()[0]
        .contains("if their residuals were independent"));
    let sampled_sd = f64_column(&df, "sd", &path).unwrap();
    let mut widest: f64 = 0.0;
    for (i, name) in names.iter().enumerate().take(7) {
        let ratio = isd[i] / sampled_sd[i];
        assert!(
            (0.75..1.25).contains(&ratio),
            "{name}: Laplace sd {} against sampled {}",
            isd[i],
            sampled_sd[i]
        );
        widest = widest.max((q95[i] - q05[i]) / (i95[i] - i05[i]));
    }
    assert!(widest > 1.2, "the adjusted intervals widen by at most {widest:.2}×");

    // white residuals: independent, nothing beside
    let (white, _) = sample(white_dir.path(), &[]);
    let config = std::fs::read_to_string(white.path().join("config.toml")).unwrap();
    assert!(config.contains("memory = \"independent\""), "{config}");
    let path = white.path().join("summary.parquet");
    let df = read_parquet(&path).unwrap();
    assert!(!column_names(&df).iter().any(|c| c.starts_with("independent_")));
    assert_eq!(str_column(&df, "holds_for", &path).unwrap()[0], "these records");
}

/// After sampling under the adjusted likelihood that `memory = "auto"`
/// took, [`mrbp::calibrate::far_from_records`] integrates 200 of the
/// posterior's draws along their own paths: the start's check reaches only
/// as far as the Laplace approximation, and along a parameter the records
/// leave free about the MAP and rule out further on the adjusted posterior
/// can go past that edge (Spencer's spring k0 on the measured 1 A records:
/// 24–36 % of the draws far, docs/real-data.md). On records with memory
/// and a law that fits them no draw is far; with every other draw's yield
/// coordinate ln (R0 + D1) moved by ln 2 (paths about twice the stress
/// off, far by any measure) half are, above the tenth that refuses the
/// adjusted likelihood, and the watch that checks the walkers while the
/// run goes on stops it there; and the start refusing it takes the
/// tempered one and says why, from the first start's search over its
/// starts (searched again, the same bits).
#[test]
fn draws_that_reach_past_the_records_leave_the_adjusted_likelihood() {
    use mrbp::calibrate::edge::EdgeWatch;
    use mrbp::calibrate::{calibrate, far_from_records, start_refusing_adjusted};
    use mrbp::sampler::{Observer, RunState};
    let (_dir, campaign) = campaign(21, 80.0);
    let settings = CalibrationSettings::default();
    let mut made = calibrate(&campaign, &settings).unwrap();
    assert_eq!(made.start.settings.likelihood.memory, Memory::Adjusted);
    assert_eq!(far_from_records(&made), None);

    let names = made.start.posterior.layout.coordinate_names();
    let yield_at = names.iter().position(|n| n.contains("R0")).expect("a yield coordinate");
    let dim = made.chains.dim;
    for (k, x) in made.chains.positions.chunks_mut(dim).enumerate() {
        if k % 2 == 0 {
            x[yield_at] += 2f64.ln();
        }
    }
    let found = far_from_records(&made).expect("half the draws far");
    let far: usize = found.split(' ').next().unwrap().parse().unwrap();
    assert!((80..=120).contains(&far), "{found}");
    // the watch sees the same in the walkers while the run goes on, and
    // stops it
    let mut watch = EdgeWatch::of(&made.start).expect("auto took the adjusted likelihood");
    let s = &made.start.settings.sampler;
    let settings_now = s.sampler(s.walkers, s.seed);
    let state = RunState {
        settings: &settings_now,
        chains: &made.chains,
        step: 10,
        max_steps: 1000,
        min_ess: None,
        accepted: 0,
    };
    assert!(watch.stepped(&state).is_err());
    assert!(watch.found().unwrap().contains("walkers at step 10"), "{:?}", watch.found());

    // the search over the starts is taken from the first start: it would
    // give the same bits again
    let again = mrbp::calibrate::start(&campaign, &settings, &mut |_| {}).unwrap();
    assert_eq!(again.searched.x, made.start.searched.x);
    let start =
        start_refusing_adjusted(&campaign, &settings, &found, &made.start.searched, &mut |_| {})
            .unwrap();
    assert_eq!(start.settings.likelihood.memory, Memory::Tempered);
    let said = start.memory_found.expect("memory found");
    assert!(said.contains("so the tempered likelihood allows for it"), "{said}");
    assert!(said.contains(&format!("(the adjusted likelihood failed here: {found})")), "{said}");
}

/// The adjustment is measured with the integrator the sampling uses. On
/// the measured 0.25 A records the step rule asks for 4 sub-steps where
/// the MAP search used 1, and that moves the independent posterior's mode
/// by more than one of its sds; the adjusted posterior, centred there,
/// would lie C⁻¹ times as far off. The start's centre is that mode as
/// found here afresh (Levenberg-Marquardt, then Newton's method on the
/// independent posterior with the chosen integrator) to 0.15 of its sd
/// (two Newton searches from different points stop anywhere within
/// about 0.1 sd of the mode: their gain tolerance, gᵀΣg < 0.01). The
/// walkers' Laplace approximation, derived from the independent one
/// (2d + 1 log-densities), has the mode Newton's method finds on the
/// adjusted posterior to 0.2 sd (measured: 0.03 sd at most) and each sd
/// within 10 % of Newton's (measured: 0.94–1.01 of it; 0.79–1.00 before
/// the spread along each axis is measured over the bulk): a transform or
/// a sign gone wrong in the derivation moves them by far more.
#[test]
fn the_adjustment_is_measured_with_the_integrator_the_sampling_uses() {
    use mrbp::model::Integrator;
    use mrbp::posterior::{laplace, map};
    let manifest =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/utfsm-mts/campaign.toml");
    let campaign = Campaign::load(&manifest).unwrap().at_current(0.25);
    let s = start(&campaign, &CalibrationSettings::default(), &mut |_| {}).unwrap();
    assert_eq!(s.settings.likelihood.memory, Memory::Adjusted);
    assert_eq!(s.posterior.integrator.substeps, 4, "the rule's choice this test is about");
    let a = s.settings.likelihood.adjustment().expect("measured");
    let plain = s.posterior.without_adjustment();
    let l = &plain.layout;
    let mode_with = |post: &mrbp::posterior::Posterior| {
        let found = map::refine(post, &s.map.x[l.fitted.clone()]).expect("searched");
        laplace::mode(post, &found).expect("Newton's method")
    };
    let fine = mode_with(&plain);
    let sd: Vec<f64> = fine.laplace.covariance().diagonal().iter().map(|v| v.sqrt()).collect();
    let off = |x: &[f64]| -> f64 {
        l.theta.clone().map(|i| (x[i] - fine.x[i]).abs() / sd[i]).fold(0.0, f64::max)
    };
    let centre_off = off(&a.centre);
    assert!(
        centre_off < 0.15,
        "the centre lies {centre_off:.3} sd from the chosen integrator's mode"
    );
    let coarse = mode_with(&plain.with_integrator(Integrator { substeps: 1, ..plain.integrator }));
    let coarse_off = off(&coarse.x);
    println!(
        "centre {centre_off:.3} sd from the mode, the search's integrator's mode {coarse_off:.3}"
    );
    assert!(coarse_off > 0.5, "the search's integrator moves the mode by only {coarse_off:.3} sd");

    let derived = s.laplace.clone().expect("derived");
    let newton = laplace::at_mode(
        &s.posterior,
        &map::refine(&s.posterior, &derived.mean.as_slice()[l.fitted.clone()]).expect("searched"),
    );
    let (dc, nc) = (derived.covariance(), newton.covariance());
    for i in 0..l.dim() {
        let (sd_d, sd_n) = (dc[(i, i)].sqrt(), nc[(i, i)].sqrt());
        let mean_off = (derived.mean[i] - newton.mean[i]).abs() / sd_n;
        println!(
            "{}: mean {mean_off:.3} sd apart, sd ratio {:.3} ({sd_d:.4} {sd_n:.4})",
            l.names[i],
            sd_d / sd_n
        );
        assert!(mean_off < 0.2, "{}: means {mean_off:.3} sd apart", l.names[i]);
        assert!((sd_d / sd_n - 1.0).abs() < 0.1, "{}: sds {sd_d} and {sd_n}", l.names[i]);
    }
}

/// The derived Laplace approximation of the adjusted posterior
/// ([`laplace::adjusted_mode`]) against Newton's method on the adjusted
/// posterior itself, on every measured current and every measured run
/// alone (fifteen posteriors of 8–11 coordinates): the modes within 0.25
/// sd and every sd within 25 % (measured: 0.18 sd and 20 % at worst; two
/// Newton searches from different points stop up to about 0.1 sd apart).
/// What the approximation serves tolerates that: the anchored move keeps
/// only its whitening (the walkers' own variances set the scale), and
/// leave-one-out's importance weights check it by their k̂.
#[test]
#[ignore = "slow tier: fifteen starts on the measured records"]
fn the_derived_laplace_approximation_holds_on_every_measured_posterior() {
    use mrbp::posterior::{laplace, map};
    let manifest =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/utfsm-mts/campaign.toml");
    let all = Campaign::load(&manifest).unwrap();
    let mut cases: Vec<Campaign> = [0.25, 0.5, 1.0].iter().map(|&i| all.at_current(i)).collect();
    for run in &all.runs {
        cases.push(all.filtered(|r| r.id() == run.id()));
    }
    let mut worst = (0.0f64, 0.0f64);
    for campaign in &cases {
        let s = start(campaign, &CalibrationSettings::default(), &mut |_| {}).unwrap();
        let Some(derived) = s.laplace.clone() else {
            assert_ne!(
                s.settings.likelihood.memory,
                Memory::Adjusted,
                "adjusted without a derived approximation"
            );
            continue;
        };
        let l = &s.posterior.layout;
        let newton = laplace::at_mode(
            &s.posterior,
            &map::refine(&s.posterior, &derived.mean.as_slice()[l.fitted.clone()])
                .expect("searched"),
        );
        let (dc, nc) = (derived.covariance(), newton.covariance());
        for i in 0..l.dim() {
            let (sd_d, sd_n) = (dc[(i, i)].sqrt(), nc[(i, i)].sqrt());
            let mean_off = (derived.mean[i] - newton.mean[i]).abs() / sd_n;
            worst = (worst.0.max(mean_off), worst.1.max((sd_d / sd_n - 1.0).abs()));
            println!(
                "{:?} {}: mean {mean_off:.3} sd apart, sd ratio {:.3}",
                campaign.runs.iter().map(|r| r.id()).collect::<Vec<_>>(),
                l.names[i],
                sd_d / sd_n
            );
        }
    }
    println!("worst: means {:.3} sd apart, sds {:.3} off", worst.0, worst.1);
    assert!(worst.0 < 0.25 && worst.1 < 0.25, "{worst:?}");
}
