//! The damper laws end to end: each law's virtual records (`mrbp synth
//! --law`) calibrated with that law (`mrbp sample --law`) cover its truth;
//! a law's calibration predicts, reports and compares like the B-P law's;
//! what a law cannot do is refused clearly.

use std::collections::BTreeMap;

use crate::common::{arg, mrbp, ok, said};
use mrbp::laws::LawKind;
use mrbp::store::{f64_column, read_parquet, str_column};

/// One revolution at 100, 200 and 400 rpm, 2 kHz, 1 A, force noise 15 N
/// and exact displacement: the likelihood takes the smoothed displacement
/// as the truth's, and the dashpots of the Bouc-Wen family read velocity
/// off it (with 2 µm displacement noise Bingham's smoothing velocity v0
/// comes out 4 sd off: errors in variables carry the strain's noise
/// through the law's stiffness, not yet through its velocity).
fn virtual_campaign(dir: &std::path::Path, law: &str) -> std::path::PathBuf {
    synth_at_1a(dir, law, &["--cycles", "1", "--rate", "2000", "--noise-displacement", "0"])
}

/// `mrbp synth --law law --currents 1.0` and `options` into `dir/data`:
/// its manifest.
fn synth_at_1a(dir: &std::path::Path, law: &str, options: &[&str]) -> std::path::PathBuf {
    let data = dir.join("data");
    let mut args = vec!["synth", "--out", arg(&data), "--law", law, "--currents", "1.0"];
    args.extend_from_slice(options);
    ok(&args);
    data.join("campaign.toml")
}

/// The truth of a virtual campaign (its `synth.toml`'s `[damper.at_1a]`).
fn truth(manifest: &std::path::Path) -> BTreeMap<String, f64> {
    let text = std::fs::read_to_string(manifest.with_file_name("synth.toml")).unwrap();
    let table: toml::Table = text.parse().unwrap();
    table["damper"]["at_1a"]
        .as_table()
        .unwrap()
        .iter()
        .map(|(k, v)| (k.clone(), v.as_float().unwrap()))
        .collect()
}

/// Every law other than B-P (whose own test is tests/it/calibration.rs)
/// covers each of its parameters within 3.5 posterior sd: a correct
/// posterior exceeds that with probability ~5e-4 per parameter, ~1e-2 over
/// the 23 checked; and the force laws' bands follow their equations
/// integrated independently ([`band_median_follows`]).
#[test]
fn each_law_recovers_its_own_truth_and_its_band_follows_its_equations() {
    for law in LawKind::ALL.iter().filter(|l| !l.is_bodner_partom()) {
        let name = law.name();
        let dir = tempfile::tempdir().unwrap();
        let manifest = virtual_campaign(dir.path(), &name);
        let out = dir.path().join("cal");
        ok(&["sample", arg(&manifest), "--law", &name, "--out", arg(&out)]);
        let path = out.join("summary.parquet");
        let summary = read_parquet(&path).unwrap();
        let names = str_column(&summary, "parameter", &path).unwrap();
        let mean = f64_column(&summary, "mean", &path).unwrap();
        let sd = f64_column(&summary, "sd", &path).unwrap();
        let r_hat = f64_column(&summary, "r_hat", &path).unwrap();
        let truth = truth(&manifest);
        assert_eq!(truth.len(), law.law().parameters().len(), "{name}");
        // the manifest's header names the law the records were made with
        let header = std::fs::read_to_string(&manifest).unwrap();
        assert!(header.contains(&format!("# Synthetic data: the {name} law + ")), "{header}");
        for (parameter, value) in truth {
            let i = names.iter().position(|n| *n == parameter).unwrap();
            let z = (mean[i] - value) / sd[i];
            assert!(
                z.abs() < 3.5 && r_hat[i] < 1.01,
                "{name} {parameter}: mean {:.5e} sd {:.3e} truth {value:.5e} ({z:.2} sd), R̂ {}",
                mean[i],
                sd[i],
                r_hat[i]
            );
        }
        let config = std::fs::read_to_string(out.join("config.toml")).unwrap();
        assert!(config.contains(&format!("law = \"{name}\"")), "{config}");
        // another current is refused with what this law can do about it
        let input = dir.path().join("at-half.csv");
        let rows: String =
            (0..40).map(|k| format!("{},{},0.5\n", 1e-3 * k as f64, 1e-4 * k as f64)).collect();
        std::fs::write(&input, format!("time_s,displacement_m,current_a\n{rows}")).unwrap();
        let o = mrbp(&["simulate", arg(&out), "--input", arg(&input)]);
        assert_eq!(o.status.code(), Some(2), "{}", said(&o));
        assert!(
            said(&o).contains(&format!("the {name} law is calibrated per current")),
            "{}",
            said(&o)
        );
        if let Some(force) = independent_force(&name) {
            let q50 = f64_column(&summary, "q50", &path).unwrap();
            band_median_follows(&out, &names, &q50, force);
        }
    }
}

