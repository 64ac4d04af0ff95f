//! The bundled measured records (data/utfsm-mts: a real MR damper on an MTS
//! machine, not made by our model): the identification gives a usable start
//! at every current, and a short calibration with the model terms ends in a
//! report that says where the B-P law misses the damper.

use std::path::PathBuf;

use crate::common::ok;

use mrbp::data::Campaign;
use mrbp::identify::{identify_campaign, IdentifySettings};
use mrbp::model::PHYSICAL_RANGE;
use mrbp::sampler::quantile;
use mrbp::store::{f64_column, read_parquet, str_column};

fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/utfsm-mts/campaign.toml")
}

/// Every current gives a combined estimate inside the physical range whose
/// Euler solution follows every record: RMS below 30 % of the record's
/// stress level (99th percentile of |τ|). The measured damper's level is
/// 8–32 kPa and the law's misfit after calibration 7–13 % of it; the
/// identification reaches 11–24 %, a start from which the MAP converges. An
/// identification that misplaces the plateau (as R0 from a yield point that
/// steady cycles do not have did: 13.7 kPa, ≈ 45 % at 1 A) fails it.
#[test]
fn identification_gives_a_usable_start_at_every_current() {
    let campaign = Campaign::load(&manifest()).unwrap();
    let results = identify_campaign(&campaign, &IdentifySettings::default());
    assert_eq!(results.len(), 3);
    for res in &results {
        for (v, (lo, hi)) in res.params.to_array().iter().zip(PHYSICAL_RANGE) {
            assert!(v.is_finite() && *v >= lo && *v <= hi, "{} A: {:?}", res.current_a, res.params);
        }
        let runs: Vec<_> =
            campaign.runs.iter().filter(|r| r.spec.current_a == res.current_a).collect();
        assert_eq!(runs.len(), res.euler_rms.len());
        for (run, rms) in runs.iter().zip(&res.euler_rms) {
            let level =
                quantile(&run.shear.tau.iter().map(|t| t.abs()).collect::<Vec<f64>>(), 0.99);
            assert!(
                *rms < 0.3 * level,
                "{}: Euler RMS {rms:.0} Pa against a level of {level:.0} Pa",
                run.id()
            );
        }
        for r in &res.runs {
            assert!(r.g.is_finite() && r.g > 0.0, "{}: G {} ({:?})", r.run, r.g, r.warnings);
        }
        // steady cycles only: the expected route is said in one line, not
        // as warnings, and names what it had to choose
        let route =
            res.route.as_deref().unwrap_or_else(|| panic!("{} A: no route line", res.current_a));
        assert!(
            route.contains("no record starts from rest")
                && route.contains("m1 = ")
                && route.contains("m2 = "),
            "{route}"
        );
        assert!(res.warnings.is_empty(), "{} A: {:?}", res.current_a, res.warnings);
    }
    let text = mrbp::report::text::identification(&results);
    let rows: Vec<&str> =
        text.lines().filter(|l| l.starts_with("I0.25_") || l.starts_with("I1.00_")).collect();
    // the id column holds the longest id: every row's G in the same column
    let g_end = |l: &str| {
        let g = l.split_whitespace().nth(1).unwrap();
        l.find(g).unwrap() + g.len()
    };
    assert!(rows.windows(2).all(|w| g_end(w[0]) == g_end(w[1])), "{text}");
}

