//! Bayesian calibration end to end on small virtual campaigns with known
//! parameters: recovery, the output tables, and reproducibility.

use crate::common::{arg, mrbp, ok, one_revolution, virtual_campaign};
use mrbp::calibrate::calibrate;
use mrbp::calibrate::CalibrationSettings;
use mrbp::data::Campaign;
use mrbp::model::Params;
use mrbp::store::read_parquet;
use mrbp::synth::{write_campaign, SynthSettings};

/// One crank revolution per crank speed at 2 kHz, 1 A; `displacement_noise`
/// in m.
fn campaign_with(seed: u64, displacement_noise: f64) -> (tempfile::TempDir, Campaign) {
    virtual_campaign(&SynthSettings {
        noise_displacement_m: displacement_noise,
        seed,
        ..one_revolution()
    })
}

fn small_campaign(seed: u64) -> (tempfile::TempDir, Campaign) {
    campaign_with(seed, 2.0e-6)
}

fn quick_settings() -> CalibrationSettings {
    let mut s = CalibrationSettings::default();
    s.sampler.max_steps = 3000;
    s
}

/// The likelihood takes the measured displacement as exact, so the test's
/// records have force noise only: then the model is the one that made the
/// data and the posterior must cover the truth. (With displacement noise the
/// posterior of G is overconfident: see docs/calibration.md.)
#[test]
fn posterior_recovers_known_parameters() {
    let (_dir, campaign) = campaign_with(7, 0.0);
    let cal = calibrate(&campaign, &quick_settings()).unwrap();
    let truth = Params::reference_1a().to_array();
    for (i, name) in ["G", "R0", "R1", "D1", "m1", "m2", "n"].iter().enumerate() {
        let p = &cal.diagnostics.coordinates[i];
        let z = (p.mean - truth[i]).abs() / p.sd;
        // the criterion; a correct posterior exceeds 3.5 sd with
        // probability ~5e-4 per parameter
        assert!(
            z < 3.5,
            "{name}: mean {:.4e} sd {:.3e} truth {:.4e} ({z:.2} sd)",
            p.mean,
            p.sd,
            truth[i]
        );
        assert!(p.r_hat < 1.01, "{name}: R̂ {}", p.r_hat);
    }
}

#[test]
fn same_seed_same_chains_whatever_the_thread_count() {
    let (_dir, campaign) = small_campaign(3);
    let mut s = quick_settings();
    s.sampler.steps = 30;
    s.integrator.substeps = 1;
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| calibrate(&campaign, &s).unwrap().chains)
    };
    assert_eq!(run(1), run(2));
}

/// A start near its Laplace approximation keeps max(32, 3 dim) walkers
/// per ensemble where they were left to the default, and its chains are
/// those of a calibration asked for that many (so the walkers its
/// config.toml records give the same chains again); `walkers` asked by
/// name are kept as they are.
#[test]
fn a_start_near_its_laplace_approximation_keeps_fewer_walkers() {
    let (_dir, campaign) = small_campaign(5);
    let mut s = quick_settings();
    s.sampler.steps = 20;
    s.integrator.substeps = 1;
    let near = calibrate(&campaign, &s).unwrap();
    let dim = near.chains.dim;
    let fewer = (3 * dim).max(32).div_ceil(2) * 2;
    assert!(fewer < (6 * dim).max(64), "dim {dim}");
    assert_eq!(near.chains.walkers, fewer);
    assert_eq!(
        near.calibration.settings.sampler.walkers, fewer,
        "the settings record the walkers kept"
    );
    let mut asked = s.clone();
    asked.sampler.walkers = fewer;
    assert_eq!(calibrate(&campaign, &asked).unwrap().chains, near.chains);
    asked.sampler.walkers = 64;
    assert_eq!(calibrate(&campaign, &asked).unwrap().chains.walkers, 64);
}

