//! Comparing current levels on virtual campaigns with known parameters:
//! `mrbp compare` over per-current calibrations, and the current law
//! predicting a current it never saw.

use std::path::Path;

use crate::common::{arg, mrbp, ok, one_revolution, said, write_virtual};

use mrbp::store::{column_names, f64_column, read_parquet, str_column};
use mrbp::synth::SynthSettings;

/// One revolution at 2 kHz per run, the bundled noise levels.
fn campaign(dir: &Path, currents: Vec<f64>, rpms: Vec<f64>) -> String {
    let settings = SynthSettings { currents_a: currents, rpms, ..one_revolution() };
    arg(&write_virtual(&settings, dir)).to_string()
}

/// R0, R1 and D1 at 1.0 A are 1/0.60 times those at 0.5 A on the virtual
/// stand (tanh law, I_s = 1 A), far beyond the posterior sd (under 1 %):
/// P(R0 at 1 A > R0 at 0.5 A) must be above 0.99, and the ratio's interval
/// must hold the true ratio tanh(1)/tanh(0.5) = 1.6499 (5 % tolerance: the
/// short chains' intervals are narrow and the displacement noise biases
/// both calibrations alike).
#[test]
fn compare_tells_current_levels_apart() {
    let data = tempfile::tempdir().unwrap();
    let manifest = campaign(data.path(), vec![0.5, 1.0], vec![100.0, 400.0]);
    let out = tempfile::tempdir().unwrap();
    ok(&["sample", &manifest, "--out", arg(out.path()), "--substeps", "2"]);
    let (lo, hi) = (out.path().join("I0.5A"), out.path().join("I1.0A"));
    for d in [&lo, &hi] {
        ok(&["predict", arg(d), "--draws", "100"]);
    }
    let cmp = out.path().join("cmp");
    ok(&["compare", arg(&hi), arg(&lo), "--out", arg(&cmp)]);

    let path = cmp.join("comparison.parquet");
    let t = read_parquet(&path).unwrap();
    assert_eq!(
        column_names(&t),
        ["calibration", "current_a", "parameter", "mean", "sd", "q05", "q50", "q95"]
    );
    // 7 B-P parameters + 2 noise scales per calibration
    assert_eq!(t.height(), 2 * 9);

    let path = cmp.join("differences.parquet");
    let d = read_parquet(&path).unwrap();
    let cols = [
        "calibration_a", "calibration_b", "parameter", "diff_q05", "diff_q50", "diff_q95",
        "ratio_q05", "ratio_q50", "ratio_q95", "p_greater",
    ];
    assert_eq!(column_names(&d), cols);
    let params = str_column(&d, "parameter", &path).unwrap();
    let a = str_column(&d, "calibration_a", &path).unwrap();
    let p = f64_column(&d, "p_greater", &path).unwrap();
    let (r05, r95) =
        (f64_column(&d, "ratio_q05", &path).unwrap(), f64_column(&d, "ratio_q95", &path).unwrap());
    assert_eq!(params.len(), 7, "one pair, the seven B-P parameters");
    let truth = 1.0f64.tanh() / 0.5f64.tanh();
    for name in ["R0", "R1", "D1"] {
        let i = params.iter().position(|x| x == name).unwrap();
        assert_eq!(a[i], "I1.0A");
        assert!(p[i] > 0.99, "{name}: P(1.0 A > 0.5 A) = {}", p[i]);
        assert!(
            r05[i] < truth * 1.05 && r95[i] > truth * 0.95,
            "{name}: ratio [{}, {}] vs {truth}",
            r05[i],
            r95[i]
        );
    }
    let html = std::fs::read_to_string(cmp.join("report.html")).unwrap();
    for id in ["calibrations", "parameters", "differences", "current-law", "figures", "reproduce"] {
        assert!(html.contains(&format!("id=\"{id}\"")), "{id}");
    }
    assert!(html.contains("<b>1.000</b>"), "a certain difference is marked");
    for f in ["forest.png", "against_current.png", "overlay.png"] {
        assert!(cmp.join(f).exists(), "{f}");
    }
}