/// A force law as the docs write it (docs/calibration.md, "Damper laws"):
/// `(parameters by name, x, ẋ, state) -> (state rate, force)`, state
/// `[w, y, W]` (the hysteretic variable or the B-P element's stress,
/// Spencer's internal displacement, the B-P element's inelastic work).
type Force = fn(&dyn Fn(&str) -> f64, f64, f64, [f64; 3]) -> ([f64; 3], f64);

/// The B-P flow rule (eq. 3) with the hardening of eq. 4 after the
/// inelastic work `w`, with the paper's fixed D0 = 1e4 1/s.
fn bp_flow(p: &dyn Fn(&str) -> f64, tau: f64, w: f64) -> f64 {
    if tau == 0.0 {
        return 0.0;
    }
    let (r, d) = (
        p("R1") + (p("R0") - p("R1")) * (-p("m1") * w).exp(),
        p("D1") * (1.0 - (-p("m2") * w).exp()),
    );
    let n = p("n");
    let q = ((r + d) / (3f64.sqrt() * tau.abs())).powf(2.0 * n);
    2.0e4 * (-0.5 * q * (n + 1.0) / n).exp() * tau.signum()
}

/// Wen's normalised hysteresis driven by the velocity `u`.
fn wen(p: &dyn Fn(&str) -> f64, u: f64, w: f64) -> f64 {
    let (sigma, n) = (p("shape"), p("n"));
    p("rho")
        * (u - sigma * u.abs() * w.abs().powf(n) * w.signum() + (sigma - 1.0) * u * w.abs().powf(n))
}

/// The equations of each force law, written here from the docs and not
/// from `src/laws/` (B-P's own path is checked against its scalar
/// reference in its unit tests).
fn independent_force(law: &str) -> Option<Force> {
    match law {
        "bingham" => Some(|p, _x, v, _s| ([0.0; 3], p("c0") * v + p("fc") * (v / p("v0")).tanh())),
        "bouc-wen" => {
            Some(|p, _x, v, s| ([wen(p, v, s[0]), 0.0, 0.0], p("c0") * v + p("fz") * s[0]))
        }
        "spencer" => Some(|p, x, v, s| {
            let (c0, c1) = (p("c0"), p("c1"));
            let y_dot = (p("fz") * s[0] + c0 * v + p("k0") * (x - s[1])) / (c0 + c1);
            ([wen(p, v - y_dot, s[0]), y_dot, 0.0], c1 * y_dot)
        }),
        // the B-P element's stress τ = s[0] on the virtual campaign's
        // area and gap (0.05 m², 1 mm), its work W = s[2]
        "bp-spencer" => Some(|p, x, v, s| {
            let (c0, c1, area, gap) = (p("c0"), p("c1"), 0.05, 0.001);
            let y_dot = (area * s[0] + c0 * v + p("k0") * (x - s[1])) / (c0 + c1);
            let flow = bp_flow(p, s[0], s[2]);
            ([p("G") * ((v - y_dot) / gap - flow), y_dot, s[0] * flow], c1 * y_dot)
        }),
        _ => None,
    }
}