/// `sample` (until converged, about 20 steps; gas spring and force offsets
/// on) and `report` on the 1 A records. Its posterior is close to the
/// Laplace approximation at the mode (ln p/q over the initial walkers
/// spreads by 0.9 nats; a Hessian rule that put one curvature 11× too low
/// made it 8.8, above the 8 that sends a run on the curved move and on to
/// twice the step at which it first converged: 800 steps, 7 min, for the
/// same posterior, when that rule was 100 τ). The calibration must fit (residual under 15 % of the peak
/// force on every run: measured 7–12 %), and the report must not hide what
/// the law misses: the residuals of these records are correlated in time
/// (lag-1 autocorrelation 0.92–0.99), so the default (`memory = "auto"`)
/// allows for their memory by the adjusted likelihood, says so in
/// calibration.toml, the summary and the report, shows the independent
/// residuals' narrower intervals beside (the adjusted ones measured 3–6×
/// wider), and adequacy.parquet says so per run.
#[test]
#[ignore = "slow tier: a calibration of the measured records"]
fn measured_records_calibrate_and_the_report_says_where_the_law_misses() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("cal");
    let config = out.path().join("terms.toml");
    std::fs::write(&config, "[terms]\nforce_offset = true\ngas_spring = true\n").unwrap();
    let run = |args: &[&str]| String::from_utf8_lossy(&ok(args).stdout).to_string();
    let (m, d, c) =
        (manifest(), dir.to_str().unwrap().to_string(), config.to_str().unwrap().to_string());
    let printed =
        run(&["sample", m.to_str().unwrap(), "--current", "1.0", "--config", &c, "--out", &d]);
    assert!(printed.contains("lag-1 autocorrelation"), "{printed}");
    assert!(!printed.contains("far from its Laplace approximation"), "{printed}");
    assert!(printed.contains("so the adjusted likelihood allows for it"), "{printed}");
    assert!(!printed.contains("too narrow by about"), "{printed}");
    // and the independent intervals beside, once, labelled
    assert_eq!(
        printed.matches("these records, if the residuals were independent").count(),
        1,
        "{printed}"
    );
    run(&["report", &d]);

    let record = std::fs::read_to_string(dir.join("calibration.toml")).unwrap();
    let parsed = record.parse::<toml::Table>().unwrap();
    assert!(parsed["memory_found"].as_str().unwrap().contains("lag-1 autocorrelation"), "{record}");
    let widened: Vec<f64> = parsed["independent"]
        .as_array()
        .unwrap()
        .iter()
        .take(7)
        .map(|r| r["sd"].as_float().unwrap())
        .collect();
    let summary = read_parquet(&dir.join("summary.parquet")).unwrap();
    let sd = f64_column(&summary, "sd", &dir.join("summary.parquet")).unwrap();
    for (i, s) in widened.iter().enumerate() {
        assert!(sd[i] > 1.5 * s, "coordinate {i}: adjusted sd {} against independent {s}", sd[i]);
    }
    let spread = record.parse::<toml::Table>().unwrap()["laplace_spread_nats"].as_float().unwrap();
    assert!(spread < 3.0, "ln p/q spread {spread} over the initial walkers (measured 0.92)");
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    for needle in [
        "Model adequacy",
        "Memory: the residuals are correlated",
        "force–velocity loop",
        "Reversals:",
        "These records, if the residuals were independent",
    ] {
        assert!(html.contains(needle), "report lacks '{needle}'");
    }
    let path = dir.join("adequacy.parquet");
    let df = read_parquet(&path).unwrap();
    let runs = str_column(&df, "run", &path).unwrap();
    assert_eq!(runs.len(), 4);
    let col = |n: &str| f64_column(&df, n, &path).unwrap();
    let (rms, peak, rho) =
        (col("residual_rms_n"), col("peak_force_n"), col("lag1_autocorrelation"));
    for i in 0..runs.len() {
        assert!(rms[i] < 0.15 * peak[i], "{}: residual {} N, peak {} N", runs[i], rms[i], peak[i]);
        assert!(rho[i] > 0.5, "{}: lag-1 {}", runs[i], rho[i]);
    }
    // the excitations the file names are the stand's: 25 mm at 0.25 Hz …
    let (amp, freq) = (col("amplitude_m"), col("frequency_hz"));
    let i = runs.iter().position(|r| r == "I1.00_25mm_0.25Hz").unwrap();
    assert!(
        (amp[i] - 0.025).abs() < 0.002 && (freq[i] - 0.25).abs() < 0.01,
        "{} m, {} Hz",
        amp[i],
        freq[i]
    );
}

/// The force channel of the measured records is quantised: 2.942 N steps
/// (58.84 Pa over the 0.05 m² area, read off the CSVs' distinct values by
/// hand). Every run's resolution is found, the floor of the discrepancy
/// model's scales.
#[test]
fn the_force_quantum_of_every_measured_run_is_found() {
    let campaign = Campaign::load(&manifest()).unwrap();
    for run in &campaign.runs {
        let data = mrbp::data::RunData::from_run(run, mrbp::data::RecordPart::WholeRecord, 2.0);
        assert!(
            (data.stress_step_pa - 58.84).abs() < 0.01,
            "{}: {}",
            run.id(),
            data.stress_step_pa
        );
    }
}

