//! The uncertainty report of one calibration: figures (SVG + PNG) beside
//! the data, and `report.html`, one self-contained file with every table and
//! figure inline, to be mailed as it is.

use std::collections::BTreeMap;
use std::path::PathBuf;

use super::adequacy;
use super::figures::{self, Figures};
use super::html::{esc, num, Mark, Page};
use crate::atomic;
use crate::calibrate::CONFOUNDING_RATIO;
use crate::calibrate::{Calibration, SmcRecord};
use crate::data::{current_tag, Campaign};
use crate::error::{Error, Result};
use crate::model::PARAM_NAMES;
use crate::posterior::map::step_shift_limit;
use crate::posterior::ParameterModel;
use crate::predict::{CoverageRow, Prediction};
use crate::sampler::diagnostics::MIN_TAU_MULTIPLE;
use crate::validate::between_runs::{LeftOut, NewTestRow};
use crate::validate::consistency::ParameterConsistency;
use crate::validate::LeaveOneOut;

/// The share of observations a 95 % predictive band should hold for the
/// report to call it calibrated.
pub const COVERAGE_OK: (f64, f64) = (0.90, 0.99);

/// The share a 95 % band must hold of a run at a current the calibration
/// never saw (a current law's held-out current).
pub const HELD_OUT_OK: f64 = 0.80;

/// Draws shown in the corner and marginal plots.
const PLOT_DRAWS: usize = 2000;

/// Everything the report of one calibration shows.
pub struct CalibrationReport<'a> {
    pub cal: &'a Calibration,
    /// The runs it was calibrated on.
    pub campaign: &'a Campaign,
    /// Its bands, coverage and adequacy.
    pub prediction: &'a Prediction,
    /// The leave-one-out study, where it was run.
    pub loo: Option<&'a LeaveOneOut>,
    /// Each run calibrated alone against this calibration (`--per-run`).
    pub consistency: Option<&'a [ParameterConsistency]>,
    /// Each run predicted as a new test by the between-run layer fitted
    /// without it, or without its current (`--per-run --leave-one-out`).
    pub new_test_loo: Option<&'a [NewTestRow]>,
}

/// Writes the figures and `report.html` into the calibration's folder.
/// Returns the report's path.
pub fn write(r: &CalibrationReport) -> Result<PathBuf> {
    let dir = &r.cal.dir;
    // no report until the new one is whole
    atomic::remove(&dir.join(super::html::REPORT))?;
    let (figs, loo_figs) = draw_figures(r)?;
    let mut page = Page::new(&title(r.cal));
    page.derived_from(&r.cal.record.calibration_id);
    let checks = verdicts(r.cal, &r.prediction.coverage);
    let warned = checks.iter().filter(|c| c.1 == Mark::Warn).count();
    page.raw(&format!(
        "<p>B-P parameters of MR fluid calibrated on {} run(s) at {} by ensemble MCMC. {}</p>",
        r.cal.record.runs.len(),
        calibrated_at(r.cal),
        if warned == 0 {
            "<span class=\"pass\">Every check passes.</span>".to_string()
        } else {
            format!("<span class=\"warn\">{warned} check(s) warn: see Diagnostics.</span>")
        }
    ));
    campaign_section(&mut page, r);
    identification_section(&mut page, r.cal);
    posterior_section(&mut page, r.cal);
    if let Some(parameters) = r.consistency {
        disagreement_note(&mut page, parameters);
    }
    page.section("diagnostics", "Diagnostics");
    let rows: Vec<Vec<String>> = checks
        .iter()
        .map(|(what, mark, detail)| vec![esc(what), mark.html().into(), esc(detail)])
        .collect();
    page.table(&["check", "", "measured"], &rows);
    for w in r
        .cal
        .record
        .warnings
        .iter()
        .chain(&r.cal.record.model_warnings)
        .chain(&r.cal.record.confounding)
    {
        page.note(w);
    }
    if let Some(smc) = &r.cal.record.smc {
        smc_section(&mut page, smc);
    }
    coverage_section(&mut page, r);
    adequacy::section(
        &mut page, dir, &r.prediction.bands, &r.prediction.adequacy, &r.campaign.geometry,
        &r.cal.settings.likelihood,
    )?;
    validation_section(&mut page, r, &loo_figs)?;
    consistency_section(&mut page, r)?;
    figures_section(&mut page, r.cal, &figs)?;
    reproduce_section(&mut page, r);
    let path = dir.join(super::html::REPORT);
    atomic::write(&path, page.finish().as_bytes())?;
    Ok(path)
}