/// The band's median force (`bands.parquet`'s q50 times the area) of every
/// run of the calibration in `out` against the law integrated
/// independently at the posterior medians (`names`, `q50`): classical
/// Runge-Kutta with 200 steps per sample interval along the strain that
/// drives the model (the displacement linear between samples), the force
/// at each sample at the central-difference velocity. The median of the
/// draws' paths and the path of the medians differ by a share of the
/// posterior's spread in the path (its interquartile width 0.8–2.2 N
/// here, 15 N of noise over 600–2400 samples a run; the more parameters,
/// the larger the share) and the calibration's step (the step rule keeps
/// it below 0.1 posterior sd). Measured: RMS 0.04–0.20 N, largest
/// 0.09–0.68 N over Bouc-Wen's, Spencer's and Bingham's nine runs, at 20
/// steps and at 200. `bp-spencer` (ten law parameters): at 200 steps RMS
/// 0.13–0.46 N with either anchored move; at 20 steps 0.12–0.31 N with the
/// former move and 0.41, 0.95, 1.23 N (largest 1.67 N; interquartile
/// widths 0.83–2.13 N) with the shrunk one — whose ten medians lie within
/// 0.05 posterior sd of its 200-step run's (the former move's within
/// 0.10), and whose band medians agree with the 200-step band's within 0.2
/// N: the path at the medians moves by about a newton for shifts of the
/// medians inside their Monte Carlo error, so its gap from the median
/// path is that noisy. Asserted: RMS within 0.4 N or 0.8 of the run's
/// mean interquartile width, and every sample within 2 N (an eighth of
/// the force noise) of the independent path; a wrong equation misses by
/// tens of newtons.
fn band_median_follows(out: &std::path::Path, names: &[String], q50: &[f64], force: Force) {
    ok(&["predict", arg(out), "--draws", "100"]);
    let value = |name: &str| q50[names.iter().position(|n| n == name).unwrap()];
    let path = out.join("bands.parquet");
    let bands = read_parquet(&path).unwrap();
    let runs = str_column(&bands, "run", &path).unwrap();
    let time = f64_column(&bands, "time_s", &path).unwrap();
    let gamma = f64_column(&bands, "gamma", &path).unwrap();
    let median = f64_column(&bands, "q50", &path).unwrap();
    let (q25, q75) =
        (f64_column(&bands, "q25", &path).unwrap(), f64_column(&bands, "q75", &path).unwrap());
    let (area, gap) = (0.05, 0.001); // the virtual campaign's geometry
    let mut start = 0;
    while start < runs.len() {
        let end = (start..runs.len()).find(|&k| runs[k] != runs[start]).unwrap_or(runs.len());
        let (t, x): (&[f64], Vec<f64>) =
            (&time[start..end], gamma[start..end].iter().map(|g| g * gap).collect());
        let n = t.len();
        let central = |k: usize| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            (x[b] - x[a]) / (t[b] - t[a])
        };
        let mut state = [0.0; 3];
        let mut path = vec![force(&value, x[0], central(0), state).1];
        for k in 0..n - 1 {
            let v = (x[k + 1] - x[k]) / (t[k + 1] - t[k]);
            let h = (t[k + 1] - t[k]) / 200.0;
            for i in 0..200 {
                let xi = x[k] + v * h * i as f64;
                let rate = |dx: f64, s: [f64; 3]| force(&value, xi + dx, v, s).0;
                let at = |s: [f64; 3], r: [f64; 3], c: f64| -> [f64; 3] {
                    std::array::from_fn(|j| s[j] + c * r[j])
                };
                let k1 = rate(0.0, state);
                let k2 = rate(0.5 * h * v, at(state, k1, 0.5 * h));
                let k3 = rate(0.5 * h * v, at(state, k2, 0.5 * h));
                let k4 = rate(h * v, at(state, k3, h));
                for j in 0..3 {
                    state[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
                }
            }
            path.push(force(&value, x[k + 1], central(k + 1), state).1);
        }
        let gaps: Vec<f64> =
            path.iter().zip(&median[start..end]).map(|(f, q)| (q * area - f).abs()).collect();
        let rms = (gaps.iter().map(|g| g * g).sum::<f64>() / n as f64).sqrt();
        let worst = gaps.iter().fold(0.0_f64, |a, b| a.max(*b));
        let iqr = (start..end).map(|k| (q75[k] - q25[k]) * area).sum::<f64>() / n as f64;
        eprintln!(
            "{}: band median − independent path: RMS {rms:.2} N, largest {worst:.2} N (interquartile width {iqr:.2} N)",
            runs[start]
        );
        assert!(
            rms < 0.4f64.max(0.8 * iqr) && worst < 2.0,
            "{}: RMS {rms:.2} N, largest {worst:.2} N, interquartile width {iqr:.2} N",
            runs[start]
        );
        start = end;
    }
}

