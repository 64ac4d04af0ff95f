//! Damper laws side by side: how well each predicts the records, in sample
//! and on tests it did not see, in the measures of a Bayesian comparison
//! (log predictive density, coverage, band width) and in those
//! practitioners quote.
//!
//! For one record with measured force F, model force F̂ (the posterior
//! median path: the bands' q50 with the model terms, as force), residual
//! r = F − F̂:
//!
//! * nRMSE = RMS(r) / max |F|, the share of the peak force;
//! * E_t = ‖r‖ / ‖F − F̄‖, E_x the same with each sample weighted by |ẋ|
//!   and E_v by |ẍ| (Spencer et al. 1997: the error as a function of time,
//!   of displacement and of velocity, each over the force's own spread
//!   weighted alike);
//! * the share of the record inside the 95 % predictive band, the band's
//!   mean width as a share of the peak force, and the log pointwise
//!   predictive density (lppd).
//!
//! Held out, the record is predicted by the posterior of the law without
//! it (leave-one-out: `loo_bands.parquet`, `loo.parquet`); the laws are
//! ranked, current by current, by the sum of their held-out lppd over the
//! tests, with the standard error of each difference from the best law
//! over the tests as units (whole tests held out, as ArviZ's `compare`
//! takes pointwise terms): SE = √(n var(d)), d each test's difference.

use crate::error::{Error, Result};
use crate::laws::LawKind;
use crate::predict::RunBands;

/// In sample or held out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    InSample,
    HeldOut,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::InSample => "in-sample",
            Kind::HeldOut => "held-out",
        }
    }

    pub fn parse(name: &str) -> Option<Kind> {
        [Kind::InSample, Kind::HeldOut].into_iter().find(|k| k.name() == name)
    }
}

/// How one law predicts one record.
#[derive(Clone, Debug, PartialEq)]
pub struct LawRow {
    pub law: LawKind,
    pub current_a: f64,
    pub run: String,
    pub kind: Kind,
    pub measures: Measures,
    /// Log pointwise predictive density of the record (Σ over its samples).
    pub lppd: f64,
    /// Wall time (s) of the law's calibration at this current (start and
    /// sampling), on its in-sample and held-out rows alike.
    pub seconds: f64,
    /// The log evidence of the law's calibration at this current, on its
    /// rows alike (none where it could not be estimated).
    pub evidence: Option<LawEvidence>,
    /// A held-out row whose posterior was sampled afresh: the largest R̂
    /// of that sampling (NaN in sample, and where the held-out posterior
    /// was reached by reweighting or Laplace importance).
    pub held_out_rhat: f64,
    /// Such a row whose refit stopped before the sampler's rule held: what
    /// it still waited for ([`super::LooRow::unconverged`]).
    pub held_out_unconverged: Option<String>,
}