fn title(cal: &Calibration) -> String {
    let rec = &cal.record;
    if cal.is_current_law() {
        let kind = if cal.sample.model.kind() == crate::posterior::ModelKind::CurrentCurves {
            "current curves"
        } else {
            "current law"
        };
        format!("mrbp report: {}, {kind} from {:?} A", rec.campaign, rec.currents)
    } else {
        format!("mrbp report: {} at {} A", rec.campaign, rec.current_a)
    }
}

fn calibrated_at(cal: &Calibration) -> String {
    match cal.sample.model {
        ParameterModel::CurrentLaw { reference_a, .. } => format!(
            "{:?} A as functions of the coil current (reference {reference_a} A)",
            cal.record.currents
        ),
        ParameterModel::CurrentCurves { low_a, high_a, .. } => {
            format!("{:?} A, each parameter its own curve in the coil current through its values at {low_a} and {high_a} A", cal.record.currents)
        }
        ParameterModel::PerCurrent => format!("{} A", cal.record.current_a),
        ParameterModel::Law { law } => {
            format!("{} A, the {} law", cal.record.current_a, law.name())
        }
    }
}

/// The figures of the calibration and of its leave-one-out study.
/// The corner plot shows every coordinate up to this many, else θ alone.
const CORNER_MAX: usize = 12;

fn draw_figures(r: &CalibrationReport) -> Result<(Figures, Figures)> {
    let (cal, dir) = (r.cal, &r.cal.dir);
    let rec = &cal.record;
    let mut figs = Figures::default();
    let geometry = r.campaign.geometry;
    figures::bands(dir, &r.prediction.bands, geometry.area_m2, geometry.gap_m, &mut figs)?;
    figures::residuals(dir, &r.prediction.bands, &mut figs)?;
    if cal.is_current_law() {
        // the table the folder holds; computed afresh for a folder made before it
        let rows = match crate::store::against_current::read(
            dir,
            &rec.calibration_id,
            crate::store::folder::REBUILD,
        )? {
            Some(rows) => rows,
            None => crate::compare::against_current(
                &cal.sample,
                &cal.draw_positions(crate::store::folder::CURRENT_DRAWS),
                &rec.currents,
            ),
        };
        let law = figures::LawCurves {
            label: "law",
            rows: &rows,
            calibrated_a: &rec.currents,
            color: None,
        };
        figures::against_current(
            dir,
            &PARAM_NAMES,
            &[law],
            &[],
            " The values are in against_current.parquet.",
            &mut figs,
        )?;
    }
    let positions = cal.draw_positions(PLOT_DRAWS);
    // θ and the noise scales, as long as the matrix stays readable
    let layout = &cal.sample.layout;
    let mut shown = layout.theta_names().to_vec();
    if layout.names.len() <= CORNER_MAX {
        shown = layout.names.clone();
    }
    let named = |m: &BTreeMap<String, f64>| -> Vec<f64> {
        shown.iter().map(|n| m.get(n).copied().unwrap_or(f64::NAN)).collect()
    };
    // a current law's coordinates are not the identification's parameters
    let identified =
        if cal.is_current_law() { vec![f64::NAN; shown.len()] } else { named(&rec.identification) };
    figures::corner(
        dir,
        &cal.sample,
        &shown,
        &positions,
        &identified,
        &named(&rec.map),
        &mut figs,
    )?;
    let priors = cal.sample.model.priors(&cal.settings.priors());
    figures::marginals(dir, &cal.sample, &positions, &priors, &mut figs)?;
    figures::traces(dir, &cal.sample, cal.burn_in(), &mut figs)?;
    let tau: Vec<f64> = cal.summary.iter().map(|r| r.tau_int).collect();
    figures::diagnostics(dir, &cal.sample, cal.burn_in(), &tau, &mut figs)?;
    let mut loo_figs = Figures::default();
    if let Some(LeaveOneOut { bands, .. }) = r.loo {
        let loo_dir = dir.join("loo");
        std::fs::create_dir_all(&loo_dir).map_err(|e| Error::output(&loo_dir, e))?;
        figures::bands(&loo_dir, bands, geometry.area_m2, geometry.gap_m, &mut loo_figs)?;
    }
    Ok((figs, loo_figs))
}