/// A law's calibration goes through predict and report like the B-P
/// law's, names the law in its report and summary, and a comparison with
/// a calibration of another law sets no parameter of one beside the
/// other's namesake.
#[test]
fn a_laws_calibration_predicts_reports_and_compares() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = virtual_campaign(dir.path(), "spencer");
    let (spencer, bouc_wen) = (dir.path().join("spencer"), dir.path().join("bouc-wen"));
    for (law, out) in [("spencer", &spencer), ("bouc-wen", &bouc_wen)] {
        let o = ok(&["run", arg(&manifest), "--law", law, "--out", arg(out), "--draws", "100"]);
        assert!(said(&o).contains(&format!("the {law} law")), "{}", said(&o));
        let html = std::fs::read_to_string(out.join("I1.0A/report.html")).unwrap();
        assert!(html.contains(&format!("the {law} law")), "the report names the law");
        assert!(out.join("I1.0A/bands.parquet").exists());
        // the paper's identification is the B-P law's: none here
        assert!(!out.join("I1.0A/identification.parquet").exists());
    }
    let cmp = dir.path().join("cmp");
    ok(&["compare", arg(&spencer.join("I1.0A")), arg(&bouc_wen.join("I1.0A")), "--out", arg(&cmp)]);
    let path = cmp.join("differences.parquet");
    let d = read_parquet(&path).unwrap();
    assert_eq!(d.height(), 0, "c0, fz, rho, shape and n of two laws are not one quantity");
}

#[test]
fn what_a_law_cannot_do_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = virtual_campaign(dir.path(), "bingham");
    let out = dir.path().join("out");
    let refused = |args: &[&str], parts: &[&str]| {
        let o = mrbp(args);
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        for p in parts {
            assert!(err.contains(p), "{args:?}: {err}");
        }
        assert!(!out.exists(), "{args:?}: no folder left behind");
    };
    refused(
        &["sample", arg(&manifest), "--law", "hooke", "--out", arg(&out)],
        &["hooke", "bouc-wen"],
    );
    refused(
        &[
            "sample",
            arg(&manifest),
            "--law",
            "bingham",
            "--model",
            "current-law",
            "--out",
            arg(&out),
        ],
        &["current-law", "bingham"],
    );
    let config = dir.path().join("prior.toml");
    std::fs::write(
        &config,
        "law = \"bingham\"\n[prior.G]\nkind = \"log-uniform\"\nlower = 1.0\nupper = 10.0\n",
    )
    .unwrap();
    refused(
        &["sample", arg(&manifest), "--config", arg(&config), "--out", arg(&out)],
        &["prior for unknown parameter 'G'", "c0, fc, v0"],
    );
}

/// `run --law A,B --leave-one-out` on records of Bingham's law: each law's
/// whole job in its own folder, then laws.parquet (every law, record and
/// kind) and a report that ranks the generating law first on the records
/// it did not see, decisively (its held-out nRMSE is the noise's).
#[test]
#[ignore = "slow tier: a validation study of two laws with leave-one-out"]
fn the_validation_study_ranks_the_generating_law_first() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = virtual_campaign(dir.path(), "bingham");
    let out = dir.path().join("out");
    let o = ok(&[
        "run",
        arg(&manifest),
        "--law",
        "bouc-wen,bingham",
        "--leave-one-out",
        "--out",
        arg(&out),
        "--draws",
        "100",
    ]);
    let said = said(&o);
    assert!(said.contains("at 1 A the bingham law predicts the held-out tests best"), "{said}");
    assert!(said.contains("decisive on these tests"), "{said}");
    for law in ["bouc-wen", "bingham"] {
        assert!(out.join(law).join("I1.0A/loo.parquet").exists(), "{law}");
    }
    let path = out.join("laws/laws.parquet");
    let t = read_parquet(&path).unwrap();
    assert_eq!(
        mrbp::store::column_names(&t),
        [
            "law", "current_a", "run", "kind", "samples", "nrmse", "e_t", "e_x", "e_v",
            "inside_p95", "band_width", "lppd", "seconds", "log_evidence", "log_evidence_se",
            "evidence_by", "pseudo_evidence", "held_out_rhat", "held_out_unconverged"
        ]
    );
    // two laws × three records × in sample and held out
    assert_eq!(t.height(), 12);
    let rows = mrbp::store::laws::read(&path).unwrap();
    // the ensemble sampler's calibrations: each law's log evidence by
    // bridge sampling on every one of its rows; the generating law's of
    // the records' own likelihood (its residuals are white), the other's
    // a pseudo-evidence (its misfit has memory: adjusted likelihood), so
    // the verdict declines to rank by them
    for law in [LawKind::Bingham, LawKind::BoucWen] {
        let of: Vec<_> = rows.iter().filter(|r| r.law == law).map(|r| r.evidence).collect();
        let e = of[0].expect("an evidence");
        assert!(of.iter().all(|x| *x == Some(e)), "{law:?}: {of:?}");
        assert!(e.by == mrbp::validate::laws::BRIDGE && e.se < 1.0, "{e:?}");
        assert_eq!(e.pseudo, law == LawKind::BoucWen, "{law:?}: {e:?}");
    }
    assert!(said.contains("The log evidence does not rank these laws"), "{said}");
    let held: Vec<_> = rows
        .iter()
        .filter(|r| r.law == LawKind::Bingham && r.kind == mrbp::validate::laws::Kind::HeldOut)
        .collect();
    assert_eq!(held.len(), 3);
    for r in held {
        // 15 N of noise over a peak force of about 2.7 kN: well under 2 %
        assert!(r.measures.nrmse < 0.02 && r.measures.inside_p95 > 0.85, "{r:?}");
    }
    let html = std::fs::read_to_string(out.join("laws/report.html")).unwrap();
    for id in ["verdict", "standings", "records", "figures", "reproduce"] {
        assert!(html.contains(&format!("id=\"{id}\"")), "{id}");
    }
    // `status` judges the laws folder by the calibrations it names: whole
    // now, stale once a law is calibrated again
    let laws_status = || {
        mrbp::store::status::status(&out)
            .unwrap()
            .into_iter()
            .find(|s| s.kind == mrbp::store::status::Kind::Laws)
            .expect("the laws folder is a results folder")
    };
    let whole = laws_status();
    assert_eq!(whole.dir, out.join("laws"));
    assert!(whole.complete(), "{:?}", whole.problems);
    let again = out.join("bingham/I1.0A");
    ok(&[
        "sample",
        arg(&manifest),
        "--law",
        "bingham",
        "--seed",
        "2",
        "--force",
        "--out",
        arg(&again),
    ]);
    let stale = laws_status();
    assert!(
        stale
            .problems
            .iter()
            .any(|p| p.contains("bingham/I1.0A") && p.contains("calibrated again")),
        "{:?}",
        stale.problems
    );
    // one law is not a comparison: `sample` refuses several
    let o = mrbp(&[
        "sample",
        arg(&manifest),
        "--law",
        "bouc-wen,bingham",
        "--out",
        arg(&dir.path().join("s")),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("run --law"));
}