/// The current law calibrated at 0.5 and 1.5 A predicts the runs at 1.0 A:
/// the bar is 80 % of the held-out observations inside the 95 %
/// predictive band (the virtual stand follows the law's family, so a
/// well-calibrated law should reach about 95 %).
#[test]
fn current_law_predicts_a_held_out_current() {
    let data = tempfile::tempdir().unwrap();
    let manifest = campaign(data.path(), vec![0.5, 1.0, 1.5], vec![200.0]);
    let out = tempfile::tempdir().unwrap();
    let law = out.path().join("law");
    ok(&[
        "sample",
        &manifest,
        "--out",
        arg(&law),
        "--model",
        "current-law",
        "--hold-out-current",
        "1.0",
        "--substeps",
        "2",
    ]);
    ok(&["predict", arg(&law), "--draws", "200"]);
    // the record keeps each run's current: an unseen run's noise is
    // interpolated between the calibrated currents from it
    let record = std::fs::read_to_string(law.join("calibration.toml")).unwrap();
    assert!(record.contains("run_currents = [0.5, 1.5]"), "{record}");
    let path = law.join("coverage.parquet");
    let cov = read_parquet(&path).unwrap();
    let runs = str_column(&cov, "run", &path).unwrap();
    let inside = f64_column(&cov, "inside_p95", &path).unwrap();
    let calibrated = f64_column(&cov, "calibrated", &path).unwrap();
    assert_eq!(runs.len(), 3, "every run of the campaign is predicted");
    let held = runs.iter().position(|r| r == "I1.0_200rpm").unwrap();
    assert_eq!(calibrated[held], 0.0);
    assert!(inside[held] >= 0.80, "held-out 1.0 A run: {:.1} % inside", 100.0 * inside[held]);

    // the law's folder compares with a per-current one, and the report says what was held out
    let per = out.path().join("per");
    ok(&["sample", &manifest, "--out", arg(&per), "--current", "1.0", "--substeps", "2"]);
    ok(&["predict", arg(&per), "--draws", "100"]);
    let cmp = out.path().join("cmp");
    ok(&["compare", arg(&per), arg(&law), "--out", arg(&cmp)]);
    let html = std::fs::read_to_string(cmp.join("report.html")).unwrap();
    assert!(
        html.contains("<b>held out</b>") && html.contains("held_out_law"),
        "held-out rows and figure"
    );

    // the law says how the parameters differ between currents, draw by
    // draw: R0 at 1.5 A over R0 at 0.5 A is tanh(1.5)/tanh(0.5) = 1.959 on
    // the stand (5 % tolerance as in `compare_tells_current_levels_apart`);
    // m1, m2 and n do not follow the current in the law, so their ratio is
    // exactly 1 in every draw and P(a > b) exactly ½ (every pair a tie)
    let path = cmp.join("differences.parquet");
    let d = read_parquet(&path).unwrap();
    let (a, b, params) = (
        str_column(&d, "calibration_a", &path).unwrap(),
        str_column(&d, "calibration_b", &path).unwrap(),
        str_column(&d, "parameter", &path).unwrap(),
    );
    let (p, r05, r50, r95) = (
        f64_column(&d, "p_greater", &path).unwrap(),
        f64_column(&d, "ratio_q05", &path).unwrap(),
        f64_column(&d, "ratio_q50", &path).unwrap(),
        f64_column(&d, "ratio_q95", &path).unwrap(),
    );
    let row = |x: &str, y: &str, name: &str| {
        (0..a.len())
            .find(|&i| a[i] == x && b[i] == y && params[i] == name)
            .unwrap_or_else(|| panic!("{x} − {y} {name} in {a:?}"))
    };
    // the currents of the comparison: the law's two and the per-current one
    assert_eq!(
        a.iter().filter(|x| x.starts_with("law at")).count(),
        3 * 7,
        "three pairs of currents, seven parameters"
    );
    let truth = 1.5f64.tanh() / 0.5f64.tanh();
    for name in ["R0", "R1", "D1"] {
        let i = row("law at 1.5 A", "law at 0.5 A", name);
        assert!(p[i] > 0.99, "{name}: P = {}", p[i]);
        assert!(
            r05[i] < truth * 1.05 && r95[i] > truth * 0.95,
            "{name}: ratio [{}, {}] vs {truth}",
            r05[i],
            r95[i]
        );
    }
    for name in ["m1", "m2", "n"] {
        let i = row("law at 1.0 A", "law at 0.5 A", name);
        assert_eq!((p[i], r50[i]), (0.5, 1.0), "{name} does not follow the current in the law");
    }

    // the law's parameters against the current, in its folder: the
    // off-state has no yield stress in this law (s(0) = 0), the held-out
    // current lies between the calibrated ones, and the band there holds
    // the stand's R0 (5 % tolerance as above)
    let path = law.join("against_current.parquet");
    let t = read_parquet(&path).unwrap();
    assert_eq!(
        column_names(&t),
        ["parameter", "current_a", "kind", "mean", "sd", "q05", "q50", "q95"]
    );
    let (names, kinds) =
        (str_column(&t, "parameter", &path).unwrap(), str_column(&t, "kind", &path).unwrap());
    let (current, q05, q50, q95) = (
        f64_column(&t, "current_a", &path).unwrap(),
        f64_column(&t, "q05", &path).unwrap(),
        f64_column(&t, "q50", &path).unwrap(),
        f64_column(&t, "q95", &path).unwrap(),
    );
    let at = |name: &str, i: f64| {
        (0..names.len())
            .find(|&k| names[k] == name && (current[k] - i).abs() < 1e-9)
            .unwrap_or_else(|| panic!("{name} at {i} A"))
    };
    assert_eq!((kinds[at("R0", 0.0)].as_str(), q50[at("R0", 0.0)]), ("outside", 0.0));
    assert_eq!(kinds[at("R0", 0.5)], "calibrated");
    assert_eq!(kinds[at("R0", 1.0)], "between");
    assert_eq!(kinds[at("R0", 1.8)], "outside", "the grid reaches 1.2× the highest current");
    let stand = mrbp::synth::StandLaw::default().params_at(1.0);
    let k = at("R0", 1.0);
    assert!(
        q05[k] < stand.r0 * 1.05 && q95[k] > stand.r0 * 0.95,
        "R0 at 1.0 A: [{}, {}] vs {}",
        q05[k],
        q95[k],
        stand.r0
    );
    ok(&["report", arg(&law)]);
    let report = std::fs::read_to_string(law.join("report.html")).unwrap();
    assert!(
        report.contains("alt=\"against_current\"") && law.join("against_current.png").exists(),
        "the law's report draws its curves"
    );

    // bad use is a usage error, not a crash
    let o = mrbp(&["sample", &manifest, "--out", arg(&per), "--hold-out-current", "1.0"]);
    assert_eq!(o.status.code(), Some(2));
    let o = mrbp(&[
        "sample",
        &manifest,
        "--out",
        arg(&law),
        "--model",
        "current-law",
        "--hold-out-current",
        "0.7",
    ]);
    assert_eq!(o.status.code(), Some(2));
    let o = mrbp(&["compare", arg(&per)]);
    assert_eq!(o.status.code(), Some(2));
}