fn campaign_section(page: &mut Page, r: &CalibrationReport) {
    let (cal, rec) = (r.cal, &r.cal.record);
    page.section("campaign", "Campaign and settings");
    let rows: Vec<Vec<String>> = r
        .campaign
        .runs
        .iter()
        .map(|run| {
            let t = &run.record.time;
            vec![
                esc(run.id()),
                run.record.len().to_string(),
                num(t[t.len() - 1] - t[0], 3),
                num(run.spec.current_a, 2),
                num(run.record.force.iter().fold(0.0f64, |m, f| m.max(f.abs())), 4),
                run.branches.len().to_string(),
            ]
        })
        .collect();
    page.table(
        &["run", "samples", "duration (s)", "current (A)", "peak force (N)", "loading branches"],
        &rows,
    );
    let geometry = r.campaign.geometry;
    let integ = &cal.settings.integrator;
    page.table(
        &["setting", "value"],
        &[
            vec!["manifest".into(), esc(&rec.manifest)],
            vec![
                "geometry".into(),
                format!("A = {} m², h = {} m", geometry.area_m2, geometry.gap_m),
            ],
            vec![
                "noise model".into(),
                esc(&format!(
                    "{:?}{}",
                    rec.noise,
                    crate::report::text::memory_note(&cal.settings.likelihood)
                )),
            ],
            vec!["samples in the likelihood".into(), esc(&format!("{:?}", rec.part))],
            vec![
                "integrator".into(),
                format!(
                    "{:?}, {} sub-step(s) per sample{}",
                    integ.scheme,
                    rec.substeps,
                    if integ.extrapolate { ", Richardson-extrapolated" } else { "" }
                ),
            ],
            vec![
                "sampler".into(),
                format!(
                    "{} ensembles × {} walkers, {} steps, burn-in {}",
                    rec.ensembles, rec.walkers, rec.steps, rec.burn_in
                ),
            ],
            vec!["seed".into(), rec.seed.to_string()],
        ],
    );
}

fn identification_section(page: &mut Page, cal: &Calibration) {
    let rec = &cal.record;
    page.section("identification", "Identification and posterior");
    let summary_of = |name: &str| cal.summary.iter().find(|r| r.parameter == name);
    let rows: Vec<Vec<String>> = PARAM_NAMES
        .iter()
        .map(|n| {
            let s = summary_of(n);
            vec![
                esc(n),
                num(rec.identification.get(*n).copied().unwrap_or(f64::NAN), 3),
                num(rec.map.get(*n).copied().unwrap_or(f64::NAN), 3),
                s.map_or("–".into(), |s| num(s.q50, 3)),
                s.map_or("–".into(), |s| format!("{} – {}", num(s.q05, 4), num(s.q95, 4))),
            ]
        })
        .collect();
    page.para("The paper's step-by-step identification, the posterior mode (MAP) and the posterior median with its 90 % credible interval, in SI units (Pa, 1/Pa, –).");
    page.table(
        &["parameter", "identification", "MAP", "posterior median", "90 % credible interval"],
        &rows,
    );
}

/// Below the posterior summary: the parameters on which the runs
/// calibrated alone disagree, with the interval a new test should quote.
fn disagreement_note(page: &mut Page, parameters: &[ParameterConsistency]) {
    let disagree: Vec<String> = parameters
        .iter()
        .filter(|p| p.disagrees())
        .map(|p| {
            let unit = match crate::posterior::unit_of(&p.parameter) {
                "-" | "" => String::new(),
                u => format!(" {u}"),
            };
            format!(
                "{} {} – {}{unit} (χ²/ν = {:.1})",
                p.parameter,
                num(p.new_test.q05, 3),
                num(p.new_test.q95, 3),
                p.chi2_nu
            )
        })
        .collect();
    if !disagree.is_empty() {
        page.note(&format!(
            "These intervals describe these records together. The runs calibrated alone disagree beyond their own intervals on {} of {} parameters, so for a new test of this damper quote the between-run layer's 90 % intervals: {} (\"Consistency across runs\" below).",
            disagree.len(),
            parameters.len(),
            disagree.join("; ")
        ));
    }
}