#[test]
fn sample_command_writes_the_contract_tables() {
    let (dir, _) = small_campaign(5);
    let out = tempfile::tempdir().unwrap();
    let o = ok(&[
        "sample",
        arg(&dir.path().join("campaign.toml")),
        "--out",
        arg(out.path()),
        "--steps",
        "40",
        "--substeps",
        "1",
        "--walkers",
        "20",
        "--ensembles",
        "2",
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("wall time"), "{stdout}");

    let chains = read_parquet(&out.path().join("chains.parquet")).unwrap();
    let names: Vec<String> = chains.get_column_names().iter().map(|s| s.to_string()).collect();
    let mut expected: Vec<String> =
        ["ensemble", "chain", "draw", "G", "R0", "R1", "D1", "m1", "m2", "n"]
            .map(String::from)
            .to_vec();
    expected
        .extend(["I1.0_100rpm", "I1.0_200rpm", "I1.0_400rpm"].iter().map(|r| format!("sigma_{r}")));
    expected.extend(["log_prob", "accepted"].map(String::from));
    assert_eq!(names, expected);
    assert_eq!(chains.height(), 40 * 41, "2 ensembles × 20 walkers × (40 steps + start)");
    let g = chains.column("G").unwrap().f64().unwrap().clone();
    assert!((0..g.len()).all(|i| g.get(i).is_some_and(|v| v > 1e3)), "G in Pa, not its logarithm");

    let summary = read_parquet(&out.path().join("summary.parquet")).unwrap();
    let names: Vec<String> = summary.get_column_names().iter().map(|s| s.to_string()).collect();
    for c in
        ["parameter", "mean", "sd", "q05", "q50", "q95", "ess_bulk", "ess_tail", "r_hat", "tau_int"]
    {
        assert!(names.contains(&c.to_string()), "summary lacks {c}: {names:?}");
    }
    assert_eq!(summary.height(), 10);
    for f in ["config.toml", "calibration.toml", "identification.parquet"] {
        assert!(out.path().join(f).exists(), "{f}");
    }
    // the written settings read back as settings
    CalibrationSettings::read(&out.path().join("config.toml")).unwrap();
}

#[test]
fn interrupted_sample_resumes_to_the_same_chains() {
    use mrbp::calibrate::{sample, start};
    use mrbp::sampler::Checkpointer;
    let (_dir, campaign) = small_campaign(11);
    let cp = tempfile::tempdir().unwrap();
    let path = cp.path().join("sampler.checkpoint");
    let mut s = quick_settings();
    s.integrator.substeps = 1;
    s.sampler.steps = 60;
    let whole = calibrate(&campaign, &s).unwrap().chains;
    // "killed" after 30 steps: only the checkpoint survives
    let mut first = s.clone();
    first.sampler.steps = 30;
    let mut saver = Checkpointer { path: path.clone(), every: 10, stop: || false };
    sample(&campaign, start(&campaign, &first, &mut |_| {}).unwrap(), None, &mut [&mut saver])
        .unwrap();
    let resumed =
        sample(&campaign, start(&campaign, &s, &mut |_| {}).unwrap(), Some(&path), &mut [])
            .unwrap()
            .chains;
    assert_eq!(resumed, whole);
}

#[test]
fn bad_settings_file_is_a_clear_error() {
    let (dir, _) = small_campaign(5);
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, "[prior.G]\nkind = \"log-normal\"\nmedian = -1.0\nsd_log = 1.0\nlower = 1.0\nupper = 10.0\n").unwrap();
    let o = mrbp(&[
        "sample",
        arg(&dir.path().join("campaign.toml")),
        "--out",
        "/nonexistent/x",
        "--config",
        arg(&cfg),
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.toml") && err.contains("prior of G"), "{err}");
}

/// The default sampler (independence proposals fitted to the complementary
/// half, stopped by the R̂ + ESS rule) and a long run of the former default
/// (differential evolution and snooker, 1500 steps) sample the same B-P
/// posterior: every mean within 5 combined Monte Carlo standard errors, and
/// every sd within 5 of its own standard errors (sd/√(2 ESS) each). A
/// correct pair fails one of the 20 checks with probability ~1e-5.
#[test]
#[ignore = "slow tier: a long differential-evolution run"]
fn default_sampler_agrees_with_a_long_differential_evolution_run() {
    use mrbp::sampler::Move;
    let (_dir, campaign) = small_campaign(17);
    let mut fast = quick_settings();
    fast.integrator.substeps = 2;
    let a = calibrate(&campaign, &fast).unwrap();
    let mut slow = fast.clone();
    slow.sampler.moves = vec![(Move::differential_evolution(), 0.8), (Move::snooker(), 0.2)];
    slow.sampler.walkers = 24;
    slow.sampler.steps = 1500;
    let b = calibrate(&campaign, &slow).unwrap();
    for (i, name) in a.calibration.sample.layout.names.iter().enumerate() {
        let (p, q) = (&a.diagnostics.coordinates[i], &b.diagnostics.coordinates[i]);
        let z_mean = (p.mean - q.mean).abs() / (p.mcse_mean.powi(2) + q.mcse_mean.powi(2)).sqrt();
        let se_sd = (p.sd.powi(2) / (2.0 * p.ess_bulk) + q.sd.powi(2) / (2.0 * q.ess_bulk)).sqrt();
        let z_sd = (p.sd - q.sd).abs() / se_sd;
        assert!(
            z_mean < 5.0 && z_sd < 5.0,
            "{name}: mean {:.5e} vs {:.5e} ({z_mean:.1} MCSE), sd {:.3e} vs {:.3e} ({z_sd:.1} se)",
            p.mean,
            q.mean,
            p.sd,
            q.sd
        );
    }
}

/// The model terms for measured records: records with a known force offset
/// per run and a known gas spring (F += F₀ + k·x, added to the CSV files as
/// a test engineer's load cell and accumulator would) are calibrated with
/// both terms on, and the posterior covers the offsets, the spring and the
/// B-P parameters (3.5 sd: a correct posterior exceeds it with probability
/// ~5e-4 per parameter, ~5e-3 over the eleven checked).
#[test]
fn model_terms_recover_a_known_offset_and_gas_spring() {
    let (dir, _) = campaign_with(11, 0.0);
    let (spring, offsets) = (3000.0, [30.0, -20.0, 10.0]);
    let manifest = std::fs::read_to_string(dir.path().join("campaign.toml")).unwrap();
    let files: Vec<String> = manifest
        .lines()
        .filter_map(|l| l.trim().strip_prefix("file = "))
        .map(|f| f.trim_matches('"').to_string())
        .collect();
    assert_eq!(files.len(), 3);
    for (file, offset) in files.iter().zip(offsets) {
        let path = dir.path().join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines = text.lines();
        let header = lines.next().unwrap().to_string();
        assert!(header.starts_with("time_s,displacement_m,force_n"), "{header}");
        let mut out = header + "\n";
        for line in lines {
            let mut cells: Vec<String> = line.split(',').map(str::to_string).collect();
            let (x, f): (f64, f64) = (cells[1].parse().unwrap(), cells[2].parse().unwrap());
            cells[2] = format!("{}", f + offset + spring * x);
            out += &(cells.join(",") + "\n");
        }
        std::fs::write(&path, out).unwrap();
    }
    let campaign = Campaign::load(&dir.path().join("campaign.toml")).unwrap();
    let mut settings = quick_settings();
    settings.terms.force_offset = true;
    settings.terms.gas_spring = true;
    let cal = calibrate(&campaign, &settings).unwrap();
    let names = &cal.start.posterior.layout.names;
    let mut truth: Vec<(String, f64)> = ["G", "R0", "R1", "D1", "m1", "m2", "n"]
        .iter()
        .map(|n| n.to_string())
        .zip(Params::reference_1a().to_array())
        .collect();
    truth.push(("gas_spring_n_per_m".into(), spring));
    for (run, offset) in campaign.runs.iter().zip(offsets) {
        truth.push((format!("force_offset_n_{}", run.id()), offset));
    }
    for (name, value) in truth {
        let i = names
            .iter()
            .position(|n| *n == name)
            .unwrap_or_else(|| panic!("no {name} in {names:?}"));
        let p = &cal.diagnostics.coordinates[i];
        let z = (p.mean - value).abs() / p.sd;
        assert!(
            z < 3.5,
            "{name}: mean {:.4e} sd {:.3e} truth {value:.4e} ({z:.2} sd)",
            p.mean,
            p.sd
        );
    }
}

/// The MAP search adds the model terms (gas spring, force offsets) to the
/// law's path instead of integrating them: points of one batch that differ
/// only in the terms share one integration. Each point's residuals must
/// keep the bits it has when integrated alone, and the terms must act as
/// the model says: a force offset ±δ on run j moves its residuals by ∓δ/A,
/// so the mean of the two mean squares exceeds the unmoved one by (δ/A)²
/// whatever the residuals' mean (an identity, checked to rounding).
#[test]
fn points_that_differ_only_in_the_terms_share_one_integration_bit_for_bit() {
    use mrbp::model::Integrator;
    use mrbp::posterior::map::{residual_rms, residual_rms_many};
    let (_dir, campaign) = small_campaign(5);
    let mut settings = CalibrationSettings::default();
    settings.terms.force_offset = true;
    settings.terms.gas_spring = true;
    let post = settings.posterior(&campaign, Integrator::default());
    let l = &post.layout;
    let truth = Params::reference_1a().to_array();
    let si: Vec<f64> = (0..l.dim())
        .map(|i| match i {
            _ if l.theta.contains(&i) => truth[i - l.theta.start],
            _ if l.spring.contains(&i) => 2000.0,
            _ if l.offset.contains(&i) => 5.0,
            _ => 1.0e3,
        })
        .collect();
    let x0 = l.from_si(&si);
    let with = |changes: &[(usize, f64)]| {
        let mut x = x0.clone();
        for &(i, d) in changes {
            x[i] += d;
        }
        x
    };
    let (spring, offset1) = (l.spring.start, l.offset.start + 1);
    let delta = 40.0;
    let xs = vec![
        x0.clone(),
        with(&[(spring, 300.0)]),
        with(&[(offset1, delta)]),
        with(&[(offset1, -delta)]),
        with(&[(0, 1e-3)]),
        with(&[(0, 1e-3), (spring, 300.0)]),
        with(&[(spring, -300.0), (offset1, delta)]),
    ];
    let batch = residual_rms_many(&post, &xs);
    for (x, together) in xs.iter().zip(&batch) {
        let alone: Vec<f64> = residual_rms(&post, x).unwrap().iter().map(|r| r.0).collect();
        let together = together.clone().unwrap();
        assert_eq!(
            alone.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            together.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "alone {alone:?}, in the batch {together:?}"
        );
    }
    let ms = |k: usize| batch[k].as_ref().unwrap()[1].powi(2);
    let shift = (delta / post.runs[1].area_m2).powi(2);
    let found = 0.5 * (ms(2) + ms(3)) - ms(0);
    assert!(
        (found - shift).abs() < 1e-9 * ms(0).max(shift),
        "{found:e} against (δ/A)² = {shift:e}"
    );
    // the other runs do not see run 1's offset
    for j in [0, 2] {
        assert_eq!(
            batch[2].as_ref().unwrap()[j].to_bits(),
            batch[0].as_ref().unwrap()[j].to_bits()
        );
    }
}

/// Errors in variables: with 2 µm displacement noise, the exact-input
/// likelihood's 90 % interval of G misses the truth on this realisation
/// (z = +2.10 in the replicate study, docs/calibration.md) and the
/// errors-in-variables one holds it (z = +0.52). The margins to the
/// interval's edge (±1.645 sd) are 0.45 sd and more, against a Monte Carlo error of
/// the 5 % and 95 % quantiles of about 0.05 sd at these ESS (≥ 700): the
/// seeds make the outcome fixed, and a change of the method that moves it
/// by more than the Monte Carlo error shows here.
#[test]
fn errors_in_variables_holds_a_g_the_exact_input_likelihood_misses() {
    let (_dir, campaign) = campaign_with(1027, 2.0e-6);
    let g = Params::reference_1a().g;
    let interval = |eiv: bool| {
        let mut s = CalibrationSettings::default();
        s.sampler.seed = 27;
        s.likelihood.errors_in_variables = eiv;
        let cal = calibrate(&campaign, &s).unwrap();
        let p = cal.diagnostics.coordinates[0].clone();
        (p.q05, p.q95, (p.mean - g) / p.sd)
    };
    let (lo, hi, z) = interval(false);
    assert!(!(lo <= g && g <= hi), "exact input: [{lo:.1}, {hi:.1}] holds G = {g} (z {z:.2})");
    let (lo, hi, z) = interval(true);
    assert!(
        lo <= g && g <= hi,
        "errors in variables: [{lo:.1}, {hi:.1}] misses G = {g} (z {z:.2})"
    );
}

/// A truncated prior narrower than the road from the start: the SBC box
/// (`studies/sbc-prior.toml`, ±2 sd about the 1 A reference) with the
/// discrepancy model, and a truth inside it (one SBC replicate's draw)
/// whose identification lies outside (R1 and m2 1.9× and 5.7× too large).
/// The MAP search must pass outside the box's walls on its way: its optimum
/// must equal the one found with the same log-normal priors truncated only
/// at the physical range (inside the box the two densities are the same,
/// and that optimum is inside the box), to 1 nat and 0.2 Laplace sd in
/// every ln θ. A search that stops at a wall ends about 7 000 nats below.
#[test]
fn map_search_crosses_the_walls_of_a_truncated_prior() {
    use mrbp::calibrate::start;
    use mrbp::noise::NoiseKind;
    use mrbp::posterior::Prior;
    let dir = tempfile::tempdir().unwrap();
    let synth = "name = \"rd1005-3-virtual\"\ncurrents_a = [1.0]\nrpms = [200.0]\ncycles = 1.0\nrate_hz = 1000.0\n\
        noise_force_n = 11.94165727843972\nnoise_displacement_m = 0.000002\nseed = 20261138\n\
        [geometry]\narea_m2 = 0.05\ngap_m = 0.001\n[crank]\nradius_m = 0.00675\nrod_m = 0.15\n[law]\nsaturation_a = 1.0\n\
        [law.at_1a]\nG = 172496.75706683312\nR0 = 102006.3265807785\nR1 = 217448.55301004904\nD1 = 32219.54262014495\n\
        m1 = 0.000004175361632627412\nm2 = 0.00020080274956810803\nn = 1.5308949205631517\n\
        [extra_force]\nsmooth_sd_n = [12.851426152844803]\nsmooth_time_s = [0.03915090130688959]\nkernel = \"matern32\"\nviscous_n_s_per_m = 0.0\n";
    std::fs::write(dir.path().join("synth.toml"), synth).unwrap();
    write_campaign(&SynthSettings::read(&dir.path().join("synth.toml")).unwrap(), dir.path())
        .unwrap();
    let campaign = Campaign::load(&dir.path().join("campaign.toml")).unwrap();
    let mut boxed =
        CalibrationSettings::read(std::path::Path::new("studies/sbc-prior.toml")).unwrap();
    boxed.likelihood.noise = NoiseKind::Discrepancy;
    let mut open = boxed.clone();
    let physical = CalibrationSettings::default().prior;
    for (name, prior) in open.prior.iter_mut() {
        let (lo, hi) = physical[name].bounds();
        if let Prior::LogNormal { lower, upper, .. } = prior {
            (*lower, *upper) = (lo, hi);
        }
    }
    let a = start(&campaign, &boxed, &mut |_| {}).unwrap();
    let b = start(&campaign, &open, &mut |_| {}).unwrap();
    let identification =
        a.identification.as_ref().expect("the B-P law is identified").params.to_array();
    let (_, hi) = boxed.prior["R1"].bounds();
    assert!(
        identification[2] > hi,
        "the premise: the identification's R1 {} is outside the box",
        identification[2]
    );
    assert!(
        (a.map.log_density - b.map.log_density).abs() < 1.0,
        "MAP log-density {} in the box, {} without",
        a.map.log_density,
        b.map.log_density
    );
    let (la, lb) = (a.posterior.layout.log_theta(&a.map.x), b.posterior.layout.log_theta(&b.map.x));
    let sd = b.map.log_theta_sd(&b.posterior.layout);
    for i in 0..7 {
        assert!(
            (la[i] - lb[i]).abs() < 0.2 * sd[i],
            "ln θ[{i}]: {} in the box, {} without (sd {})",
            la[i],
            lb[i],
            sd[i]
        );
    }
}

/// The sampler updates each run's discrepancy parameters on their own from
/// the residuals a full evaluation left behind (its memo): a block's terms
/// must change exactly as the whole log-density does. Checked on two runs
/// with errors in variables (the memo carries the stiffness too) and both
/// model terms, at the MAP and at points with every run's noise moved,
/// against the log-density itself to 1e-9 of its size.
#[test]
fn discrepancy_block_terms_change_as_the_log_density_does() {
    use mrbp::calibrate::start;
    use mrbp::noise::NoiseKind;
    use mrbp::sampler::LogDensity;
    let dir = tempfile::tempdir().unwrap();
    let synth = "name = \"rd1005-3-virtual\"\ncurrents_a = [1.0]\nrpms = [100.0, 200.0]\ncycles = 1.0\nrate_hz = 500.0\n\
        noise_force_n = 12.0\nnoise_displacement_m = 0.000002\nseed = 33\n\
        [geometry]\narea_m2 = 0.05\ngap_m = 0.001\n[crank]\nradius_m = 0.00675\nrod_m = 0.15\n[law]\nsaturation_a = 1.0\n\
        [law.at_1a]\nG = 172496.0\nR0 = 102006.0\nR1 = 217448.0\nD1 = 32219.0\nm1 = 0.000004\nm2 = 0.0002\nn = 1.5\n\
        [extra_force]\nsmooth_sd_n = [30.0]\nsmooth_time_s = [0.02]\nkernel = \"matern32\"\nviscous_n_s_per_m = 0.0\n";
    std::fs::write(dir.path().join("synth.toml"), synth).unwrap();
    write_campaign(&SynthSettings::read(&dir.path().join("synth.toml")).unwrap(), dir.path())
        .unwrap();
    let campaign = Campaign::load(&dir.path().join("campaign.toml")).unwrap();
    let mut s = CalibrationSettings::default();
    s.likelihood.noise = NoiseKind::Discrepancy;
    s.terms.force_offset = true;
    s.terms.gas_spring = true;
    let a = start(&campaign, &s, &mut |_| {}).unwrap();
    // a force of the model's own kind is the discrepancy's, not the law's:
    // the law's path at the MAP misses the records about as the law fitted
    // alone does (the confounding check's ratio stays below 2)
    let alone = a
        .law_alone_rms
        .clone()
        .expect("the law alone is fitted for a noise model with a force of its own");
    let at = mrbp::posterior::map::residual_rms(&a.posterior, &a.map.x).unwrap();
    let runs: Vec<(&str, usize)> =
        a.posterior.runs.iter().zip(&at).map(|(r, (_, n))| (r.id.as_str(), *n)).collect();
    let rms: Vec<f64> = at.iter().map(|(rms, _)| *rms).collect();
    assert_eq!(
        mrbp::calibrate::confounding_warning(&runs, &rms, &alone),
        None,
        "{rms:?} against {alone:?}"
    );
    let post = &a.posterior;
    let (d, blocks) = (post.dim(), post.blocks());
    // the walkers are sized for what the ensemble moves explore: θ and the
    // terms (the coordinates not named for a run's noise), 6 each and at
    // least 64 — not every coordinate (6 × 16 = 96)
    let explored = post
        .layout
        .names
        .iter()
        .filter(|n| !n.starts_with("sigma_") && !n.starts_with("discrepancy_"))
        .count();
    assert_eq!((explored, d), (10, 16));
    assert_eq!(a.settings.sampler.walkers, (6 * explored).max(64));
    assert_eq!(blocks.len(), 2, "one block per run");
    assert_eq!(blocks[0].len(), 3, "sigma, discrepancy_sd, discrepancy_time");
    // eight points: the MAP with its noise moved by different amounts
    let points: Vec<f64> = (0..8)
        .flat_map(|p| {
            let mut x = a.map.x.clone();
            for i in post.layout.noise.clone() {
                x[i] += 0.05 * (p as f64 - 3.5) * if i % 2 == 0 { 1.0 } else { -0.7 };
            }
            x
        })
        .collect();
    let mut lp = vec![0.0; 8];
    let mut memos = vec![Vec::new(); 8];
    post.log_density_batch_memo(&points, &mut lp, &mut memos);
    for (p, x) in points.chunks(d).enumerate() {
        assert!(
            (lp[p] - post.log_density(x)).abs() < 1e-9 * lp[p].abs(),
            "memo evaluation {} vs {}",
            lp[p],
            post.log_density(x)
        );
    }
    let views: Vec<&[f64]> = memos.iter().map(|m| m.as_slice()).collect();
    for (b, block) in blocks.iter().enumerate() {
        // the memo's own terms are the block's at the point
        let mut at = vec![0.0; 8];
        post.block_log_density_batch(b, &points, &views, &mut at);
        for p in 0..8 {
            assert!(
                (at[p] - memos[p][b]).abs() < 1e-9 * at[p].abs(),
                "block {b}: {} vs memo {}",
                at[p],
                memos[p][b]
            );
        }
        let mut moved = points.clone();
        for (p, x) in moved.chunks_mut(d).enumerate() {
            for (k, &i) in block.iter().enumerate() {
                x[i] += 0.1 + 0.03 * (p + k) as f64;
            }
        }
        let mut new = vec![0.0; 8];
        post.block_log_density_batch(b, &moved, &views, &mut new);
        for p in 0..8 {
            let full = post.log_density(&moved[p * d..(p + 1) * d]) - lp[p];
            assert!(full.abs() > 1e-3, "the move changes the density");
            assert!(
                (new[p] - at[p] - full).abs() < 1e-9 * lp[p].abs(),
                "block {b}, point {p}: {} vs {}",
                new[p] - at[p],
                full
            );
        }
    }
}

/// The start of the measured 1 A records' calibration (the B-P law,
/// defaults) and its posterior with independent residuals and the linearly
/// implicit scheme at 4 sub-steps: smooth on any record, where the
/// explicit scheme's step cuts make a likelihood rugged on the scale of a
/// fit's last steps (two searches from different points stop up to half a
/// nat apart).
fn measured_1a_searched() -> (mrbp::calibrate::start::Start, mrbp::posterior::Posterior) {
    use mrbp::model::{Integrator, Scheme};
    let campaign = Campaign::load(std::path::Path::new("data/utfsm-mts/campaign.toml"))
        .unwrap()
        .at_current(1.0);
    let s = mrbp::calibrate::start::start(&campaign, &CalibrationSettings::default(), &mut |_| {})
        .unwrap();
    let smooth =
        Integrator { scheme: Scheme::LinearlyImplicit, substeps: 4, ..s.posterior.integrator };
    let post = s.posterior.without_adjustment().with_integrator(smooth);
    (s, post)
}

/// The MAP search's starts are screened with a budget of evaluations
/// (`map::best_map`), and the best one goes on from where its budget
/// stopped it. With a budget of one (n + 1) evaluations a fit, which stops
/// a start 10 Laplace sd off in every coordinate far short of its optimum
/// (measured 1 A records, the B-P law: without the second stage it ends
/// about 100 nats below, checked by removing it), the search must reach the optimum the
/// unbudgeted search finds from the same start, to within 0.1 nat, on
/// [`measured_1a_searched`]'s smooth posterior.
#[test]
fn a_screened_map_search_finishes_its_best_start() {
    use mrbp::posterior::map;
    let (s, post) = measured_1a_searched();
    let post = &post;
    let (at, sd) = (&s.searched.x, s.searched.sd());
    let from: Vec<f64> = (0..post.layout.fitted.len()).map(|i| at[i] + 10.0 * sd[i]).collect();
    let full = map::refine(post, &from).unwrap();
    let screened = map::best_map_within(post, &[from], 1).unwrap();
    println!("screened {} against {}", screened.log_density, full.log_density);
    assert!(
        (screened.log_density - full.log_density).abs() < 0.1,
        "screened {} against {}",
        screened.log_density,
        full.log_density
    );
}

/// The prior medians' start (`map::best_map_or`'s fallback) is searched
/// where the law's own starts give nothing that converged, and only there:
/// from two starts that converge, the result is `best_map`'s from those
/// two, bit for bit (with the fallback searched too it differs); a later
/// tier of starts is searched only where no earlier one converged (a
/// converging first tier gives `best_map`'s from it alone, a failing one
/// the second tier's);
/// from two starts whose integration fails (ln of the first θ coordinate
/// 60 above the MAP), the fallback's search reaches the MAP that an
/// unbudgeted search from it finds, to within 0.1 nat (the screened
/// search's tolerance above).
#[test]
fn the_prior_medians_are_searched_where_no_start_converges() {
    use mrbp::posterior::map;
    let (s, post) = measured_1a_searched();
    let post = &post;
    let n = post.layout.fitted.len();
    let (at, sd) = (&s.searched.x[..n], s.searched.sd());
    let off = |k: f64| -> Vec<f64> { (0..n).map(|i| at[i] + k * sd[i]).collect() };
    let mut broken = at.to_vec();
    broken[post.layout.theta.start] += 60.0;
    assert!(map::best_map(post, std::slice::from_ref(&broken)).is_none());
    let pair = [off(0.5), off(-3.0)];
    let alone = map::best_map(post, &pair).unwrap();
    let with = map::best_map_or(post, &[pair.to_vec()], &off(6.0)).unwrap();
    assert_eq!(with.log_density.to_bits(), alone.log_density.to_bits());
    let first = map::best_map(post, &[off(-3.0)]).unwrap();
    assert_ne!(first.log_density.to_bits(), alone.log_density.to_bits());
    let tiers = [vec![off(-3.0)], vec![off(0.5)]];
    let tiered = map::best_map_or(post, &tiers, &off(6.0)).unwrap();
    assert_eq!(tiered.log_density.to_bits(), first.log_density.to_bits());
    let tiers = [vec![broken.clone(), broken.clone()], pair.to_vec()];
    let tiered = map::best_map_or(post, &tiers, &off(6.0)).unwrap();
    assert_eq!(tiered.log_density.to_bits(), alone.log_density.to_bits());
    // searched, the fallback would have changed the result
    let all = map::best_map(post, &[off(0.5), off(-3.0), off(6.0)]).unwrap();
    assert_ne!(all.log_density.to_bits(), alone.log_density.to_bits());
    let fallback = off(4.0);
    let full = map::refine(post, &fallback).unwrap();
    let rescued = map::best_map_or(post, &[vec![broken.clone(), broken]], &fallback).unwrap();
    assert!(
        (rescued.log_density - full.log_density).abs() < 0.1,
        "rescued {} against {}",
        rescued.log_density,
        full.log_density
    );
}
