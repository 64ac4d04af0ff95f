//! Randomised robustness tests, seeded so a failure reproduces:
//!
//! * the integrator over the prior's whole support (θ log-uniform in the
//!   truncation box) along strain histories a stand can make (sums of
//!   sinusoids up to ±30, ramps, steps of a quantised channel, rest), at
//!   sampling rates from 100 Hz to 10 kHz, every scheme: it returns finite
//!   values or an error value, never NaN, never a panic;
//! * the readers of manifests and CSV/Parquet records under random
//!   mutation of valid files (bytes flipped, cut, duplicated; cells
//!   replaced by text, huge and non-finite numbers): `Campaign::load`
//!   returns a campaign or an error, never a panic.
//!
//! The case counts keep each test to seconds in CI; `MRBP_ROBUSTNESS_CASES`
//! raises them for a longer hunt.

use std::f64::consts::PI;

use mrbp::data::Campaign;
use mrbp::model::{Integrator, Params, Scheme, LANES, PHYSICAL_RANGE};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn cases(default: usize) -> usize {
    std::env::var("MRBP_ROBUSTNESS_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn random_params(rng: &mut ChaCha8Rng) -> Params {
    let v: [f64; 7] = std::array::from_fn(|i| {
        let (lo, hi) = PHYSICAL_RANGE[i];
        (lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln())).exp()
    });
    Params::from_array(v)
}

/// A strain history of `n` samples at `rate` Hz.
fn random_history(rng: &mut ChaCha8Rng) -> (Vec<f64>, Vec<f64>) {
    let rate = [100.0, 200.0, 1000.0, 5000.0, 10_000.0][rng.random_range(0..5)];
    let n = rng.random_range(20..600);
    let time: Vec<f64> = (0..n).map(|k| k as f64 / rate).collect();
    let kind = rng.random_range(0..4);
    let amp = 30.0 * rng.random::<f64>();
    let freq = 0.1 + 10.0 * rng.random::<f64>();
    let quantum = if rng.random::<bool>() { 0.03 } else { 0.0 };
    let gamma = time
        .iter()
        .map(|&t| {
            let g = match kind {
                0 => amp * (2.0 * PI * freq * t).sin(),
                1 => {
                    amp * (2.0 * PI * freq * t).sin()
                        + 0.3 * amp * (2.0 * PI * 3.1 * freq * t).cos()
                }
                2 => amp * (t * rate / n as f64),
                _ => 0.0,
            };
            if quantum > 0.0 {
                (g / quantum).round() * quantum
            } else {
                g
            }
        })
        .collect();
    (time, gamma)
}

#[test]
fn the_integrator_returns_numbers_or_errors_over_the_prior_support() {
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    let schemes = [Scheme::Explicit, Scheme::LinearlyImplicit];
    let (mut ok, mut failed) = (0usize, 0usize);
    for case in 0..cases(200) {
        let (time, gamma) = random_history(&mut rng);
        let params: [Params; LANES] = std::array::from_fn(|_| random_params(&mut rng));
        let integ = Integrator {
            scheme: schemes[case % 2],
            substeps: rng.random_range(1..5),
            extrapolate: rng.random::<bool>(),
            ..Integrator::default()
        };
        let initial = if rng.random::<bool>() { 0.0 } else { 1e5 * (rng.random::<f64>() - 0.5) };
        let mut seen_bad = None;
        let outcome = integ.run_lanes(&params, &time, &gamma, initial, |k, s| {
            for lane in 0..LANES {
                if !(s.tau[lane].is_finite() && s.w[lane].is_finite()) && seen_bad.is_none() {
                    seen_bad = Some((k, lane));
                }
            }
        });
        // a lane that reported success must have given finite values all along
        if let Some((k, lane)) = seen_bad {
            assert!(outcome[lane].is_err(), "case {case}: lane {lane} non-finite at sample {k} but reported Ok ({:?}, {integ:?})", params[lane]);
        }
        for r in &outcome {
            if r.is_ok() {
                ok += 1
            } else {
                failed += 1
            }
        }
        // one lane alone agrees with the lane batch (both from rest)
        if initial == 0.0 {
            let single = integ.run(&params[0], &time, &gamma);
            assert_eq!(
                single.is_ok(),
                outcome[0].is_ok(),
                "case {case}: single and lane runs disagree ({:?})",
                params[0]
            );
        }
    }
    assert!(ok > 0 && ok + failed == cases(200) * LANES, "{ok} ok, {failed} errors");
}