/// The current curves recover a law of their own form from a virtual
/// campaign at 0.25, 0.5 and 1.0 A: an off-state, every parameter its own
/// bend, G falling with the current (as on the measured damper), R0
/// saturating early — together with two records whose current is switched
/// while the crank turns (steps through 0.25, 1.0 and 0.5 A every 80 ms;
/// a 50 Hz PWM-like command between 0 and 1 A), through which the coil's
/// lag (12 ms) is recovered too. Every coordinate's posterior mean lies
/// within 3.5 of its posterior sds of the truth (a two-sided normal tail of
/// 5·10⁻⁴ per coordinate: one of the 22 fails by chance with probability
/// about 1 %). Measured: |z| ≤ 1.70 (R0_high); the lag 11.98 ± 0.03 ms.
#[test]
#[ignore = "slow tier: the current curves with a coil lag"]
fn current_curves_and_coil_lag_recover_their_truth() {
    use mrbp::model::{CurrentCurves, Params};
    use mrbp::synth::SwitchedRun;
    let low = Params { g: 2.6e5, r0: 6.0e4, r1: 9.0e4, d1: 1.5e4, m1: 3.0e-6, m2: 4.0e-4, n: 1.1 };
    let high = Params { g: 1.7e5, r0: 1.3e5, r1: 1.6e5, d1: 4.0e4, m1: 4.0e-6, m2: 2.0e-4, n: 1.3 };
    let truth = CurrentCurves {
        low_a: 0.25,
        high_a: 1.0,
        low,
        high,
        bend: [6.0, 0.2, 1.0, 2.0, 1.0, 1.0, 0.5],
    };
    let lag = 0.012;
    let data = tempfile::tempdir().unwrap();
    let mut settings = SynthSettings {
        currents_a: vec![0.25, 0.5, 1.0],
        rpms: vec![100.0, 400.0],
        ..one_revolution()
    };
    settings.law.curves = Some(truth);
    settings.law.coil_lag_s = lag;
    settings.switched = vec![
        SwitchedRun { rpm: 200.0, levels_a: vec![0.25, 1.0, 0.5], holds_s: vec![0.08] },
        SwitchedRun { rpm: 400.0, levels_a: vec![0.0, 1.0], holds_s: vec![0.006, 0.014] },
    ];
    let manifest = write_virtual(&settings, data.path());
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("curves");
    ok(&["sample", arg(&manifest), "--out", arg(&dir), "--model", "current-curves"]);
    let path = dir.join("summary.parquet");
    let t = read_parquet(&path).unwrap();
    let names = str_column(&t, "parameter", &path).unwrap();
    let (mean, sd) = (f64_column(&t, "mean", &path).unwrap(), f64_column(&t, "sd", &path).unwrap());
    let value = |name: &str| -> (f64, f64) {
        let i =
            names.iter().position(|n| n == name).unwrap_or_else(|| panic!("{name} in the summary"));
        (mean[i], sd[i])
    };
    let (lo, hi) = (low.to_array(), high.to_array());
    let mut expected: Vec<(String, f64)> = vec![("coil_lag_s".into(), lag)];
    for (k, p) in mrbp::model::PARAM_NAMES.iter().enumerate() {
        expected.extend([
            (format!("{p}_low"), lo[k]),
            (format!("{p}_high"), hi[k]),
            (format!("{p}_bend"), truth.bend[k]),
        ]);
    }
    let mut largest = (String::new(), 0.0f64);
    for (name, want) in expected {
        let (m, s) = value(&name);
        let z = (m - want) / s;
        assert!(
            z.abs() < 3.5,
            "{name}: {m:.4e} ± {s:.2e} against the truth {want:.4e} (z = {z:.2})"
        );
        if z.abs() > largest.1.abs() {
            largest = (name, z);
        }
    }
    eprintln!("largest |z|: {} ({:.2}); coil lag {:?}", largest.0, largest.1, value("coil_lag_s"));
    // the switched runs are predicted along their current: their 95 %
    // predictive band holds about 95 % of each (at least 90 %: a model
    // that missed the switching would leave whole stretches outside)
    ok(&["predict", arg(&dir), "--draws", "60", "--replicates", "4"]);
    let path = dir.join("coverage.parquet");
    let cov = read_parquet(&path).unwrap();
    let (runs, inside) =
        (str_column(&cov, "run", &path).unwrap(), f64_column(&cov, "inside_p95", &path).unwrap());
    for id in ["S1_200rpm", "S2_400rpm"] {
        let i = runs.iter().position(|r| r == id).unwrap();
        assert!(inside[i] >= 0.9, "{id}: {:.1} % inside", 100.0 * inside[i]);
    }
    // the bands carry a switched run's current (the command's levels, each
    // held in turn), NaN for a run at one current; its figure draws it
    let path = dir.join("bands.parquet");
    let bands = read_parquet(&path).unwrap();
    let (rows, current) = (
        str_column(&bands, "run", &path).unwrap(),
        f64_column(&bands, "coil_current_a", &path).unwrap(),
    );
    let of = |id: &str| -> Vec<f64> {
        rows.iter().zip(&current).filter(|(r, _)| *r == id).map(|(_, c)| *c).collect()
    };
    let s1 = of("S1_200rpm");
    assert!(
        !s1.is_empty() && s1.iter().all(|c| [0.25, 1.0, 0.5].iter().any(|l| (c - l).abs() < 1e-12)),
        "S1's current holds its levels"
    );
    for level in [0.25, 1.0, 0.5] {
        assert!(s1.contains(&level), "S1 holds {level} A at some sample");
    }
    let held = rows.iter().find(|r| !r.starts_with('S')).expect("a run at one current").clone();
    assert!(of(&held).iter().all(|c| c.is_nan()), "{held} has no current history");
    ok(&["report", arg(&dir)]);
    let figure = std::fs::read_to_string(dir.join("bands_S1_200rpm.svg"))
        .expect("the switched run's bands figure");
    assert!(figure.contains("S1_200rpm: coil current"), "the figure has the current's panel");
    // one parameter set per current cannot calibrate a switched run: it is
    // left out, and said so
    let per = out.path().join("per");
    let o =
        mrbp(&["sample", arg(&manifest), "--out", arg(&per), "--current", "1.0", "--steps", "5"]);
    let said = said(&o);
    assert!(
        o.status.success()
            && said.contains("S1_200rpm, S2_400rpm: the current changes within the record"),
        "{said}"
    );
    let config = std::fs::read_to_string(dir.join("config.toml")).unwrap();
    assert!(config.contains("coil_lag = true"), "the lag is written with the settings:\n{config}");
    let config = std::fs::read_to_string(dir.join("config.toml")).unwrap();
    assert!(
        config.contains("anchor_currents_a = [0.25, 1.0]"),
        "the anchors are written with the settings:\n{config}"
    );
}

