//! The deterministic identification end to end: recovery on noise-free
//! virtual records with known parameters, and the bundled campaign.

use crate::common::{ok, write_virtual};
use mrbp::data::Campaign;
use mrbp::identify::{identify_campaign, identify_current, IdentifySettings};
use mrbp::model::{Params, PHYSICAL_RANGE};
use mrbp::store::read_parquet;
use mrbp::synth::SynthSettings;

#[test]
fn noise_free_10khz_recovers_g_r0_and_n() {
    let dir = tempfile::tempdir().unwrap();
    let settings = SynthSettings {
        currents_a: vec![1.0],
        rate_hz: 10_000.0,
        noise_force_n: 0.0,
        noise_displacement_m: 0.0,
        ..SynthSettings::default()
    };
    let campaign = Campaign::load(&write_virtual(&settings, dir.path())).unwrap();
    let id = identify_current(&campaign, 1.0, &IdentifySettings::default());
    let truth = Params::reference_1a();
    let rel = |e: f64, t: f64| (e - t).abs() / t;
    assert!(rel(id.raw[0], truth.g) < 0.02, "G {}", id.raw[0]);
    assert!(rel(id.raw[1], truth.r0) < 0.10, "R0 {}", id.raw[1]);
    assert!(rel(id.raw[6], truth.n) < 0.10, "n {}", id.raw[6]);
    // every run reached yield and had a converged eq. 7 fit
    for r in &id.runs {
        assert!(
            r.yield_point.is_some() && r.curve.as_ref().is_some_and(|c| c.converged),
            "{}: {:?}",
            r.run,
            r.warnings
        );
    }
}

#[test]
fn bundled_campaign_identifies_every_current_inside_the_physical_range() {
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let campaign = Campaign::load(&repo.join("data/campaign.toml")).unwrap();
    let results = identify_campaign(&campaign, &IdentifySettings::default());
    assert_eq!(results.len(), 3);
    for res in &results {
        for (v, (lo, hi)) in res.params.to_array().iter().zip(PHYSICAL_RANGE) {
            assert!(*v >= lo && *v <= hi, "{} A: {:?}", res.current_a, res.params);
        }
        assert!(res.euler_rms.iter().all(|r| r.is_finite()));
    }
}

#[test]
fn identify_command_writes_table_and_figures() {
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = tempfile::tempdir().unwrap();
    ok(&[
        "identify",
        repo.join("data/campaign.toml").to_str().unwrap(),
        "--out",
        out.path().to_str().unwrap(),
    ]);
    let df = read_parquet(&out.path().join("identification.parquet")).unwrap();
    let names: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).collect();
    for c in ["run", "parameter", "value"] {
        assert!(names.contains(&c.to_string()), "{names:?}");
    }
    let runs = df.column("run").unwrap().str().unwrap().clone();
    let params = df.column("parameter").unwrap().str().unwrap().clone();
    let combined_g = (0..df.height())
        .filter(|&i| runs.get(i) == Some("all") && params.get(i) == Some("G"))
        .count();
    assert_eq!(combined_g, 3, "one combined G per current");
    for k in 1..=5 {
        let n = std::fs::read_dir(out.path())
            .unwrap()
            .filter(|e| {
                e.as_ref().unwrap().file_name().to_string_lossy().starts_with(&format!("fig{k}_"))
            })
            .count();
        assert_eq!(n, 6, "fig{k}: svg and png for 3 currents");
    }
}