/// The measured 1 A 25 mm / 0.25 Hz record alone: the MAP search from the
/// identification ends on a local optimum (log-density −36 553.3) whose
/// walkers climb more than 100 nats within a few steps; the start searches
/// again from the highest walker and starts about a mode at −36 414.0 (the
/// highest log-density any of our long runs of this posterior visited:
/// −36 414.0, a 10 000-step run from the old start). The posterior there
/// is a long curved ridge, far from its Laplace approximation (ln p/q over
/// the initial walkers spreads by 28–30 nats; the other eleven records
/// 0.2–3.6): the run says so and walks with the curved move. Ten fixed
/// steps: this checks the start, not the posterior.
#[test]
fn a_local_map_is_left_for_higher_ground_and_a_ridge_is_named() {
    let out = tempfile::tempdir().unwrap();
    let data = manifest().parent().unwrap().to_path_buf();
    std::fs::copy(data.join("I1.00_25mm_0.25Hz.csv"), out.path().join("I1.00_25mm_0.25Hz.csv"))
        .unwrap();
    let one = out.path().join("campaign.toml");
    std::fs::write(
        &one,
        "name = \"one\"\n[geometry]\narea_m2 = 0.05\ngap_m = 0.001\n[[run]]\nid = \"I1.00_25mm_0.25Hz\"\nfile = \"I1.00_25mm_0.25Hz.csv\"\ncurrent_a = 1.0\n",
    )
    .unwrap();
    let dir = out.path().join("cal");
    let config = data.join("mrbp.toml");
    ok(&[
        "sample",
        one.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "--steps",
        "10",
        // the ridge is the independent likelihood's (the adjusted one,
        // which the default chooses on these records, is close to its
        // Laplace approximation: ln p/q spread 0.56 nats)
        "--memory",
        "independent",
    ]);
    let record: toml::Table =
        std::fs::read_to_string(dir.join("calibration.toml")).unwrap().parse().unwrap();
    let map = record["map_log_density"].as_float().unwrap();
    let spread = record["laplace_spread_nats"].as_float().unwrap();
    assert!(spread > 8.0, "ln p/q spread {spread} over the initial walkers (measured 30)");
    assert!(map > -36_416.0, "MAP log-density {map}: still the local optimum (−36 553)");
    let warnings: Vec<&str> =
        record["warnings"].as_array().unwrap().iter().filter_map(|w| w.as_str()).collect();
    assert!(
        warnings.iter().any(|w| w.contains("climbed") && w.contains("-36553.3")),
        "{warnings:?}"
    );
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("far from its Laplace approximation") && w.contains("curved move")),
        "{warnings:?}"
    );
}

/// The tempered likelihood on the 1 A records (`--memory tempered`): each
/// run's memory time is measured at the MAP (10.9–61 samples on these
/// records) and kept in config.toml, the "too narrow by about" warning gives way to
/// a line that says what was done, the report's adequacy section says the
/// intervals allow for the memory, and G's interval widens: its sd 3.5 %
/// of its value, against 0.8 % with independent residuals (above 2 %
/// asserted).
#[test]
#[ignore = "slow tier: two calibrations of the measured records"]
fn the_tempered_likelihood_widens_the_measured_intervals() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("cal");
    let d = dir.to_str().unwrap().to_string();
    let run = |args: &[&str]| String::from_utf8_lossy(&ok(args).stdout).to_string();
    let printed = run(&[
        "sample",
        manifest().to_str().unwrap(),
        "--current",
        "1.0",
        "--memory",
        "tempered",
        "--out",
        &d,
    ]);
    assert!(printed.contains("likelihood tempered by the residuals' memory"), "{printed}");
    assert!(!printed.contains("too narrow by about"), "{printed}");
    let config: toml::Table =
        std::fs::read_to_string(dir.join("config.toml")).unwrap().parse().unwrap();
    let likelihood = config["likelihood"].as_table().unwrap();
    assert_eq!(likelihood["memory"].as_str(), Some("tempered"));
    let times = likelihood["memory_times"].as_table().unwrap();
    assert_eq!(times.len(), 4, "{times:?}");
    for (id, k) in times {
        let k = k.as_float().unwrap();
        assert!((5.0..100.0).contains(&k), "{id}: memory time {k}");
    }
    run(&["report", &d]);
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(
        html.contains("the likelihood was tempered for it"),
        "report lacks the tempered memory finding"
    );
    let path = dir.join("summary.parquet");
    let df = read_parquet(&path).unwrap();
    let names = str_column(&df, "parameter", &path).unwrap();
    let g = names.iter().position(|n| n == "G").unwrap();
    let (mean, sd) =
        (f64_column(&df, "mean", &path).unwrap()[g], f64_column(&df, "sd", &path).unwrap()[g]);
    assert!(sd > 0.02 * mean, "G {mean} ± {sd}: not widened");
}