/// `--per-run` with a law other than B-P: each run calibrated alone, the
/// between-run layer in the law's parameters (between_runs.parquet and
/// consistency.parquet name them), and `simulate --new-test` draws new
/// tests of it. Three runs of one virtual damper agree: each run's median
/// inside the layer's 90 % interval for a new test.
#[test]
fn a_laws_runs_alone_feed_the_between_run_layer() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = virtual_campaign(dir.path(), "bingham");
    let out = dir.path().join("out");
    ok(&["sample", arg(&manifest), "--law", "bingham", "--per-run", "--out", arg(&out)]);
    // one current: the folder is the calibration's
    let folder = out;
    let layer = read_parquet(&folder.join("between_runs.parquet")).unwrap();
    let names = mrbp::store::column_names(&layer);
    for c in ["c0", "fc", "v0", "centre_c0", "centre_fc", "centre_v0"] {
        assert!(names.iter().any(|n| n == c), "{c} in {names:?}");
    }
    assert!(!names.iter().any(|n| n == "G"), "{names:?}");
    let path = folder.join("consistency.parquet");
    let table = read_parquet(&path).unwrap();
    let parameter = str_column(&table, "parameter", &path).unwrap();
    let label = str_column(&table, "label", &path).unwrap();
    let (q05, q50, q95) = (
        f64_column(&table, "q05", &path).unwrap(),
        f64_column(&table, "q50", &path).unwrap(),
        f64_column(&table, "q95", &path).unwrap(),
    );
    for p in ["c0", "fc", "v0"] {
        let rows: Vec<usize> = (0..parameter.len()).filter(|&i| parameter[i] == p).collect();
        let new = rows.iter().find(|&&i| label[i] == "new test").copied().expect(p);
        let runs: Vec<usize> =
            rows.iter().copied().filter(|&i| label[i].starts_with("I1.0_")).collect();
        assert_eq!(runs.len(), 3, "{p}");
        for i in runs {
            assert!(q05[new] <= q50[i] && q50[i] <= q95[new], "{p} {}", label[i]);
        }
    }
    let sim = dir.path().join("sim");
    let input = manifest.with_file_name("I1.0_200rpm.csv");
    ok(&["simulate", arg(&folder), "--input", arg(&input), "--new-test", "--out", arg(&sim)]);
    assert!(sim.join("simulation.parquet").exists());
}