/// `run --model current-law` asks for the law stage (before, `run` took
/// `--model` as that stage's model only and, without `--current-law`,
/// calibrated each current alone and said nothing): the law calibrated
/// without the middle current beside the per-current folders; a campaign
/// of one current says it has no law to calibrate.
#[test]
fn run_with_the_current_law_as_its_model_calibrates_the_law() {
    let data = tempfile::tempdir().unwrap();
    let manifest = crate::common::synth_small(data.path(), "0.5,1.0,1.5");
    let out = tempfile::tempdir().unwrap();
    let o = ok(&[
        "run",
        arg(&manifest),
        "--out",
        arg(out.path()),
        "--model",
        "current-law",
        "--steps",
        "20",
        "--draws",
        "50",
    ]);
    let law = out.path().join("current-law-without-I1.0A");
    assert!(law.join("calibration.toml").exists(), "{}", said(&o));
    for current in ["I0.5A", "I1.0A", "I1.5A", "comparison"] {
        assert!(out.path().join(current).is_dir(), "{current}");
    }
    let one = tempfile::tempdir().unwrap();
    let manifest = crate::common::synth_small(one.path(), "1.0");
    let out = one.path().join("out");
    let o =
        ok(&["run", arg(&manifest), "--out", arg(&out), "--model", "current-law", "--steps", "20"]);
    assert!(said(&o).contains("this one has runs at one current only"), "{}", said(&o));
    assert!(!out.join("current-law").exists());
}