/// The error measures of `bands` (one record, its median path and bands in
/// stress) with the damper's `area_m2`: every sample after the first.
pub fn measures(bands: &RunBands, area_m2: f64) -> Measures {
    let n = bands.time.len();
    let f = &bands.force;
    let model: Vec<f64> = bands.model[2].iter().map(|t| t * area_m2).collect();
    let peak = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    // |ẋ| and |ẍ| of the displacement by central differences
    let x = &bands.displacement;
    let t = &bands.time;
    let derivative = |y: &[f64], k: usize| {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        if b > a {
            (y[b] - y[a]) / (t[b] - t[a])
        } else {
            0.0
        }
    };
    let v: Vec<f64> = (0..n).map(|k| derivative(x, k)).collect();
    let a: Vec<f64> = (0..n).map(|k| derivative(&v, k)).collect();
    let mean_f = f[1..].iter().sum::<f64>() / (n - 1).max(1) as f64;
    let ratio = |w: &dyn Fn(usize) -> f64| {
        let (mut num, mut den) = (0.0, 0.0);
        for k in 1..n {
            num += w(k) * (f[k] - model[k]).powi(2);
            den += w(k) * (f[k] - mean_f).powi(2);
        }
        (num / den).sqrt()
    };
    let rms = ((1..n).map(|k| (f[k] - model[k]).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    let inside = (1..n)
        .filter(|&k| {
            bands.tau_obs[k] >= bands.predictive[0][k] && bands.tau_obs[k] <= bands.predictive[1][k]
        })
        .count();
    let width = (1..n).map(|k| bands.predictive[1][k] - bands.predictive[0][k]).sum::<f64>()
        / (n - 1) as f64
        * area_m2;
    Measures {
        samples: n - 1,
        nrmse: rms / peak,
        e_t: ratio(&|_| 1.0),
        e_x: ratio(&|k| v[k].abs()),
        e_v: ratio(&|k| a[k].abs()),
        inside_p95: inside as f64 / (n - 1) as f64,
        band_width: width / peak,
    }
}

/// The error measures of one record ([`measures`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measures {
    /// The samples compared (every one after the first).
    pub samples: usize,
    /// RMS(F − F̂) / max |F|.
    pub nrmse: f64,
    pub e_t: f64,
    pub e_x: f64,
    pub e_v: f64,
    /// Share of the samples inside the 95 % predictive band.
    pub inside_p95: f64,
    /// The 95 % predictive band's mean width over max |F|.
    pub band_width: f64,
}

/// One law at one current, its records together.
#[derive(Clone, Debug, PartialEq)]
pub struct Standing {
    pub law: LawKind,
    pub current_a: f64,
    /// Held-out lppd summed over the tests (elpd of leaving one test out).
    pub elpd: f64,
    /// Its difference from the best law's at this current (0 for the best)
    /// and the standard error of that difference (NaN on fewer than two
    /// tests: one difference has no spread).
    pub elpd_diff: f64,
    pub elpd_diff_se: f64,
    /// Means over the tests, in sample and held out.
    pub nrmse_in: f64,
    pub nrmse_out: f64,
    /// Held-out samples inside the 95 % band, pooled over the tests.
    pub inside_p95_out: f64,
    pub band_width_out: f64,
    /// Wall time of the law's calibration at this current (s; the whole
    /// job's, leave-one-out included, is the report's per law).
    pub seconds: f64,
    /// Rank at the current by held-out elpd (1: best).
    pub rank: usize,
    /// The log evidence of the law's calibration at this current, its
    /// standard error, and whether it is a pseudo-evidence (a likelihood
    /// tempered or adjusted for the residuals' memory); where it was
    /// sampled by sequential Monte Carlo (`--sampler smc`).
    pub evidence: Option<LawEvidence>,
    /// Tests some law at this current could not be held out on (its
    /// leave-one-out row `failed`): left out of every law's held-out
    /// numbers here, so that the laws are compared on the same tests.
    pub set_aside: Vec<String>,
    /// The tests whose held-out posterior, sampled afresh, did not
    /// converge when the refit stopped, with what it still waited for (an
    /// R̂, a drift, an ESS, the chains' length): this law's held-out
    /// numbers there are of draws, not of a posterior.
    pub unsettled: Vec<(String, String)>,
}

/// A law's log evidence at one current.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LawEvidence {
    pub log_evidence: f64,
    pub se: f64,
    pub pseudo: bool,
    /// How it was estimated: [`SMC`] or [`BRIDGE`].
    pub by: &'static str,
}

pub use crate::calibrate::evidence::{BRIDGE, SMC};

impl From<&crate::calibrate::evidence::Estimate> for LawEvidence {
    fn from(e: &crate::calibrate::evidence::Estimate) -> Self {
        LawEvidence { log_evidence: e.log_evidence, se: e.se, pseudo: e.pseudo, by: e.by }
    }
}

