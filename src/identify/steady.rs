//! Identification from steady cycles, for records that do not start with a
//! full-stroke loading from rest (a servo-hydraulic test whose amplitude
//! ramps up, say): the paper's route needs the virgin loading, this one
//! reads what steady cycles show.
//!
//! * G: the slope of τ(γ) in the middle of the elastic swing after each
//!   full-stroke reversal (from 20 % to 60 % of the swing, where the flow of
//!   eq. 3 has stopped and not yet restarted), the median over reversals;
//! * the flow curve: in steady flow γ̇ᴵ ≈ γ̇, so eq. 3 with saturated
//!   hardening gives |τ| = z / (√3 [(2n/(n+1)) ln(2D₀/|γ̇|)]^(1/(2n))) over
//!   the samples of each stroke where the stress has settled (at least 80 %
//!   of its largest value and flowing the way it is loaded); fitted for
//!   z = R1 + D1 and n, on ln |τ|.
//!
//! R0 and the hardening rates m1, m2 show only in a loading from rest; the
//! combined estimate takes them from elsewhere (see [`super::identify_current`]).

use crate::data::Run;
use crate::fit::least_squares;
use crate::model::D0;

/// Strokes spanning at least this share of the record's largest count as full.
const FULL_STROKE: f64 = 0.8;
/// The part of the elastic swing after a reversal that G is fitted over.
const SWING: (f64, f64) = (0.2, 0.6);
/// Settled flow: at least this share of the stroke's largest |τ|…
const SETTLED: f64 = 0.8;
/// …and at least this share of the record's largest |γ̇|.
const FLOWING: f64 = 0.05;

const SQRT_3: f64 = 1.732_050_807_568_877_2;

/// What the steady cycles of one record give.
#[derive(Clone, Debug)]
pub struct SteadyFit {
    pub g: f64,
    /// Saturated hardening R1 + D1 (Pa).
    pub z: f64,
    pub n: f64,
    /// Reversals G was measured at, and flow samples the flow curve used.
    pub reversals: usize,
    pub flow_samples: usize,
    /// RMS of ln τ − ln (flow curve) over those samples.
    pub rms_log: f64,
}

/// The first branch spanning at least [`FULL_STROKE`] of the record's largest.
pub fn first_full_stroke(run: &Run) -> usize {
    let spans: Vec<f64> = run.branches.iter().map(|b| span(&run.shear.gamma[b.clone()])).collect();
    let largest = spans.iter().copied().fold(0.0, f64::max);
    spans.iter().position(|s| *s >= FULL_STROKE * largest).unwrap_or(0)
}

/// Whether the paper's route applies to `run`: its first branch is a full
/// stroke from rest (stress near zero at its start).
pub fn starts_from_rest(run: &Run) -> bool {
    let spans: Vec<f64> = run.branches.iter().map(|b| span(&run.shear.gamma[b.clone()])).collect();
    let largest = spans.iter().copied().fold(0.0, f64::max);
    let peak = run.shear.tau.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    spans.first().is_some_and(|s| *s >= FULL_STROKE * largest)
        && (run.shear.tau[0] - run.shear.initial_tau).abs() < 0.1 * peak
}

fn span(x: &[f64]) -> f64 {
    let (lo, hi) =
        x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
    hi - lo
}