/// `simulate --new-test --current I` between the calibrated currents: a
/// virtual Bingham damper (its forces on the stand's tanh curve in the
/// current) calibrated run by run at 0.5 and 1 A, and three records of the
/// same damper at 0.75 A, which no calibration saw (other noise seeds).
/// The layer, fitted again predicting 0.75 A from its centres' curve,
/// holds at least 90 % of those records' samples in its 95 % band pooled
/// (the bound for a new test; measured 99.95 %, the band 17–20 %
/// of the peak force wide: two currents leave the curve's shape between
/// them open). A current far beyond the calibrated ones is refused, and
/// so is another current from a layer of one current.
#[test]
fn a_new_test_between_the_calibrated_currents_holds_its_records() {
    let dir = tempfile::tempdir().unwrap();
    let synth = |out: &str, currents: &str, seed: &str| {
        ok(&[
            "synth",
            "--out",
            arg(&dir.path().join(out)),
            "--law",
            "bingham",
            "--currents",
            currents,
            "--cycles",
            "1",
            "--rate",
            "2000",
            "--noise-displacement",
            "0",
            "--seed",
            seed,
        ]);
    };
    // each run calibrated alone too: the folder of the layer
    let per_run = |name: &str| {
        let out = dir.path().join(format!("{name}-out"));
        let manifest = dir.path().join(name).join("campaign.toml");
        ok(&["sample", arg(&manifest), "--law", "bingham", "--per-run", "--out", arg(&out)]);
        out
    };
    let new_test = |folder: &std::path::Path, input: &std::path::Path, current: &str, out: &str| {
        let out = dir.path().join(out);
        let args = ["--new-test", "--current", current, "--out", arg(&out)];
        mrbp(&[&["simulate", arg(folder), "--input", arg(input)][..], &args].concat())
    };
    synth("cal", "0.5,1.0", "1");
    synth("check", "0.75", "9");
    let folder = per_run("cal").join("I1.0A");
    let (mut inside, mut samples) = (0usize, 0usize);
    for rpm in [100, 200, 400] {
        let input = dir.path().join(format!("check/I0.8_{rpm}rpm.csv"));
        let o = new_test(&folder, &input, "0.75", &format!("sim{rpm}"));
        assert!(o.status.success(), "{}", said(&o));
        assert!(said(&o).contains("a new test at 0.75 A, between the calibrated currents"));
        let text = std::fs::read_to_string(&input).unwrap();
        let force: Vec<f64> =
            text.lines().skip(1).map(|l| l.split(',').nth(2).unwrap().parse().unwrap()).collect();
        let path = dir.path().join(format!("sim{rpm}/simulation.parquet"));
        let table = read_parquet(&path).unwrap();
        let lo = f64_column(&table, "force_p025_n", &path).unwrap();
        let hi = f64_column(&table, "force_p975_n", &path).unwrap();
        assert_eq!(lo.len(), force.len());
        // the first sample is the fixed initial state
        for k in 1..force.len() {
            samples += 1;
            inside += usize::from(lo[k] <= force[k] && force[k] <= hi[k]);
        }
    }
    let share = inside as f64 / samples as f64;
    assert!(share >= 0.90, "{:.1} % of the 0.75 A records inside", 100.0 * share);
    // an excitation of the user's own: time and displacement only
    let input = dir.path().join("excitation.csv");
    let text = std::fs::read_to_string(dir.path().join("check/I0.8_100rpm.csv")).unwrap();
    let plain: Vec<String> =
        text.lines().map(|l| l.split(',').take(2).collect::<Vec<_>>().join(",")).collect();
    std::fs::write(&input, plain.join("\n") + "\n").unwrap();
    let far = new_test(&folder, &input, "3.0", "far");
    assert_eq!(far.status.code(), Some(2), "{}", said(&far));
    assert!(said(&far).contains("far outside the currents the runs were calibrated at"));
    // a layer of runs at one current has no curve to read another current off
    synth("one", "1.0", "1");
    let o = new_test(&per_run("one"), &input, "0.75", "one-sim");
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    assert!(said(&o).contains("two currents or more"), "{}", said(&o));
}