fn posterior_section(page: &mut Page, cal: &Calibration) {
    page.section("posterior", "Posterior summary");
    let min_ess = cal.settings.sampler.min_ess;
    let rows: Vec<Vec<String>> = cal
        .summary
        .iter()
        .map(|s| {
            let ok = s.r_hat < 1.01 && s.ess_bulk >= min_ess && s.ess_tail >= min_ess;
            vec![
                esc(&s.parameter),
                num(s.mean, 4),
                num(s.sd, 3),
                num(s.q05, 4),
                num(s.q50, 4),
                num(s.q95, 4),
                format!("{:.0}", s.ess_bulk),
                format!("{:.0}", s.ess_tail),
                cal.record
                    .ess_bulk_per_second
                    .get(&s.parameter)
                    .map_or("–".into(), |v| format!("{v:.0}")),
                format!("{:.4}", s.r_hat),
                format!("{:.1}", s.tau_int),
                Mark::of(ok).html().into(),
            ]
        })
        .collect();
    let rec = &cal.record;
    if let Some(found) = &rec.memory_found {
        page.para(&format!("Memory: {found}."));
    }
    page.para(&format!(
        "The intervals hold for {}{}. ESS/s: bulk effective sample size per second of the whole calibration (identification, MAP, step rule and sampling).",
        cal.intervals_hold_for(),
        if rec.independent.is_empty() {
            String::new()
        } else {
            format!("; for a test not yet run, {}", crate::report::text::new_test_hint(cal))
        }
    ));
    page.table(
        &[
            "parameter", "mean", "sd", "q05", "q50", "q95", "ESS bulk", "ESS tail", "ESS/s", "R̂",
            "τ (steps)", "",
        ],
        &rows,
    );
    if rec.independent.is_empty() {
        return;
    }
    page.para("These records, if the residuals were independent: the Laplace approximation of that posterior at its mode. Too narrow for these records, whose residuals have memory; shown for comparison with a calibration that ignores it. \"Widened ×\": the 90 % interval above over this one.");
    let rows: Vec<Vec<String>> = cal
        .independent_beside()
        .into_iter()
        .map(|(i, widened)| {
            vec![
                esc(&i.parameter),
                num(i.sd, 3),
                num(i.q05, 4),
                num(i.q50, 4),
                num(i.q95, 4),
                format!("{widened:.2}"),
            ]
        })
        .collect();
    page.table(&["parameter", "sd", "q05", "q50", "q95", "widened ×"], &rows);
}

/// What sequential Monte Carlo did (`--sampler smc`): its ladder per
/// population and the log evidence each population estimated.
fn smc_section(page: &mut Page, smc: &SmcRecord) {
    page.section("smc", "Sequential Monte Carlo and the log evidence");
    page.para(&format!("{}.", upper_first(&smc.summary())));
    page.para("Each population climbed its own ladder of temperatures from the reference (β = 0) to the posterior (β = 1), moved by the ensemble sampler at each; the evidence is the mean of the populations' estimates, and its standard error the larger of what the weights and what the populations' spread say. The ensemble sampler then continued from the final particles (the posterior summary above).");
    let offset = smc.log_evidence - smc.log_integral;
    let rows: Vec<Vec<String>> = smc
        .temperatures
        .iter()
        .zip(&smc.mutation_steps)
        .zip(&smc.per_population)
        .enumerate()
        .map(|(i, ((betas, steps), log_z))| {
            let ladder: Vec<String> = betas.iter().map(|b| format!("{b:.3}")).collect();
            vec![
                format!("{}", i + 1),
                betas.len().to_string(),
                esc(&ladder.join(", ")),
                steps.iter().sum::<usize>().to_string(),
                format!("{:.2}", log_z + offset),
            ]
        })
        .collect();
    page.table(&["population", "temperatures", "β", "mutation steps", "its log evidence"], &rows);
}

/// `text` with its first letter in upper case.
fn upper_first(text: &str) -> String {
    let mut chars = text.chars();
    chars.next().map_or(String::new(), |c| c.to_uppercase().chain(chars).collect())
}