/// The laws' standings, current by current (rank 1 the best held-out
/// elpd), on the tests every law was held out on: a test some law could
/// not be held out on is set aside for all of them
/// ([`Standing::set_aside`]).
pub fn standings(rows: &[LawRow]) -> Result<Vec<Standing>> {
    let mut currents: Vec<f64> = rows.iter().map(|r| r.current_a).collect();
    currents.sort_by(f64::total_cmp);
    currents.dedup();
    let mut out = Vec::new();
    for c in currents {
        let at: Vec<&LawRow> = rows.iter().filter(|r| r.current_a == c).collect();
        let mut laws: Vec<LawKind> = at.iter().map(|r| r.law).collect();
        laws.dedup();
        laws.sort_by_key(|l| LawKind::ALL.iter().position(|k| k == l));
        laws.dedup();
        // the tests every law was held out on (a law whose held-out
        // posterior could not be reached for a test has no row for it)
        let held_on = |law: LawKind, run: &str| {
            at.iter().any(|r| r.law == law && r.kind == Kind::HeldOut && r.run == run)
        };
        let mut every: Vec<String> =
            at.iter().filter(|r| r.kind == Kind::HeldOut).map(|r| r.run.clone()).collect();
        every.sort();
        every.dedup();
        let (tests, set_aside): (Vec<String>, Vec<String>) =
            every.into_iter().partition(|run| laws.iter().all(|&law| held_on(law, run)));
        if tests.is_empty() && !set_aside.is_empty() {
            return Err(Error::Compute(format!(
                "at {c} A no test was held out by every law ({set_aside:?}): the laws cannot be compared"
            )));
        }
        let held = |law: LawKind| -> Vec<&LawRow> {
            let mut v: Vec<&LawRow> = at
                .iter()
                .copied()
                .filter(|r| r.law == law && r.kind == Kind::HeldOut && tests.contains(&r.run))
                .collect();
            v.sort_by(|a, b| a.run.cmp(&b.run));
            v
        };
        let elpd = |law: LawKind| held(law).iter().map(|r| r.lppd).sum::<f64>();
        let best = laws
            .iter()
            .copied()
            .max_by(|a, b| elpd(*a).total_cmp(&elpd(*b)))
            .ok_or_else(|| Error::Compute(format!("no law at {c} A")))?;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let mut standing: Vec<Standing> = laws
            .iter()
            .map(|&law| {
                let h = held(law);
                let d: Vec<f64> = h.iter().zip(held(best)).map(|(a, b)| a.lppd - b.lppd).collect();
                let n = d.len() as f64;
                let md = mean(&d);
                let var = d.iter().map(|x| (x - md).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
                let ins: Vec<&LawRow> = at
                    .iter()
                    .copied()
                    .filter(|r| r.law == law && r.kind == Kind::InSample)
                    .collect();
                let samples: usize = h.iter().map(|r| r.measures.samples).sum();
                Standing {
                    law,
                    current_a: c,
                    elpd: elpd(law),
                    elpd_diff: d.iter().sum(),
                    // fewer than two differences have no spread to measure
                    elpd_diff_se: if n >= 2.0 { (n * var).sqrt() } else { f64::NAN },
                    nrmse_in: mean(&ins.iter().map(|r| r.measures.nrmse).collect::<Vec<_>>()),
                    nrmse_out: mean(&h.iter().map(|r| r.measures.nrmse).collect::<Vec<_>>()),
                    inside_p95_out: h
                        .iter()
                        .map(|r| r.measures.inside_p95 * r.measures.samples as f64)
                        .sum::<f64>()
                        / samples.max(1) as f64,
                    band_width_out: mean(
                        &h.iter().map(|r| r.measures.band_width).collect::<Vec<_>>(),
                    ),
                    seconds: ins.first().or(h.first()).map_or(0.0, |r| r.seconds),
                    rank: 0,
                    evidence: None,
                    set_aside: set_aside.clone(),
                    unsettled: h
                        .iter()
                        .filter_map(|r| r.held_out_unconverged.clone().map(|u| (r.run.clone(), u)))
                        .collect(),
                }
            })
            .collect();
        standing.sort_by(|a, b| b.elpd.total_cmp(&a.elpd));
        for (k, s) in standing.iter_mut().enumerate() {
            s.rank = k + 1;
        }
        out.extend(standing);
    }
    Ok(out)
}

/// The verdict in plain words, current by current: the law that predicts
/// tests it did not see best, by how much more than the next (in units of
/// the difference's standard error), and whether that is decisive (more
/// than two standard errors) or not.
pub fn verdict(standings: &[Standing]) -> Vec<String> {
    let mut currents: Vec<f64> = standings.iter().map(|s| s.current_a).collect();
    currents.dedup();
    currents
        .iter()
        .map(|&c| {
            let at: Vec<&Standing> = standings.iter().filter(|s| s.current_a == c).collect();
            let first = at[0];
            let line = match at.get(1) {
                None => format!("at {c} A only the {} law was calibrated", first.law.name()),
                Some(second) => {
                    let gap = -second.elpd_diff;
                    let se = second.elpd_diff_se;
                    let margin = if !se.is_finite() {
                        "fewer than two tests in common: no standard error of the difference, so not decisive".to_string()
                    } else if gap > 2.0 * se {
                        format!("± {se:.0}, more than two standard errors: decisive on these tests")
                    } else {
                        format!("± {se:.0}, within two standard errors: not decisive on these tests")
                    };
                    format!(
                        "at {c} A the {} law predicts the held-out tests best: {:.0} nats of log predictive density ahead of the {} law ({margin}); held-out nRMSE {:.1} % against {:.1} %, its 95 % band {:.0} % of the peak force wide and holding {:.1} % of the held-out samples",
                        first.law.name(),
                        gap,
                        second.law.name(),
                        100.0 * first.nrmse_out,
                        100.0 * second.nrmse_out,
                        100.0 * first.band_width_out,
                        100.0 * first.inside_p95_out
                    )
                }
            };
            let line = match first.set_aside.as_slice() {
                [] => line,
                aside => format!(
                    "{line} (on the tests every law was held out on: {} set aside, some law's held-out posterior could not be reached there — loo.parquet says why)",
                    aside.join(", ")
                ),
            };
            let line = at.iter().filter(|s| !s.unsettled.is_empty()).fold(line, |line, s| {
                let tests: Vec<&str> = s.unsettled.iter().map(|(run, _)| run.as_str()).collect();
                let why: Vec<String> =
                    s.unsettled.iter().map(|(run, u)| format!("{run}: {u}")).collect();
                format!(
                    "{line}. The {} law's held-out posteriors without {} were not reached ({}; loo.parquet's `unconverged`), so its held-out numbers there are approximate and its rank here is not to be trusted",
                    s.law.name(),
                    tests.join(", "),
                    why.join("; ")
                )
            });
            match evidence_sentence(&at) {
                Some(sentence) => format!("{line}. {sentence}"),
                None => line,
            }
        })
        .collect()
}

/// What the log evidence says of the laws at one current (`at`, ranked by
/// held-out elpd), where every law has one: which leads and by how much,
/// and whether that agrees with the held-out ranking, with why it may
/// not.
fn evidence_sentence(at: &[&Standing]) -> Option<String> {
    let with: Vec<(&Standing, LawEvidence)> =
        at.iter().map(|s| s.evidence.map(|e| (*s, e))).collect::<Option<Vec<_>>>()?;
    if with.len() < 2 {
        return None;
    }
    let pseudo: Vec<String> =
        with.iter().filter(|(_, e)| e.pseudo).map(|(s, _)| s.law.name()).collect();
    if !pseudo.is_empty() {
        // each law's adjustment (or tempering) is its own: their
        // pseudo-evidences do not compare, with one another or with an
        // evidence proper
        return Some(format!(
            "The log evidence does not rank these laws: the likelihood of the {} law{} allowed for the residuals' memory, which makes it a pseudo-evidence of that law's own adjustment (--memory independent gives evidences that compare, of a likelihood that takes the residuals as independent)",
            pseudo.join(", "),
            if pseudo.len() > 1 { "s" } else { "" }
        ));
    }
    let mut by_evidence = with.clone();
    by_evidence.sort_by(|a, b| b.1.log_evidence.total_cmp(&a.1.log_evidence));
    let ((top, e1), (next, e2)) = (by_evidence[0], by_evidence[1]);
    let gap = e1.log_evidence - e2.log_evidence;
    let se = e1.se.hypot(e2.se);
    let agrees = top.law == at[0].law;
    Some(format!(
        "By the log evidence (all the tests in sample, priors included) the {} law leads the {} law by {gap:.1} ± {se:.2} nats; {}",
        top.law.name(),
        next.law.name(),
        if agrees {
            "the same law as the held-out ranking"
        } else {
            "not the held-out ranking's law: the evidence weighs how well the priors foresaw the fit and counts every sample as new information, while held-out tests judge prediction; with residuals that keep memory the evidence overstates the information in the records most"
        }
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record whose force is its model's plus a known residual: nRMSE,
    /// E_t and the coverage by hand.
    #[test]
    fn measures_by_hand() {
        let n = 401;
        let time: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        let x: Vec<f64> =
            time.iter().map(|t| 0.01 * (2.0 * std::f64::consts::PI * t).sin()).collect();
        let model_force: Vec<f64> =
            time.iter().map(|t| 1000.0 * (2.0 * std::f64::consts::PI * t).cos()).collect();
        // residual ±20 N alternating: RMS 20 N
        let force: Vec<f64> = model_force
            .iter()
            .enumerate()
            .map(|(k, f)| f + if k % 2 == 0 { 20.0 } else { -20.0 })
            .collect();
        let area = 0.05;
        let tau = |v: &Vec<f64>| v.iter().map(|f| f / area).collect::<Vec<f64>>();
        let q50 = tau(&model_force);
        // a band ±30 N: every sample inside
        let lo: Vec<f64> = model_force.iter().map(|f| (f - 30.0) / area).collect();
        let hi: Vec<f64> = model_force.iter().map(|f| (f + 30.0) / area).collect();
        let bands = RunBands {
            run: "r".into(),
            current_a: 1.0,
            time: time.clone(),
            gamma: x.clone(),
            gamma_model: x.clone(),
            tau_obs: tau(&force),
            model: [q50.clone(), q50.clone(), q50.clone(), q50.clone(), q50],
            predictive: [lo, hi],
            displacement: x,
            force: force.clone(),
            discrepancy: None,
            coil_current_a: None,
        };
        let m = measures(&bands, area);
        let peak = force.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((m.nrmse - 20.0 / peak).abs() < 1e-12, "{}", m.nrmse);
        assert_eq!(m.inside_p95, 1.0);
        assert!((m.band_width - 60.0 / peak).abs() < 1e-9);
        // E_t: ‖r‖ / ‖F − F̄‖ computed here independently
        let mean = force[1..].iter().sum::<f64>() / (n - 1) as f64;
        let den: f64 = force[1..].iter().map(|f| (f - mean).powi(2)).sum();
        assert!((m.e_t - (400.0 * (n - 1) as f64 / den).sqrt()).abs() < 1e-12);
    }

    fn row(law: LawKind, run: &str, kind: Kind, lppd: f64) -> LawRow {
        LawRow {
            law,
            current_a: 1.0,
            run: run.into(),
            kind,
            measures: Measures {
                samples: 100,
                nrmse: 0.05,
                e_t: 0.1,
                e_x: 0.1,
                e_v: 0.1,
                inside_p95: 0.95,
                band_width: 0.2,
            },
            lppd,
            evidence: None,
            held_out_rhat: f64::NAN,
            held_out_unconverged: None,
            seconds: 1.0,
        }
    }

    /// The ranking and the standard error of a difference by hand: held-out
    /// lppd per test (Bouc-Wen −100, −200; Spencer −110, −180) give elpd
    /// −300 and −290: Spencer first, Bouc-Wen 10 nats behind.
    #[test]
    fn laws_are_ranked_by_held_out_elpd_with_the_se_of_the_difference() {
        let rows = vec![
            row(LawKind::BoucWen, "t1", Kind::HeldOut, -100.0),
            row(LawKind::BoucWen, "t2", Kind::HeldOut, -200.0),
            row(LawKind::Spencer, "t1", Kind::HeldOut, -110.0),
            row(LawKind::Spencer, "t2", Kind::HeldOut, -180.0),
            row(LawKind::BoucWen, "t1", Kind::InSample, -90.0),
            row(LawKind::Spencer, "t1", Kind::InSample, -90.0),
        ];
        let s = standings(&rows).unwrap();
        assert_eq!((s[0].law, s[0].rank, s[0].elpd), (LawKind::Spencer, 1, -290.0));
        assert_eq!((s[1].law, s[1].rank, s[1].elpd_diff), (LawKind::BoucWen, 2, -10.0));
        // d = (10, −20): mean −5, var = (225 + 225)/1 = 450, SE = √(2 · 450) = 30
        assert!((s[1].elpd_diff_se - 30.0).abs() < 1e-12, "{}", s[1].elpd_diff_se);
        assert_eq!(s[0].elpd_diff, 0.0);
        let v = verdict(&s);
        assert!(
            v[0].contains("the spencer law predicts the held-out tests best: 10 nats"),
            "{v:?}"
        );
        assert!(v[0].contains("not decisive"), "{v:?}");
        // a test some law could not be held out on is set aside for every
        // law: Spencer on t1 and t3, Bouc-Wen on t1 and t2 compare on t1
        // alone (−100 against −110: Bouc-Wen first)
        let mut other = rows.clone();
        other[3].run = "t3".into();
        let s = standings(&other).unwrap();
        assert_eq!((s[0].law, s[0].elpd, s[1].elpd), (LawKind::BoucWen, -100.0, -110.0));
        assert_eq!(s[0].set_aside, ["t2", "t3"]);
        assert!(verdict(&s)[0].contains("t2, t3 set aside"), "{:?}", verdict(&s));
        // one test in common: its difference has no standard error, and a
        // gap of 10 nats is not called decisive (it was: "± 0, more than
        // two standard errors")
        assert!(s[1].elpd_diff_se.is_nan(), "{}", s[1].elpd_diff_se);
        assert!(
            verdict(&s)[0]
                .contains("fewer than two tests in common: no standard error of the difference, so not decisive"),
            "{:?}",
            verdict(&s)
        );
        // no test that every law was held out on: refused
        other[2].run = "t4".into();
        assert!(standings(&other).is_err());
    }

    /// A held-out refit that stopped unconverged (R̂ 1.60 for Spencer
    /// without t2) is named in the verdict with what it waited for, the
    /// law's rank called untrustworthy; a converged refit (R̂ 1.005) or a
    /// row reached without sampling (NaN) is not.
    #[test]
    fn the_verdict_names_a_held_out_posterior_that_did_not_converge() {
        let mut rows = vec![
            row(LawKind::BoucWen, "t1", Kind::HeldOut, -100.0),
            row(LawKind::BoucWen, "t2", Kind::HeldOut, -200.0),
            row(LawKind::Spencer, "t1", Kind::HeldOut, -110.0),
            row(LawKind::Spencer, "t2", Kind::HeldOut, -180.0),
        ];
        rows[0].held_out_rhat = 1.005;
        let v = verdict(&standings(&rows).unwrap());
        assert!(!v[0].contains("were not reached"), "{v:?}");
        rows[3].held_out_rhat = 1.6;
        let waited = "R̂ of fz is 1.6000 (target < 1.01)";
        rows[3].held_out_unconverged = Some(waited.into());
        let s = standings(&rows).unwrap();
        assert_eq!(s[0].unsettled, [("t2".to_string(), waited.to_string())]);
        assert!(s[1].unsettled.is_empty());
        let v = verdict(&s);
        assert!(
            v[0].contains(
                "The spencer law's held-out posteriors without t2 were not reached (t2: R̂ of fz is 1.6000 (target < 1.01); loo.parquet's `unconverged`)"
            ),
            "{v:?}"
        );
        assert!(v[0].contains("its rank here is not to be trusted"), "{v:?}");
    }

    /// The evidence sentence: only where every law has an evidence; the
    /// gap and its se by hand (e₁ − e₂ = 12.5, √(0.3² + 0.4²) = 0.5);
    /// whether it names the held-out ranking's law; no ranking where a
    /// law's is a pseudo-evidence.
    #[test]
    fn the_verdict_adds_the_evidence_where_every_law_has_one() {
        let rows = vec![
            row(LawKind::BoucWen, "t1", Kind::HeldOut, -100.0),
            row(LawKind::BoucWen, "t2", Kind::HeldOut, -200.0),
            row(LawKind::Spencer, "t1", Kind::HeldOut, -110.0),
            row(LawKind::Spencer, "t2", Kind::HeldOut, -180.0),
        ];
        let mut s = standings(&rows).unwrap();
        assert!(!verdict(&s)[0].contains("log evidence"));
        s[0].evidence =
            Some(LawEvidence { log_evidence: -1000.0, se: 0.3, pseudo: false, by: SMC });
        assert!(!verdict(&s)[0].contains("log evidence"), "one law alone has an evidence");
        s[1].evidence =
            Some(LawEvidence { log_evidence: -1012.5, se: 0.4, pseudo: false, by: BRIDGE });
        let v = verdict(&s);
        assert!(
            v[0].contains("the spencer law leads the bouc-wen law by 12.5 ± 0.50 nats; the same law as the held-out ranking"),
            "{v:?}"
        );
        s[1].evidence = Some(LawEvidence { log_evidence: -990.0, se: 0.4, pseudo: false, by: SMC });
        let v = verdict(&s);
        assert!(
            v[0].contains("the bouc-wen law leads the spencer law by 10.0 ± 0.50 nats"),
            "{v:?}"
        );
        assert!(v[0].contains("not the held-out ranking's law"), "{v:?}");
        s[1].evidence = Some(LawEvidence { log_evidence: -990.0, se: 0.4, pseudo: true, by: SMC });
        let v = verdict(&s);
        assert!(
            v[0].contains("does not rank these laws: the likelihood of the bouc-wen law allowed"),
            "{v:?}"
        );
    }
}
