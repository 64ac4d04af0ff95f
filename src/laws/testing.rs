//! What every law's tests share: a crank-like run, an independent scalar
//! reference integration, and the conformance harness each law runs.

use super::{DamperLaw, LawValues, LANES};
use crate::data::RunData;
use crate::model::Integrator;

/// A sine stroke of ±10 mm at 2 Hz, `cycles` of it at `rate_hz`, with the
/// bundled campaign's geometry (A = 0.05 m², h = 1 mm) and a force record
/// of ±1 kN (only its scale matters to the laws' starts).
pub fn crank_run(rate_hz: f64, cycles: f64) -> RunData {
    let n = (cycles * rate_hz / 2.0).round() as usize + 1;
    let time: Vec<f64> = (0..n).map(|k| k as f64 / rate_hz).collect();
    let omega = 2.0 * std::f64::consts::PI * 2.0;
    let gamma: Vec<f64> = time.iter().map(|t| 0.010 * (omega * t).sin() / 0.001).collect();
    let tau: Vec<f64> = time.iter().map(|t| 1000.0 * (omega * t).cos() / 0.05).collect();
    RunData::new("crank".into(), time, gamma, tau, 0.0, 1.0, (0.05, 0.001), (0.0, 0.3))
}

/// The force (N) of a law written as `law(x, v, state) -> (state rate,
/// force)` along `run`, by classical Runge-Kutta with 400 steps per sample
/// interval (the displacement linear between samples, its velocity that
/// interval's), the force at each sample at the velocity of central
/// differences: an integration independent of the laws' own.
pub fn reference_path<const N: usize>(
    run: &RunData,
    law: impl Fn(f64, f64, [f64; N]) -> ([f64; N], f64),
) -> Vec<f64> {
    let h = run.gap_m;
    let x: Vec<f64> = run.gamma.iter().map(|g| h * g).collect();
    let t = &run.time;
    let n = t.len();
    let central = |k: usize| {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        (x[b] - x[a]) / (t[b] - t[a])
    };
    let mut state = [0.0; N];
    let mut out = vec![law(x[0], central(0), state).1];
    for k in 0..n - 1 {
        let dt = t[k + 1] - t[k];
        let v = (x[k + 1] - x[k]) / dt;
        let m = 400;
        let s = dt / m as f64;
        for i in 0..m {
            let xi = x[k] + v * s * i as f64;
            let add = |a: [f64; N], b: [f64; N], c: f64| -> [f64; N] {
                std::array::from_fn(|i| a[i] + c * b[i])
            };
            let k1 = law(xi, v, state).0;
            let k2 = law(xi + 0.5 * s * v, v, add(state, k1, 0.5 * s)).0;
            let k3 = law(xi + 0.5 * s * v, v, add(state, k2, 0.5 * s)).0;
            let k4 = law(xi + s * v, v, add(state, k3, s)).0;
            state = std::array::from_fn(|i| {
                state[i] + s / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
        }
        out.push(law(x[k + 1], central(k + 1), state).1);
    }
    out
}

/// The law's force (stress × area) with 128 sub-steps per interval,
/// extrapolated, within `tolerance` of the peak of `reference` at every
/// sample.
pub fn close_to(
    law: &dyn DamperLaw,
    p: &LawValues,
    run: &RunData,
    reference: &[f64],
    tolerance: f64,
) {
    let fine = Integrator {
        substeps: 128,
        extrapolate: true,
        max_substeps: 100_000,
        ..Integrator::default()
    };
    let path = law.path(&fine, p, run).expect("integrates");
    let peak = reference.iter().fold(0.0f64, |m, f| m.max(f.abs()));
    for (k, (tau, f)) in path.iter().zip(reference).enumerate() {
        let force = tau * run.area_m2;
        assert!(
            (force - f).abs() <= tolerance * peak,
            "{:?} at sample {k}: {force} N against the reference's {f} N (peak {peak})",
            law.kind()
        );
    }
}

/// Every law's conformance, at the parameter set `p` (inside the range):
///
/// * lanes: eight different parameter sets integrated together give, lane
///   by lane, the bits of each integrated alone, whatever lane it is in;
/// * a parameter set outside the range fails in its lane only;
/// * order: the error against a fine-step integration (512 sub-steps,
///   extrapolated) halves, within [1.6, 2.5], as the sub-steps double
///   from 16 to 32 to 64 (first order; a second-order law: falls more
///   than 3.2×), and falls more than 1.25 × 2^order per doubling with
///   Richardson extrapolation, unless it is already at the rounding of the
///   force (1e-10 of its peak: a law without a state);
/// * the starts read off a run lie inside the physical range and integrate.
pub fn conformance(law: &dyn DamperLaw, p: &LawValues) {
    conformance_from(law, p, 16)
}

/// [`conformance`] with the order's ladder from `first` sub-steps (`first`,
/// 2×, 4×; the reference at 32× extrapolated): a law stiff at 16 sub-steps
/// (the B-P flow rule's knee at yield) reaches its asymptotic order only
/// at finer steps than a smooth one.
pub fn conformance_from(law: &dyn DamperLaw, p: &LawValues, first: u32) {
    law.validate(p).expect("the test's parameters are inside the range");
    let run = crank_run(1000.0, 1.0);
    let count = law.parameters().len();
    // eight sets: p with one parameter moved by 1–8 % in turn
    let sets: [LawValues; LANES] = std::array::from_fn(|lane| {
        let mut q = *p;
        q[lane % count] *= 1.0 + 0.01 * (lane + 1) as f64;
        q
    });
    let integrator = Integrator::default();
    let mut together = vec![[0.0; LANES]; run.time.len()];
    let outcome = law.run_lanes(&integrator, &sets, &run, &mut |k, s| together[k] = *s);
    assert!(outcome.iter().all(|o| o.is_ok()), "{:?}: {outcome:?}", law.kind());
    for lane in 0..LANES {
        let alone = law.path(&integrator, &sets[lane], &run).unwrap();
        let other_lane: Vec<f64> = {
            let mut shifted = [sets[(lane + 3) % LANES]; LANES];
            shifted[(lane + 5) % LANES] = sets[lane];
            let mut out = vec![0.0; run.time.len()];
            let o = law
                .run_lanes(&integrator, &shifted, &run, &mut |k, s| out[k] = s[(lane + 5) % LANES]);
            assert!(o.iter().all(|o| o.is_ok()));
            out
        };
        for k in 0..run.time.len() {
            assert_eq!(together[k][lane].to_bits(), alone[k].to_bits(), "lane {lane} sample {k}");
            assert_eq!(other_lane[k].to_bits(), alone[k].to_bits(), "moved lane {lane}, {k}");
        }
    }
    // one lane outside the range fails alone
    let mut bad = sets;
    bad[2][0] = law.parameters()[0].range.1 * 10.0;
    let outcome = law.run_lanes(&integrator, &bad, &run, &mut |_, _| {});
    for (lane, o) in outcome.iter().enumerate() {
        assert_eq!(o.is_err(), lane == 2, "{:?} lane {lane}: {o:?}", law.kind());
    }
    // the order of the integrator
    let p_order = law.order() as i32;
    let with = |substeps: u32, extrapolate: bool| {
        let i =
            Integrator { substeps, extrapolate, max_substeps: 100_000, ..Integrator::default() };
        law.path(&i, p, &run).unwrap()
    };
    let reference = with(32 * first, true);
    let peak = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let error = |path: Vec<f64>| {
        path.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
    };
    let ladder: [u32; 3] = [first, 2 * first, 4 * first];
    let rate = 2f64.powi(p_order);
    for extrapolate in [false, true] {
        let e: Vec<f64> = ladder.iter().map(|&m| error(with(m, extrapolate))).collect();
        if e[0] <= 1e-10 * peak {
            continue;
        }
        for w in e.windows(2) {
            let ratio = w[0] / w[1];
            if w[1] <= 1e-8 * peak {
                continue;
            }
            if extrapolate {
                assert!(ratio > 1.25 * rate, "{:?}, extrapolated: errors {e:?}", law.kind());
            } else if p_order == 1 {
                assert!((1.6..=2.5).contains(&ratio), "{:?}: errors {e:?}", law.kind());
            } else {
                assert!(ratio > 0.8 * rate, "{:?}: errors {e:?}", law.kind());
            }
        }
    }
    // starts
    let starts = law.starts(std::slice::from_ref(&run));
    assert!(!starts.is_empty());
    for s in &starts {
        law.validate(s).unwrap_or_else(|e| panic!("{:?} start {s:?}: {e}", law.kind()));
        law.path(&integrator, s, &run).unwrap_or_else(|e| panic!("{:?} start: {e}", law.kind()));
    }
}