fn coverage_section(page: &mut Page, r: &CalibrationReport) {
    page.section("coverage", "Predictive coverage");
    page.para(&format!(
        "{} posterior draws (after the burn-in, thinned by {} steps) integrated along each whole record, with {} noise replicates per draw. A calibrated model holds about 95 % of the observations in its 95 % predictive band; the report passes {}–{} %.",
        r.prediction.record.draws,
        r.prediction.record.thin,
        r.prediction.record.noise_replicates,
        100.0 * COVERAGE_OK.0,
        100.0 * COVERAGE_OK.1
    ));
    coverage_table(page, &r.prediction.coverage, false);
}

fn validation_section(page: &mut Page, r: &CalibrationReport, loo_figs: &Figures) -> Result<()> {
    page.section("validation", "Leave-one-out validation");
    match r.loo {
        Some(LeaveOneOut { rows, .. }) => {
            page.para("Each run predicted by the posterior of the other runs of this calibration only (its noise level taken as the root-mean-square σ of those runs): the honest test of the bands on data the fit has not seen. That posterior is reached by the cheapest way that can be trusted: the full posterior's draws reweighted by Pareto-smoothed importance sampling where the Pareto k̂ of the weights is at most 0.7; else importance sampling from the Laplace approximation of the held-out posterior, if its k̂ is at most 0.7; else ensemble MCMC of the held-out posterior. The log predictive density (mean over the run's samples of ln p(τ_obs | other runs)) scores the held-out prediction as a whole: compare it between model variants (terms, noise models) on the same records; higher is better.");
            let coverage: Vec<CoverageRow> =
                rows.iter().filter(|r| r.failure.is_none()).map(|r| r.coverage.clone()).collect();
            coverage_table(page, &coverage, true);
            let how: Vec<Vec<String>> = rows
                .iter()
                .map(|r| {
                    let or_dash = |v: f64, digits: usize| if v.is_finite() { format!("{v:.digits$}") } else { "–".into() };
                    vec![
                        esc(&r.coverage.run),
                        or_dash(r.coverage.lppd / r.coverage.samples.max(1) as f64, 3),
                        or_dash(r.pareto_k, 2),
                        or_dash(r.pareto_k_laplace, 2),
                        r.by.label().into(),
                        r.rhat_shown(),
                    ]
                })
                .collect();
            page.table(&["held out", "log predictive density per sample (nat)", "Pareto k̂ (reweighting)", "Pareto k̂ (Laplace)", "held-out posterior by", "largest R̂"], &how);
            for r in rows {
                if let Some(why) = &r.failure {
                    page.para(&format!("{} could not be held out ({}): it has no held-out bands and no numbers above; the other runs were held out as usual.", r.coverage.run, why));
                }
                if let Some(why) = &r.tempered_instead {
                    page.para(&format!("{} was held out under the tempered likelihood, as `memory = \"auto\"` takes it for a calibration of the runs kept: {}.", r.coverage.run, why));
                }
            }
            if let Some(warning) = super::text::refits_unsettled(rows) {
                page.para(&format!("Not converged: {warning}."));
            }
            for (stem, caption) in &loo_figs.items {
                page.figure(&r.cal.dir.join("loo").join(format!("{stem}.png")), &format!("Held out: {caption}"))?;
            }
        }
        None => page.para("Not run for this calibration: `mrbp run MANIFEST --out DIR --leave-one-out` runs it (the bundled job does)."),
    }
    Ok(())
}