/// Where the adjusted likelihood would spread draws whose own paths miss
/// the records, `memory = "auto"` takes the tempered one and says why. The
/// B-P law with a parallel dashpot on the 0.25 A records with their model
/// terms (`mrbp.toml`): the start's check finds 33 of 64 draws of the
/// adjusted Laplace approximation far (2026-12-02). The case this test
/// first held, the B-P element in Spencer's frame at 1 A without the
/// terms (17 of 64 far, 2026-11-29, its spring k0 barely fixed), no longer
/// meets it since that law walks its B-P element in the B-P law's
/// coordinates, whose Laplace approximation lies closer to the posterior.
/// B-P on the 1 A records stays adjusted
/// ([`measured_records_calibrate_and_the_report_says_where_the_law_misses`]:
/// none far). Ten steps: the choice is the start's.
#[test]
#[ignore = "slow tier: a calibration of the measured records (about 40 s)"]
fn auto_leaves_the_adjusted_likelihood_where_its_draws_miss_the_records() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("cal");
    let d = dir.to_str().unwrap().to_string();
    let o = ok(&[
        "sample",
        manifest().to_str().unwrap(),
        "--config",
        manifest().with_file_name("mrbp.toml").to_str().unwrap(),
        "--current",
        "0.25",
        "--law",
        "bp-viscous",
        "--steps",
        "10",
        "--out",
        &d,
    ]);
    let printed = String::from_utf8_lossy(&o.stdout);
    assert!(
        printed.contains(
            "so the tempered likelihood allows for it (the adjusted likelihood failed here: "
        ),
        "{printed}"
    );
    assert!(printed.contains("draws of its Laplace approximation have paths that miss a record"));
    let config: toml::Table =
        std::fs::read_to_string(dir.join("config.toml")).unwrap().parse().unwrap();
    assert_eq!(config["likelihood"]["memory"].as_str(), Some("tempered"), "{config:?}");
    let record: toml::Table =
        std::fs::read_to_string(dir.join("calibration.toml")).unwrap().parse().unwrap();
    assert!(record["memory_found"].as_str().unwrap().contains("miss a record"), "{record:?}");
}

/// Leave-one-out under `memory = "auto"` holds out every run: where the
/// adjusted likelihood's held-out posterior reaches past the records kept,
/// it takes the tempered likelihood, as the start would for a calibration
/// of those runs alone. Bouc-Wen on the 0.5 A records with their terms:
/// without the 25 mm / 0.25 Hz test, 18 of 64 draws of the adjusted
/// held-out posterior's Laplace approximation miss a record kept
/// (2026-12-02), and the run was marked `failed`; now it is held out under
/// the tempered likelihood, no draw far (a posterior past the records
/// would have them far by construction), its band holding 88.8 % of the
/// record (the other three runs, adjusted as before, 82.6–95.7 %). With
/// the twenty steps here the held-out posteriors are searched from other
/// draws, and the one that falls back is the 10 mm / 2 Hz test's (14 of
/// 64 far; the slow test's passes, 87.1 % inside): which run's adjusted
/// posterior is judged past the records depends on where its mode search
/// starts, so the test asks that some run falls back, every run is held
/// out, and none has far draws.
#[test]
#[ignore = "slow tier: a calibration of the measured records and its leave-one-out (about 60 s)"]
fn leave_one_out_under_auto_takes_the_tempered_likelihood_where_the_adjusted_one_misleads() {
    let out = tempfile::tempdir().unwrap();
    let d = out.path().join("study");
    ok(&[
        "run",
        manifest().to_str().unwrap(),
        "--config",
        manifest().with_file_name("mrbp.toml").to_str().unwrap(),
        "--current",
        "0.5",
        "--law",
        "bouc-wen",
        "--steps",
        "20",
        "--leave-one-out",
        "--no-per-run",
        "--out",
        d.to_str().unwrap(),
    ]);
    let path = d.join("I0.5A/loo.parquet");
    let loo = read_parquet(&path).unwrap();
    let runs = str_column(&loo, "run", &path).unwrap();
    let by = str_column(&loo, "held_out_by", &path).unwrap();
    let tempered = str_column(&loo, "tempered_instead", &path).unwrap();
    let inside = f64_column(&loo, "inside_p95", &path).unwrap();
    let far = f64_column(&loo, "far_draws", &path).unwrap();
    assert_eq!(runs.len(), 4);
    for i in 0..4 {
        assert_ne!(by[i], "failed", "{}", runs[i]);
        assert!(
            inside[i] > 0.5 && far[i] < 0.05,
            "{}: {} inside, {} far",
            runs[i],
            inside[i],
            far[i]
        );
        assert!(
            tempered[i].is_empty() || tempered[i].contains("reaches past the records kept"),
            "{}: {}",
            runs[i],
            tempered[i]
        );
    }
    assert!(tempered.iter().any(|t| !t.is_empty()), "every held-out posterior adjusted");
}