/// A displacement channel that lags the force channel by 5 ms (each
/// record's displacement column delayed by 10 samples at 2 kHz, written
/// here, not by mrbp): with `displacement_lag_ms = 5` the Bouc-Wen
/// calibration covers its truth within 3.5 sd and the noise σ of the runs
/// at 100 and 200 rpm is the stand's 15 N; without it the misfit the lag
/// leaves more than doubles them. (The last 5 ms of a record
/// have no displacement that late: the shift extrapolates along the last
/// interval, which misses the crank's curvature at 400 rpm, whose σ is
/// left out.)
#[test]
fn a_displacement_lag_is_taken_back() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = virtual_campaign(dir.path(), "bouc-wen");
    let delay = 10;
    for entry in std::fs::read_dir(manifest.parent().unwrap()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "csv") {
            let text = std::fs::read_to_string(&path).unwrap();
            let mut lines: Vec<Vec<String>> =
                text.lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect();
            let x: Vec<String> = lines.iter().map(|l| l[1].clone()).collect();
            for (k, line) in lines.iter_mut().enumerate() {
                line[1] = x[k.saturating_sub(delay)].clone();
            }
            let header = text.lines().next().unwrap();
            let body: Vec<String> = lines.iter().map(|l| l.join(",")).collect();
            std::fs::write(&path, format!("{header}\n{}\n", body.join("\n"))).unwrap();
        }
    }
    // (parameter, mean, sd, median) of a calibration with the lag `lag_ms`
    let calibrate = |lag_ms: f64| -> Vec<(String, f64, f64, f64)> {
        let config = dir.path().join(format!("lag{lag_ms}.toml"));
        std::fs::write(&config, format!("[likelihood]\ndisplacement_lag_ms = {lag_ms}\n")).unwrap();
        let out = dir.path().join(format!("cal{lag_ms}"));
        ok(&[
            "sample",
            arg(&manifest),
            "--law",
            "bouc-wen",
            "--config",
            arg(&config),
            "--out",
            arg(&out),
        ]);
        let path = out.join("summary.parquet");
        let summary = read_parquet(&path).unwrap();
        let names = str_column(&summary, "parameter", &path).unwrap();
        let column = |c: &str| f64_column(&summary, c, &path).unwrap();
        let (mean, sd, q50) = (column("mean"), column("sd"), column("q50"));
        (0..names.len()).map(|i| (names[i].clone(), mean[i], sd[i], q50[i])).collect()
    };
    // σ of a run (Pa) as force over the campaign's 0.05 m² area
    let sigma_n = |rows: &[(String, f64, f64, f64)], run: &str| {
        rows.iter().find(|r| r.0 == format!("sigma_{run}")).unwrap().3 * 0.05
    };
    let lagged = calibrate(5.0);
    for (parameter, value) in truth(&manifest) {
        let (_, mean, sd, _) = lagged.iter().find(|r| r.0 == parameter).unwrap();
        let z = (mean - value) / sd;
        assert!(z.abs() < 3.5, "{parameter}: mean {mean:.5e} sd {sd:.3e} truth {value:.5e}");
    }
    let unlagged = calibrate(0.0);
    for run in ["I1.0_100rpm", "I1.0_200rpm"] {
        // σ's posterior median within 10 % of 15 N (hundreds of samples
        // or more: its sd is under 3 %)
        let (with, without) = (sigma_n(&lagged, run), sigma_n(&unlagged, run));
        assert!((with / 15.0 - 1.0).abs() < 0.1, "{run}: σ {with} N with the lag taken back");
        assert!(without > 2.0 * with, "{run}: σ {without} N against {with} N with the lag");
    }
}

/// Leave-one-out of a law that misses the records, under the adjusted
/// likelihood (asked for by name: `memory = "auto"` now takes the tempered
/// one here, 10 of 64 draws of the adjusted Laplace approximation far from
/// a record, and the adjusted posterior's own draws 3–12 % far by run,
/// measured 2026-11-29): B-P on one revolution of Spencer's model at
/// 100/200/400 rpm. Without the 200 rpm run the adjusted posterior's
/// search started from the weighted draws' mean, where the adjusted
/// likelihood's point x* = c + C (x − c) could not be integrated ("the MAP
/// search failed"); it starts from the centre c now, and every run is held
/// out.
#[test]
#[ignore = "slow tier: a whole job with leave-one-out under the adjusted likelihood (about 35 s)"]
fn adjusted_leave_one_out_of_a_law_that_misses_completes() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = virtual_campaign(dir.path(), "spencer");
    let out = dir.path().join("out");
    let o = ok(&[
        "run",
        arg(&manifest),
        "--law",
        "bodner-partom",
        "--memory",
        "adjusted",
        "--leave-one-out",
        "--draws",
        "100",
        "--out",
        arg(&out),
    ]);
    let said = said(&o);
    assert!(said.contains("likelihood adjusted for the residuals' memory"), "{said}");
    let loo = read_parquet(&out.join("I1.0A/loo.parquet")).unwrap();
    assert_eq!(loo.height(), 3, "every run held out");
}

/// `mrbp synth` of a virtual Spencer damper at 1 A, a crank test at each
/// of `rpms` (5 kHz, two revolutions), the sensor noise from `seed`, into
/// `dir/data`: its manifest.
fn spencer_damper(dir: &std::path::Path, rpms: &str, seed: &str) -> std::path::PathBuf {
    synth_at_1a(dir, "spencer", &["--rpm", rpms, "--seed", seed])
}