fn consistency_section(page: &mut Page, r: &CalibrationReport) -> Result<()> {
    page.section("consistency", "Consistency across runs");
    let Some(parameters) = r.consistency.filter(|p| !p.is_empty()) else {
        page.para("Not run for this calibration: `mrbp run MANIFEST --out DIR --per-run --leave-one-out` also calibrates each run alone, compares them here, and fits the between-run layer, whose intervals and bands hold for a new test of the damper (every current of the campaign at once: it learns how tests differ from all of them).");
        return Ok(());
    };
    page.para(&format!(
        "Each run calibrated alone, beside the joint calibration. For each parameter, χ²/ν of the run-wise posterior means of ln θ about their precision-weighted mean, with their own sds (ν = runs − 1): about 1 when one parameter set describes every run and the intervals are honest; the runs are said to disagree when its p-value is below {}. Where they disagree, the joint interval describes these records, not a new test. The between-run layer takes each test as a draw from a population of tests of this damper: each current its own centre, one between-test covariance learned from every run calibrated alone at every current (docs/calibration.md); its interval for a new test is the one to quote, and its spread is how much one test's parameter differs from the next (a factor, 1 sd).",
        crate::validate::consistency::DISAGREE_P
    ));
    let rows: Vec<Vec<String>> = parameters
        .iter()
        .map(|p| {
            let interval = |e: &crate::validate::consistency::Estimate| {
                format!("{} – {}", num(e.q05, 4), num(e.q95, 4))
            };
            vec![
                esc(&p.parameter),
                format!("{:.2}", p.chi2_nu),
                format!("{:.1e}", p.p_value),
                Mark::of(!p.disagrees()).html().into(),
                interval(&p.joint),
                interval(&p.new_test),
                p.spread_shown(),
            ]
        })
        .collect();
    page.table(
        &["parameter", "χ²/ν", "p", "", "joint 90 %", "new test 90 %", "spread between tests"],
        &rows,
    );
    for p in parameters.iter().filter(|p| p.disagrees()) {
        page.note(&p.verdict());
    }
    if let Some(rows) = r.new_test_loo {
        new_test_table(page, rows, r.loo);
    }
    let mut figs = Figures::default();
    figures::consistency(&r.cal.dir, parameters, &mut figs)?;
    for (stem, caption) in &figs.items {
        page.figure(&r.cal.dir.join(format!("{stem}.png")), caption)?;
    }
    Ok(())
}

/// Each run held out and predicted as a new test by the between-run layer,
/// beside its prediction by the joint calibration of the other runs; then
/// each run predicted from the other currents alone.
fn new_test_table(page: &mut Page, rows: &[NewTestRow], loo: Option<&LeaveOneOut>) {
    page.para("Each run predicted as a new test of this damper: the between-run layer fitted to every other run calibrated alone, at every current, draws the run's parameters and noise, which the integrator carries along its record. Beside it, where the leave-one-out study was run, the same run predicted by the joint calibration of the other runs at its current. Pooled over many tests, a right band for a new test holds about 95 % of the samples; one test is inside nearly everywhere or, if its parameters lie in the population's tails, outside over much of its record, since tests differ by more than the noise. So a run near 100 % is a typical test, a run far below is unlike the others, and the pooled share under the tables judges the band (docs/calibration.md); the log predictive density per sample scores sharpness and honesty together (higher is better).");
    let per_sample = |c: &CoverageRow| c.lppd / c.samples.max(1) as f64;
    let joint = |run: &str| {
        loo.and_then(|l| l.rows.iter().find(|r| r.coverage.run == run && r.failure.is_none()))
            .map(|r| &r.coverage)
    };
    let table: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.left_out == LeftOut::Run)
        .map(|r| {
            let c = &r.coverage;
            let j = joint(&c.run);
            vec![
                esc(&c.run),
                format!("{:.1}", 100.0 * c.inside_p95),
                j.map_or("–".into(), |j| format!("{:.1}", 100.0 * j.inside_p95)),
                format!("{:.0}", c.rmse_q50_pa),
                j.map_or("–".into(), |j| format!("{:.0}", j.rmse_q50_pa)),
                format!("{:.3}", per_sample(c)),
                j.map_or("–".into(), |j| format!("{:.3}", per_sample(j))),
                Mark::of(c.inside_p95 >= 0.9).html().into(),
            ]
        })
        .collect();
    page.table(
        &[
            "held out", "new test: inside 95 % (%)", "joint: inside 95 % (%)",
            "new test: RMS to median (Pa)", "joint: RMS to median (Pa)",
            "new test: lppd per sample", "joint: lppd per sample", "",
        ],
        &table,
    );
    let by_current: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.left_out == LeftOut::Current)
        .map(|r| {
            let c = &r.coverage;
            vec![
                esc(&c.run),
                format!("{:.1}", 100.0 * c.inside_p95),
                format!("{:.1}", 100.0 * c.inside_q95),
                format!("{:.0}", c.rmse_q50_pa),
                format!("{:.3}", per_sample(c)),
                Mark::of(c.inside_p95 >= 0.85).html().into(),
            ]
        })
        .collect();
    if !by_current.is_empty() {
        page.para("A current the layer never saw: every run at this current left out, the layer fitted to the runs at the other currents, its centre here read off its curve in the current (docs/calibration.md), and each run predicted as a new test there.");
        page.table(
            &[
                "held out with its current", "inside 95 % (%)", "inside model band (%)",
                "RMS to median (Pa)", "lppd per sample", "",
            ],
            &by_current,
        );
    }
    let pooled = super::text::new_test_pooled(rows);
    if !pooled.is_empty() {
        page.para(&format!("Pooled: {}.", pooled.join("; ")));
    }
    if let Some(warning) = super::text::new_tests_unsettled(rows) {
        page.para(&format!("Not converged: {warning}."));
    }
    if let Some(warning) = super::text::new_tests_unfit(rows) {
        page.para(&format!("Not a band: {warning}."));
    }
    if let Some(warning) = super::text::new_tests_too_wide(rows) {
        page.para(&format!("Wider than the force: {warning}."));
    }
}