/// Where the discrepancy model's smooth force takes over force the law
/// alone carries, the calibration says so. At 0.25 A the law fitted alone
/// (independent noise) leaves an RMS of 0.4–0.75 kPa a run; under the
/// discrepancy model its path at the posterior median misses by 3–5 kPa
/// (measured 2026-11-27: 3.7–11× run by run, all runs together about 7×;
/// the check's ratio is 2),
/// and its held-out runs are predicted worse than the independent
/// model's (docs/real-data.md). 20 steps: the law's path has moved from
/// the start long before. On virtual records whose force is of the model's
/// own kind the check stays silent (tests/it/calibration.rs).
#[test]
#[ignore = "slow tier: the discrepancy model on the measured records"]
fn a_discrepancy_that_takes_over_the_laws_force_is_named() {
    use mrbp::calibrate::{calibrate, start, CalibrationSettings};
    use mrbp::noise::NoiseKind;
    let campaign = Campaign::load(&manifest()).unwrap().at_current(0.25);
    let mut s = CalibrationSettings::default();
    s.likelihood.noise = NoiseKind::Discrepancy;
    s.sampler.steps = 20;
    let record = calibrate(&campaign, &s).unwrap().calibration.record;
    assert_eq!(record.confounding.len(), 1, "{:?}", record.confounding);
    let w = &record.confounding[0];
    // all runs together, then each run's RMS against the law alone's
    let ratio: f64 = w
        .split(" Pa (")
        .nth(1)
        .and_then(|t| t.split('×').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("{w}"));
    assert!(
        ratio > 3.0,
        "pooled ratio {ratio} (measured with the converged posterior: about 7): {w}"
    );
    assert!(w.contains("I0.25_10mm_2Hz") && w.contains("I0.25_5mm_3Hz"), "{w}");
    // the independent model has no force of its own to compare
    assert!(start(&campaign, &CalibrationSettings::default(), &mut |_| {})
        .unwrap()
        .law_alone_rms
        .is_none());
}

/// A parameter whose posterior presses the end of its range is sampled,
/// not walled in: Bouc-Wen's exponent n on the measured records at
/// 0.25 A. Its range starts at 1, and the records hardly fix it (at 0.5 A
/// the chains' log-density is within 1 nat of its best anywhere over
/// n = 1.05–2, 2026-11-30), so its posterior is about its prior
/// (median 2.05) cut at 1. Walked in ln n, the MAP sat on the wall, the
/// walkers started in a sliver there and stayed: n 1.005 [1.000, 1.021]
/// (90 %), R̂ 1.0098 — a converged-looking wrong answer. Walked in
/// ln(n − 1) (`posterior::Layout::floors`) n is 2.06 [1.11, 4.63]. The
/// bounds below sit far from both: a median above 1.3 and a 95th
/// percentile above 2, where the walled posterior's 95th percentile was
/// 1.021.
#[test]
#[ignore = "slow tier: a calibration of the measured records (about 70 s)"]
fn a_parameter_at_the_end_of_its_range_is_sampled_not_walled_in() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("cal");
    let config = manifest().with_file_name("mrbp.toml");
    ok(&[
        "sample",
        manifest().to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--current",
        "0.25",
        "--law",
        "bouc-wen",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let path = dir.join("summary.parquet");
    let summary = read_parquet(&path).unwrap();
    let names = str_column(&summary, "parameter", &path).unwrap();
    let at = |column: &str| {
        let i = names.iter().position(|n| n == "n").unwrap();
        f64_column(&summary, column, &path).unwrap()[i]
    };
    let r_hat = f64_column(&summary, "r_hat", &path).unwrap();
    assert!(r_hat.iter().all(|r| *r < 1.01), "{r_hat:?}");
    assert!(at("q50") > 1.3 && at("q95") > 2.0, "n: q50 {}, q95 {}", at("q50"), at("q95"));
}