/// The steady-cycle identification of one record from its smoothed stress
/// `tau`, strain `gamma` and strain rate `rate`; or why it cannot be done.
pub fn identify(run: &Run, tau: &[f64], gamma: &[f64], rate: &[f64]) -> Result<SteadyFit, String> {
    let spans: Vec<f64> = run.branches.iter().map(|b| span(&gamma[b.clone()])).collect();
    let largest = spans.iter().copied().fold(0.0, f64::max);
    let strokes: Vec<std::ops::Range<usize>> = run
        .branches
        .iter()
        .zip(&spans)
        .filter(|(_, s)| **s >= FULL_STROKE * largest)
        .map(|(b, _)| b.clone())
        .collect();
    if strokes.is_empty() {
        return Err("no full stroke in the record".into());
    }
    // G: the middle of the elastic swing after each reversal
    let mut slopes: Vec<f64> = strokes
        .iter()
        .filter(|b| b.start > 0)
        .filter_map(|b| {
            let t0 = tau[b.start];
            let swing = tau[b.clone()].iter().map(|v| (v - t0).abs()).fold(0.0, f64::max);
            let inside: Vec<usize> = b
                .clone()
                .take_while(|&k| (tau[k] - t0).abs() <= SWING.1 * swing)
                .filter(|&k| (tau[k] - t0).abs() >= SWING.0 * swing)
                .collect();
            (inside.len() >= 3).then(|| {
                super::elastic::slope(
                    &inside.iter().map(|&k| gamma[k]).collect::<Vec<_>>(),
                    &inside.iter().map(|&k| tau[k]).collect::<Vec<_>>(),
                )
            })
        })
        .filter(|g| *g > 0.0)
        .collect();
    if slopes.is_empty() {
        return Err(
            "no reversal has three samples inside its elastic swing: G cannot be measured".into()
        );
    }
    slopes.sort_by(f64::total_cmp);
    let g = slopes[slopes.len() / 2];
    // the flow curve over the settled part of every stroke
    let top_rate = rate.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut flow: Vec<(f64, f64)> = Vec::new();
    for b in &strokes {
        let top = tau[b.clone()].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for k in b.clone() {
            let (t, r) = (tau[k], rate[k]);
            if t.abs() >= SETTLED * top
                && r.abs() >= FLOWING * top_rate
                && t * r > 0.0
                && r.abs() < 2.0 * D0
            {
                flow.push((r.abs(), t.abs()));
            }
        }
    }
    if flow.len() < 10 {
        return Err(format!(
            "only {} samples of settled flow: the flow curve cannot be fitted",
            flow.len()
        ));
    }
    let model = |p: &[f64], rate: f64| {
        p[0] - SQRT_3.ln()
            - ((2.0 * p[1].exp() / (p[1].exp() + 1.0)) * (2.0 * D0 / rate).ln()).ln()
                / (2.0 * p[1].exp())
    };
    let residuals = |p: &[f64]| Some(flow.iter().map(|(r, t)| model(p, *r) - t.ln()).collect());
    // start at n = 1 with z matching the mean level
    let z0 =
        flow.iter().map(|(r, t)| t.ln() - model(&[0.0, 0.0], *r)).sum::<f64>() / flow.len() as f64;
    let fit = least_squares(&[z0, 0.0], &residuals, None);
    let (z, n) = (fit.params[0].exp(), fit.params[1].exp());
    if !fit.converged
        || !(super::yield_stress::N_TRUSTED.0..=super::yield_stress::N_TRUSTED.1).contains(&n)
    {
        return Err(format!("the flow curve does not determine n (fit gave n = {n:.3e})"));
    }
    Ok(SteadyFit {
        g,
        z,
        n,
        reversals: slopes.len(),
        flow_samples: flow.len(),
        rms_log: (2.0 * fit.cost / flow.len() as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Campaign, Columns, Geometry, Manifest, RunSpec};
    use crate::model::{Integrator, Params};

    /// A sinusoid whose amplitude ramps up over two cycles, as a
    /// servo-hydraulic test runs, through the model with known parameters
    /// and no noise: G within 5 % and n within 10 %, and z within 5 % of
    /// the flow stress's R1 + D1.
    #[test]
    fn steady_cycles_recover_g_z_and_n() {
        let p = Params { r0: 1.0e5, ..Params::reference_1a() };
        let rate = 2000.0;
        let t: Vec<f64> = (0..8000).map(|k| k as f64 / rate).collect();
        let x: Vec<f64> = t
            .iter()
            .map(|t| 8e-3 * (t / 1.0).min(1.0) * (2.0 * std::f64::consts::PI * 2.0 * t).sin())
            .collect();
        let gamma: Vec<f64> = x.iter().map(|x| x / 1e-3).collect();
        let tau = Integrator {
            substeps: 8,
            extrapolate: true,
            max_substeps: 100_000,
            ..Integrator::default()
        }
        .run(&p, &t, &gamma)
        .unwrap()
        .tau;
        let dir = tempfile::tempdir().unwrap();
        let rec = crate::data::Record {
            time: t,
            displacement: x,
            force: tau.iter().map(|v| v * 0.05).collect(),
            current: None,
        };
        std::fs::write(
            dir.path().join("r.csv"),
            crate::data::table::csv_text(&rec).replace(",NaN", ",1"),
        )
        .unwrap();
        let manifest = Manifest {
            name: "t".into(),
            geometry: Geometry { area_m2: 0.05, gap_m: 1e-3 },
            columns: Columns::default(),
            limits: Default::default(),
            runs: vec![RunSpec::new("r".into(), "r.csv".into(), 1.0)],
        };
        std::fs::write(dir.path().join("c.toml"), toml::to_string(&manifest).unwrap()).unwrap();
        let campaign = Campaign::load(&dir.path().join("c.toml")).unwrap();
        let run = &campaign.runs[0];
        assert!(!starts_from_rest(run), "the ramp's first branch is not a full stroke");
        let sh = &run.shear;
        let (tau_s, _) = crate::data::local_polynomial(&sh.time, &sh.tau, 2, 3);
        let (gamma_s, rate_s) = crate::data::local_polynomial(&sh.time, &sh.gamma, 2, 3);
        let fit = identify(run, &tau_s, &gamma_s, &rate_s).unwrap();
        assert!((fit.g / p.g - 1.0).abs() < 0.05, "G {}", fit.g);
        assert!((fit.n / p.n - 1.0).abs() < 0.1, "n {}", fit.n);
        assert!((fit.z / (p.r1 + p.d1) - 1.0).abs() < 0.05, "z {}", fit.z);
    }
}