fn figures_section(page: &mut Page, cal: &Calibration, figs: &Figures) -> Result<()> {
    page.section("figures", "Figures");
    for (stem, caption) in &figs.items {
        page.figure(&cal.dir.join(format!("{stem}.png")), caption)?;
    }
    let tag = current_tag(cal.record.current_a);
    let ident = [
        (
            "fig1_tau_gamma",
            "Identification, Fig. 1: the loading branches used by the identification.",
        ),
        (
            "fig2_yield_rate",
            "Identification, Fig. 2: yield stress against inelastic strain rate (eq. 6).",
        ),
        ("fig3_tau_gamma_i", "Identification, Fig. 3: stress against inelastic strain with eq. 7."),
        (
            "fig4_euler",
            "Identification, Fig. 4: Euler solution of the identified model against the records.",
        ),
        ("fig5_psi", "Identification, Fig. 5: the hardening function ψ."),
    ];
    for (stem, caption) in ident {
        let png = cal.dir.join(format!("{stem}_{tag}.png"));
        if png.exists() {
            page.figure(&png, caption)?;
        }
    }
    Ok(())
}

fn reproduce_section(page: &mut Page, r: &CalibrationReport) {
    let (rec, prediction) = (&r.cal.record, &r.prediction.record);
    page.section("reproduce", "Reproduce");
    page.table(
        &["", ""],
        &[
            vec!["mrbp version".into(), esc(&rec.mrbp_version)],
            vec!["calibration command".into(), format!("<code>{}</code>", esc(&rec.command))],
            vec!["prediction command".into(), format!("<code>{}</code>", esc(&prediction.command))],
            vec!["sampler seed".into(), rec.seed.to_string()],
            vec!["prediction seed".into(), prediction.seed.to_string()],
            vec![
                "wall time".into(),
                format!(
                    "{:.1} s calibration ({:.1} s sampling), {:.1} s prediction",
                    rec.seconds_start + rec.seconds_sampling,
                    rec.seconds_sampling,
                    prediction.seconds
                ),
            ],
        ],
    );
    page.para("The settings below (config.toml in the folder) repeat the calibration with `mrbp sample MANIFEST --config config.toml --out DIR`; the same seed gives the same chains bit for bit, on any number of threads.");
    let config =
        std::fs::read_to_string(r.cal.dir.join(crate::store::folder::CONFIG)).unwrap_or_default();
    page.pre(&config);
}

/// Whether a run's band holds what it should: 90–99 % of a run the
/// calibration saw or a held-out run of its own current (leave-one-out),
/// at least [`HELD_OUT_OK`] of a run at a current it never saw.
fn coverage_ok(r: &CoverageRow, same_current: bool) -> bool {
    if r.calibrated || same_current {
        r.inside_p95 >= COVERAGE_OK.0 && r.inside_p95 <= COVERAGE_OK.1
    } else {
        r.inside_p95 >= HELD_OUT_OK
    }
}

pub(super) fn coverage_table(page: &mut Page, rows: &[CoverageRow], leave_one_out: bool) {
    let rows: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            vec![
                if r.calibrated || leave_one_out {
                    esc(&r.run)
                } else {
                    format!("{} <b>(held out)</b>", esc(&r.run))
                },
                num(r.current_a, 2),
                r.samples.to_string(),
                format!("{:.1}", 100.0 * r.inside_p95),
                format!("{:.1}", 100.0 * r.inside_q95),
                num(r.rmse_q50_pa, 3),
                r.draws.to_string(),
                Mark::of(coverage_ok(r, leave_one_out)).html().into(),
            ]
        })
        .collect();
    page.table(
        &[
            "run", "current (A)", "samples", "inside 95 % predictive (%)", "inside 95 % model (%)",
            "RMS residual to median (Pa)", "draws", "",
        ],
        &rows,
    );
}