/// Where the adjusted likelihood's own mode lies past the records' edge,
/// `memory = "auto"` sees it and takes the tempered likelihood. Bouc-Wen
/// on two crank tests (100 and 200 rpm, 1 A) of a virtual Spencer damper
/// misses the records by 8–40 % of the peak, its residuals' lag-1
/// autocorrelation 0.99; the independent posterior's mode stands on the
/// ends of the shape's and n's ranges, and the adjusted posterior's mode,
/// C⁻¹ times as far from it as the likelihood's unconstrained peak, lies
/// where the paths miss every record. The start's check and the walkers'
/// watch judged draws against that mode's own paths, so they passed them:
/// with `--seed 2` (here) c0's posterior median came out at 9.8e6 N s/m
/// against the independent mode's 1.45e4, with seeds 1 and 3 at 1.6 and
/// 1.95 times it; with seed 7 the watch caught it at step 10 and the
/// calibration started again (2026-12-01). Judged against the best fit,
/// the independent likelihood's MAP, the start's check finds all 64 draws
/// far and takes the tempered likelihood from the start: c0's median
/// within 8 % of the independent mode for seeds 1, 2 and 3 (+7, −8, +8 %;
/// +17 % for seed 7: the tempered posterior moves the shape off its
/// range's end, 250 → 2–3, and c0 with it).
#[test]
fn auto_judges_the_adjusted_draws_against_the_best_fit() {
    let dir = tempfile::tempdir().unwrap();
    let data = spencer_damper(dir.path(), "100,200", "2");
    let out = dir.path().join("cal");
    let o = ok(&["sample", arg(&data), "--law", "bouc-wen", "--steps", "10", "--out", arg(&out)]);
    let printed = said(&o);
    assert!(
        printed.contains(
            "so the tempered likelihood allows for it (the adjusted likelihood failed here: "
        ),
        "{printed}"
    );
    let path = out.join("summary.parquet");
    let summary = read_parquet(&path).unwrap();
    let names = str_column(&summary, "parameter", &path).unwrap();
    let at = names.iter().position(|n| n == "c0").unwrap();
    let q50 = f64_column(&summary, "q50", &path).unwrap()[at];
    let independent = f64_column(&summary, "independent_q50", &path).unwrap()[at];
    assert!((q50 / independent - 1.0).abs() < 0.3, "c0 {q50} against {independent}");
}

/// Leave-one-out judges each held-out posterior under the adjusted
/// likelihood as the start judges the calibration's, against the kept
/// runs' best fit. Bouc-Wen on three crank tests of a virtual Spencer
/// damper (`--seed 7`, 1 A) with `--memory adjusted` asked for by name:
/// the adjustment measured on the three runs carries the posterior of two
/// past their records, and before this check the 200 and 400 rpm tests
/// were "predicted" from it with median paths missing by 8.2 MPa and
/// 146 kPa RMS (the records' peak is 58 kPa; 2026-12-01). Now both are
/// marked not held out, 64 of 64 draws far, with the reason, and the
/// 100 rpm test (no draw far) is held out as before.
#[test]
fn leave_one_out_refuses_a_held_out_posterior_past_the_records() {
    let dir = tempfile::tempdir().unwrap();
    let data = spencer_damper(dir.path(), "100,200,400", "7");
    let out = dir.path().join("study");
    ok(&[
        "run",
        arg(&data),
        "--law",
        "bouc-wen",
        "--memory",
        "adjusted",
        "--leave-one-out",
        "--no-per-run",
        "--out",
        arg(&out),
    ]);
    let path = out.join("I1.0A").join("loo.parquet");
    let loo = read_parquet(&path).unwrap();
    let runs = str_column(&loo, "run", &path).unwrap();
    let by = str_column(&loo, "held_out_by", &path).unwrap();
    let why = str_column(&loo, "failure", &path).unwrap();
    for (run, expected) in [
        ("I1.0_100rpm", "laplace-importance"),
        ("I1.0_200rpm", "failed"),
        ("I1.0_400rpm", "failed"),
    ] {
        let i = runs.iter().position(|r| r == run).unwrap();
        assert_eq!(by[i], expected, "{run}: {}", why[i]);
        if expected == "failed" {
            assert!(
                why[i].contains("held-out posterior reaches past the records kept"),
                "{}",
                why[i]
            );
        }
    }
}