/// A valid campaign folder: a manifest and one CSV and one Parquet record.
fn valid_files() -> (String, String, Vec<u8>) {
    let manifest = "name = \"f\"\n[geometry]\narea_m2 = 0.05\ngap_m = 0.001\n\n[[run]]\nid = \"a\"\nfile = \"a.csv\"\ncurrent_a = 1.0\n\n[[run]]\nid = \"b\"\nfile = \"b.parquet\"\ncurrent_a = 1.0\n".to_string();
    let t: Vec<f64> = (0..60).map(|k| k as f64 * 1e-3).collect();
    let x: Vec<f64> = t.iter().map(|t| 0.005 * (2.0 * PI * 30.0 * t).sin()).collect();
    let f: Vec<f64> = t.iter().map(|t| 900.0 * (2.0 * PI * 30.0 * t).cos()).collect();
    let csv = std::iter::once("time_s,displacement_m,force_n,current_a".to_string())
        .chain((0..60).map(|k| format!("{},{},{},1.0", t[k], x[k], f[k])))
        .collect::<Vec<_>>()
        .join("\n");
    let mut buf = Vec::new();
    {
        use polars::prelude::*;
        let mut df = DataFrame::new_infer_height(vec![
            Column::new("time_s".into(), t),
            Column::new("displacement_m".into(), x),
            Column::new("force_n".into(), f),
        ])
        .unwrap();
        ParquetWriter::new(&mut buf).finish(&mut df).unwrap();
    }
    (manifest, csv, buf)
}

fn mutate(rng: &mut ChaCha8Rng, bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    if b.is_empty() {
        return b;
    }
    match rng.random_range(0..7) {
        0 => {
            let i = rng.random_range(0..b.len());
            b[i] = rng.random();
        }
        1 => b.truncate(rng.random_range(0..b.len())),
        2 => {
            let i = rng.random_range(0..b.len());
            let j = (i + rng.random_range(1..64)).min(b.len());
            let piece = b[i..j].to_vec();
            b.splice(i..i, piece);
        }
        3 => {
            let i = rng.random_range(0..b.len());
            b.remove(i);
        }
        _ => {
            // a text edit where the file is text: a token replaced by a nasty one
            if let Ok(text) = String::from_utf8(b.clone()) {
                let nasty = [
                    "abc", "1e300", "-1e999", "NaN", "inf", "", ",", "\"", "[[run]]", "0", "-0.0",
                    "1e-320", "\n", "ÿ", "current_a = 2.5",
                ];
                let tokens: Vec<&str> = text.split_inclusive([',', '\n', '=']).collect();
                let k = rng.random_range(0..tokens.len());
                let mut out = String::new();
                for (i, t) in tokens.iter().enumerate() {
                    if i == k {
                        out += nasty[rng.random_range(0..nasty.len())];
                        out += &t[t.len() - t.chars().last().map_or(0, |c| c.len_utf8())..];
                    } else {
                        out += t;
                    }
                }
                return out.into_bytes();
            }
            let i = rng.random_range(0..b.len());
            b[i] ^= 0xff;
        }
    }
    b
}

#[test]
fn the_readers_refuse_or_accept_mutated_files_without_panicking() {
    let (manifest, csv, parquet) = valid_files();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("campaign.toml");
    // the unmutated files load
    let write = |m: &[u8], c: &[u8], p: &[u8]| {
        std::fs::write(&path, m).unwrap();
        std::fs::write(dir.path().join("a.csv"), c).unwrap();
        std::fs::write(dir.path().join("b.parquet"), p).unwrap();
    };
    write(manifest.as_bytes(), csv.as_bytes(), &parquet);
    Campaign::load(&path).expect("the valid files load");
    let (mut accepted, mut refused) = (0, 0);
    for case in 0..cases(400) {
        let (mut m, mut c, mut p) =
            (manifest.as_bytes().to_vec(), csv.as_bytes().to_vec(), parquet.clone());
        match case % 3 {
            0 => m = mutate(&mut rng, &m),
            1 => c = mutate(&mut rng, &c),
            _ => p = mutate(&mut rng, &p),
        }
        write(&m, &c, &p);
        let result = std::panic::catch_unwind(|| Campaign::load(&path));
        match result {
            Ok(Ok(campaign)) => {
                accepted += 1;
                // what is accepted is usable: finite, increasing time, within limits
                for run in &campaign.runs {
                    let r = &run.record;
                    assert!(
                        r.time.windows(2).all(|w| w[1] > w[0]),
                        "case {case}: time not increasing"
                    );
                    assert!(
                        r.force.iter().chain(&r.displacement).all(|v| v.is_finite()),
                        "case {case}: non-finite accepted"
                    );
                }
            }
            Ok(Err(e)) => {
                refused += 1;
                assert!(
                    e.exit_code() == 2,
                    "case {case}: a bad file is an input error (exit 2), got {e}"
                );
                assert!(
                    !e.to_string().contains('\n') || e.to_string().lines().count() <= 2,
                    "case {case}: one line: {e}"
                );
            }
            Err(_) => panic!("case {case}: a reader panicked"),
        }
    }
    assert!(accepted > 0 && refused > 0, "{accepted} accepted, {refused} refused");
}