/// The report's checks: what, verdict, what was measured.
fn verdicts(cal: &Calibration, coverage: &[CoverageRow]) -> Vec<(String, Mark, String)> {
    let s = &cal.summary;
    let max_rhat = cal.max_rhat();
    let min_bulk = s.iter().map(|r| r.ess_bulk).fold(f64::NAN, f64::min);
    let min_tail = s.iter().map(|r| r.ess_tail).fold(f64::NAN, f64::min);
    let tau = cal.tau_max();
    // draws 0..=steps are kept from the burn-in on, as the sampler counts them
    let kept = (cal.record.steps + 1).saturating_sub(cal.record.burn_in) as f64;
    let min_ess = cal.settings.sampler.min_ess;
    let mut v = vec![
        (
            "R̂ (rank-normalised split, across ensembles) < 1.01".to_string(),
            Mark::of(max_rhat < 1.01),
            format!("largest {max_rhat:.4}"),
        ),
        (
            format!("bulk and tail ESS ≥ {min_ess:.0}"),
            Mark::of(min_bulk >= min_ess && min_tail >= min_ess),
            format!("smallest bulk {min_bulk:.0}, tail {min_tail:.0}"),
        ),
        (
            format!("chains longer than {MIN_TAU_MULTIPLE} τ after burn-in"),
            Mark::of(kept >= MIN_TAU_MULTIPLE * tau),
            format!("{kept:.0} steps, τ_max {tau:.2} ({:.1} τ)", kept / tau),
        ),
        (
            "no sampler warnings (draws that still drift, stuck walkers …)".to_string(),
            Mark::of(cal.record.warnings.is_empty()),
            format!("{} warning(s)", cal.record.warnings.len()),
        ),
        (
            "residuals as independent as the noise model assumes (MAP lag-1 autocorrelation ≤ 0.5)"
                .to_string(),
            Mark::of(cal.record.model_warnings.is_empty()),
            format!("{} run(s) with memory: see Model adequacy", cal.record.runs_with_memory()),
        ),
    ];
    if cal.settings.likelihood.noise.model(&Default::default()).models_memory() {
        v.push((
            format!("the noise's own force does not take over the law's (law-path RMS at the posterior median, all runs together, ≤ {CONFOUNDING_RATIO}× the law alone's)"),
            Mark::of(cal.record.confounding.is_empty()),
            if cal.record.confounding.is_empty() { "within it".to_string() } else { "see the warning below".to_string() },
        ));
    }
    if let Some(last) = cal.record.step_study.last() {
        let limit = step_shift_limit(cal.settings.integrator.extrapolate);
        v.push((
            "integrator step: halving it moves no MAP parameter by the limit".to_string(),
            Mark::of(last.largest_shift_sd < limit),
            format!(
                "{} sub-step(s): {:.3} sd ({}), limit {limit:.3}",
                last.substeps, last.largest_shift_sd, last.parameter
            ),
        ));
    }
    for r in coverage.iter().filter(|r| !r.calibrated) {
        v.push((
            format!(
                "{} (held out): 95 % predictive band holds ≥ {:.0} % of the record",
                r.run,
                100.0 * HELD_OUT_OK
            ),
            Mark::of(coverage_ok(r, false) && r.failed_draws == 0),
            format!("{:.1} %, {} failed draw(s)", 100.0 * r.inside_p95, r.failed_draws),
        ));
    }
    for r in coverage.iter().filter(|r| r.calibrated) {
        v.push((
            format!(
                "{}: 95 % predictive band holds {:.0}–{:.0} % of the record",
                r.run,
                100.0 * COVERAGE_OK.0,
                100.0 * COVERAGE_OK.1
            ),
            Mark::of(coverage_ok(r, false) && r.failed_draws == 0),
            format!("{:.1} %, {} failed draw(s)", 100.0 * r.inside_p95, r.failed_draws),
        ));
    }
    v
}
