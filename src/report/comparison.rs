//! `mrbp compare`: tables, figures and one HTML report over several
//! calibration folders (current levels, dampers, settings, a current law).

use std::path::{Path, PathBuf};

use super::figures::{AtCurrent, Figures, LawCurves};
use super::html::{esc, num, Mark, Page};
use crate::atomic;
use crate::calibrate::evidence::Estimate;
use crate::calibrate::Calibration;
use crate::compare::{self, Comparison, CurrentRow};
use crate::data::{loading_branches, REVERSAL_SHARE};
use crate::error::Result;
use crate::plot::{self, Chart, Figure, LegendAt, Series, PALETTE};
use crate::posterior::unit_of;
use crate::predict::adequacy::{AdequacyRow, Excitation};
use crate::predict::{Prediction, RunBands};
use crate::store::command_line;
use crate::validate::between_runs::TypicalRow;

/// One calibration in a comparison: its folder, the draws compared, and
/// its bands and coverage where they were computed.
pub struct Entry {
    pub label: String,
    pub cal: Calibration,
    pub positions: Vec<(usize, usize)>,
    /// Its bands, coverage and adequacy, where they were computed.
    pub prediction: Option<Prediction>,
    /// Its log evidence: sequential Monte Carlo's where it was sampled so,
    /// else by bridge sampling where another calibration of the comparison
    /// is of the same runs (the only evidences that compare).
    pub evidence: Option<Estimate>,
}

impl Entry {
    fn is_law(&self) -> bool {
        self.cal.is_current_law()
    }
}

/// The crank speed of a record (rpm) from its loading branches: each is
/// half a revolution.
fn rpm_of(time: &[f64], displacement: &[f64]) -> f64 {
    let branches = loading_branches(displacement, REVERSAL_SHARE);
    let mut half: Vec<f64> = branches
        .iter()
        .take(branches.len().saturating_sub(1).max(1))
        .map(|b| time[b.end.saturating_sub(1).max(b.start)] - time[b.start])
        .filter(|d| *d > 0.0)
        .collect();
    if half.is_empty() {
        return f64::NAN;
    }
    half.sort_by(f64::total_cmp);
    60.0 / (2.0 * half[half.len() / 2])
}

/// Writes the figures and `report.html` of the comparison of `entries`
/// (whose tables are `comparison`) into `out`. `rpm` picks the runs whose
/// bands are overlaid.
/// `typical`: the between-run layer's typical test against the current,
/// where the folders hold one (`--per-run`).
pub fn write(
    out: &Path,
    entries: &[Entry],
    comparison: &Comparison,
    rpm: Option<f64>,
    typical: Option<&[TypicalRow]>,
) -> Result<PathBuf> {
    atomic::remove(&out.join(super::html::REPORT))?;
    let mut figs = Figures::default();
    forest(out, entries, &mut figs)?;
    against_current(out, entries, typical, &mut figs)?;
    overlay(out, entries, rpm, &mut figs)?;
    held_out_figures(out, entries, &mut figs)?;

    let mut page = Page::new(&format!("mrbp comparison of {} calibrations", entries.len()));
    for e in entries {
        page.derived_from(&e.cal.record.calibration_id);
    }
    calibrations_section(&mut page, entries);
    parameters_section(&mut page, entries);
    differences_section(&mut page, comparison);
    typical_test_section(&mut page, comparison);
    adequacy_section(&mut page, entries);
    page.section("current-law", "Current law and held-out currents");
    law_section(&mut page, entries);
    for (stem, caption) in figs.items.iter().filter(|f| f.0.starts_with("held_out")) {
        page.figure(&out.join(format!("{stem}.png")), caption)?;
    }
    page.section("figures", "Figures");
    for (stem, caption) in figs.items.iter().filter(|f| !f.0.starts_with("held_out")) {
        page.figure(&out.join(format!("{stem}.png")), caption)?;
    }
    reproduce_section(&mut page, entries);
    let path = out.join(super::html::REPORT);
    atomic::write(&path, page.finish().as_bytes())?;
    Ok(path)
}

fn calibrations_section(page: &mut Page, entries: &[Entry]) {
    page.section("calibrations", "Calibrations");
    let mut rows_html: Vec<Vec<String>> = entries
        .iter()
        .map(|e| {
            let (rhat, ess) = (e.cal.max_rhat(), e.cal.min_ess());
            // every warning of the calibration counts, not only R̂ and ESS
            let warnings: Vec<&String> = e
                .cal
                .record
                .warnings
                .iter()
                .chain(&e.cal.record.model_warnings)
                .chain(&e.cal.record.confounding)
                .collect();
            let pass = rhat < 1.01
                && ess >= e.cal.settings.sampler.min_ess
                && e.cal.record.warnings.is_empty();
            let verdict = if warnings.is_empty() {
                Mark::of(pass).html().to_string()
            } else {
                format!(
                    "{} {}",
                    Mark::of(pass).html(),
                    warnings.iter().map(|w| esc(w)).collect::<Vec<_>>().join("; ")
                )
            };
            vec![
                esc(&e.label),
                if e.is_law() { "current law".into() } else { "per current".into() },
                if e.is_law() {
                    format!("{:?}", e.cal.record.currents)
                } else {
                    num(e.cal.record.current_a, 2)
                },
                esc(&e.cal.record.runs.join(", ")),
                format!("{rhat:.4}"),
                format!("{ess:.0}"),
                verdict,
            ]
        })
        .collect();
    let mut header = vec![
        "calibration", "model", "current (A)", "runs", "max R̂", "min ESS", "converged; warnings",
    ];
    if entries.iter().any(|e| e.evidence.is_some()) {
        header.insert(6, "log evidence");
        for (row, e) in rows_html.iter_mut().zip(entries) {
            let shown = e.evidence.as_ref().map_or("–".to_string(), |ev| {
                let pseudo = if ev.pseudo { " (pseudo)" } else { "" };
                let by = if ev.by == crate::calibrate::evidence::BRIDGE { " b" } else { "" };
                format!("{:.2} ± {:.2}{by}{pseudo}", ev.log_evidence, ev.se)
            });
            row.insert(6, shown);
        }
        for line in bayes_factors(entries) {
            page.para(&line);
        }
    }
    page.table(&header, &rows_html);
}

/// A sentence for each pair of calibrations that calibrate the same runs
/// with evidences of their records' own likelihood: the log Bayes factor
/// between them. Evidences of different records, or pseudo-evidences of a
/// likelihood adjusted or tempered for the residuals' memory, do not
/// compare, and the sentence says why.
fn bayes_factors(entries: &[Entry]) -> Vec<String> {
    let mut out = vec!["Log evidence: ln p(records | law, priors, noise model) ± its standard error, by sequential Monte Carlo where a calibration was sampled so (`--sampler smc`), else by bridge sampling from its chains (marked b; computed where another calibration here is of the same runs). Two calibrations' evidences compare only where they calibrate the same runs, each with its records' own likelihood; their difference is then the log Bayes factor.".to_string()];
    for (i, a) in entries.iter().enumerate() {
        for b in &entries[i + 1..] {
            let (Some(ea), Some(eb)) = (&a.evidence, &b.evidence) else { continue };
            if a.cal.record.runs != b.cal.record.runs {
                continue;
            }
            if ea.pseudo || eb.pseudo {
                out.push(format!("{} and {} calibrate the same runs, but at least one evidence is of a likelihood that allowed for the residuals' memory (a pseudo-evidence): they do not compare.", esc(&a.label), esc(&b.label)));
                continue;
            }
            let d = ea.log_evidence - eb.log_evidence;
            let se = ea.se.hypot(eb.se);
            let (hi, lo) = if d >= 0.0 { (a, b) } else { (b, a) };
            out.push(format!(
                "{} over {} (the same runs): log Bayes factor {:.2} ± {:.2}.",
                esc(&hi.label),
                esc(&lo.label),
                d.abs(),
                se
            ));
        }
    }
    out
}

fn parameters_section(page: &mut Page, entries: &[Entry]) {
    page.section("parameters", "Parameters");
    page.para("Posterior median and 90 % credible interval of each law parameter (SI units; – where a calibration's law has no such parameter). In a current law, R0, R1 and D1 are the values at its reference current.");
    let mut header = vec!["parameter".to_string()];
    header.extend(entries.iter().map(|e| e.label.clone()));
    let mut names: Vec<String> = Vec::new();
    for e in entries {
        for n in e.cal.sample.layout.theta_names() {
            if !names.contains(n) {
                names.push(n.clone());
            }
        }
    }
    let table: Vec<Vec<String>> = names
        .iter()
        .map(|n| {
            let mut row = vec![esc(n)];
            for e in entries {
                row.push(match e.cal.summary.iter().find(|r| &r.parameter == n) {
                    Some(r) => format!("{} [{}, {}]", num(r.q50, 3), num(r.q05, 3), num(r.q95, 3)),
                    None => "–".into(),
                });
            }
            row
        })
        .collect();
    page.table(&header.iter().map(String::as_str).collect::<Vec<_>>(), &table);
}

fn differences_section(page: &mut Page, comparison: &Comparison) {
    page.section("differences", "Differences");
    page.para("For each pair a, b and each parameter both have: the 90 % interval of a − b and of a / b, and P(a > b). Probabilities beyond 0.99 or below 0.01 (bold) mean the records tell the two apart. Two calibrations are independent posteriors; a law's rows (\"LAW at I A\") compare its B-P parameters at two currents within its one posterior, draw by draw — what the law says about how the damper changes with the current.");
    let table: Vec<Vec<String>> = comparison
        .differences
        .iter()
        .map(|r| {
            let d = &r.difference;
            let sure = d.p_greater > 0.99 || d.p_greater < 0.01;
            let pg = format!("{:.3}", d.p_greater);
            vec![
                esc(&r.a),
                esc(&r.b),
                esc(&r.parameter),
                format!("{} [{}, {}]", num(d.diff_q50, 3), num(d.diff_q05, 3), num(d.diff_q95, 3)),
                format!(
                    "{} [{}, {}]",
                    num(d.ratio_q50, 3),
                    num(d.ratio_q05, 3),
                    num(d.ratio_q95, 3)
                ),
                if sure { format!("<b>{pg}</b>") } else { pg },
            ]
        })
        .collect();
    page.table(
        &[
            "a", "b", "parameter", "a − b: median [5 %, 95 %]", "a / b: median [5 %, 95 %]",
            "P(a > b)",
        ],
        &table,
    );
}

/// P(a > b) between currents by the joint calibrations beside the same by
/// the between-run layer's centres, where the folders hold one fit.
fn typical_test_section(page: &mut Page, comparison: &Comparison) {
    let layer: Vec<&compare::DifferenceRow> =
        comparison.differences.iter().filter(|r| r.a.ends_with(compare::TYPICAL_TEST)).collect();
    if layer.is_empty() {
        return;
    }
    page.para("Between currents for a typical test: the between-run layer's centres (each current's typical test of this damper, `--per-run`), compared draw by draw within its one posterior, beside the joint calibrations' comparison. Where the tests of a current disagree, the joint calibrations' P(a > b) rests on intervals that describe these records only; the layer's says how sure one may be that the damper itself differs between the currents.");
    let joint = |a: &str, b: &str, p: &str| {
        comparison
            .differences
            .iter()
            .find(|r| r.a == a && r.b == b && r.parameter == p)
            .map(|r| r.difference.p_greater)
    };
    let table: Vec<Vec<String>> = layer
        .iter()
        .map(|r| {
            let (a, b) = (
                r.a.trim_end_matches(compare::TYPICAL_TEST),
                r.b.trim_end_matches(compare::TYPICAL_TEST),
            );
            let d = &r.difference;
            vec![
                esc(a),
                esc(b),
                esc(&r.parameter),
                joint(a, b, &r.parameter).map_or("–".into(), |p| format!("{p:.3}")),
                format!("{:.3}", d.p_greater),
                format!(
                    "{} [{}, {}]",
                    num(d.ratio_q50, 3),
                    num(d.ratio_q05, 3),
                    num(d.ratio_q95, 3)
                ),
            ]
        })
        .collect();
    page.table(
        &[
            "a",
            "b",
            "parameter",
            "P(a > b), joint",
            "P(a > b), typical test",
            "a / b, typical test: median [5 %, 95 %]",
        ],
        &table,
    );
}

fn reproduce_section(page: &mut Page, entries: &[Entry]) {
    page.section("reproduce", "Reproduce");
    let mut rows_html =
        vec![vec!["command".to_string(), format!("<code>{}</code>", esc(&command_line()))]];
    rows_html.push(vec!["mrbp version".into(), esc(env!("CARGO_PKG_VERSION"))]);
    for e in entries {
        rows_html.push(vec![
            esc(&e.label),
            format!("<code>{}</code> (seed {})", esc(&e.cal.record.command), e.cal.record.seed),
        ]);
    }
    page.table(&["", ""], &rows_html);
}

/// The held-out runs of current-law calibrations against the per-current
/// calibrations of the same runs: coverage and RMS error.
fn law_section(page: &mut Page, entries: &[Entry]) {
    let laws: Vec<&Entry> = entries.iter().filter(|e| e.is_law()).collect();
    if laws.is_empty() {
        page.para("No current-law calibration among these folders: `mrbp sample MANIFEST --model current-law [--hold-out-current I]` makes one (the bundled job does).");
        return;
    }
    for law in laws {
        let Some(cov) = law.prediction.as_ref().map(|p| &p.coverage) else {
            page.para(&format!("{}: no bands yet (run `mrbp predict` on it).", law.label));
            continue;
        };
        page.para(&format!(
            "{}: the current law calibrated on the runs at {:?} A. Runs it did not see are predicted at their current; the per-current calibration of the same runs saw them (in-sample), so it is the best that seven free parameters per current can do.",
            law.label, law.cal.record.currents
        ));
        let mut table = Vec::new();
        for r in cov {
            let per_current = entries.iter().filter(|e| !e.is_law()).find_map(|e| {
                e.prediction
                    .as_ref()
                    .and_then(|p| p.coverage.iter().find(|x| x.run == r.run))
                    .map(|x| (e.label.clone(), x.clone()))
            });
            let ok = r.inside_p95 >= 0.8;
            table.push(vec![
                esc(&r.run),
                num(r.current_a, 2),
                if r.calibrated { "calibrated on".into() } else { "<b>held out</b>".into() },
                format!("{:.1}", 100.0 * r.inside_p95),
                num(r.rmse_q50_pa, 3),
                per_current.as_ref().map_or("–".into(), |(l, x)| {
                    format!("{:.1} ({})", 100.0 * x.inside_p95, esc(l))
                }),
                per_current.as_ref().map_or("–".into(), |(_, x)| num(x.rmse_q50_pa, 3)),
                if r.calibrated { String::new() } else { Mark::of(ok).html().into() },
            ]);
        }
        page.table(
            &[
                "run", "current (A)", "law", "law: inside 95 % (%)", "law: RMS to median (Pa)",
                "per-current: inside 95 % (%)", "per-current: RMS (Pa)", "held out ≥ 80 %",
            ],
            &table,
        );
    }
}

/// Excitations closer than this in amplitude and frequency (relative) are
/// the same test at different currents.
const SAME_EXCITATION: f64 = 0.1;

/// The misfit of every per-current calibration, as a matrix of excitation
/// (rows) by current (columns): where across the test programme the law
/// describes the damper and where it does not.
fn adequacy_section(page: &mut Page, entries: &[Entry]) {
    let mut cells: Vec<(f64, AdequacyRow)> = Vec::new();
    for e in entries.iter().filter(|e| !e.is_law()) {
        if let Some(p) = &e.prediction {
            cells.extend(p.adequacy.iter().map(|a| (e.cal.record.current_a, a.clone())));
        }
    }
    if cells.is_empty() {
        return;
    }
    page.section("adequacy", "Model adequacy by excitation and current");
    page.para(
        "Each cell: the residual force RMS as a share of the peak force, the lag-1 autocorrelation of the residual, and the share of the \
         record inside the 95 % predictive band — for the run of that excitation at that current. Each calibration's own report says more.",
    );
    let close = |a: f64, b: f64| (a - b).abs() <= SAME_EXCITATION * a.abs().max(b.abs());
    let mut groups: Vec<Excitation> = Vec::new();
    for (_, a) in &cells {
        let e = a.excitation;
        if !groups.iter().any(|g| {
            close(g.amplitude_m, e.amplitude_m)
                && (close(g.frequency_hz, e.frequency_hz)
                    || !(g.frequency_hz.is_finite() || e.frequency_hz.is_finite()))
        }) {
            groups.push(e);
        }
    }
    groups.sort_by(|a, b| {
        a.frequency_hz.total_cmp(&b.frequency_hz).then(b.amplitude_m.total_cmp(&a.amplitude_m))
    });
    let mut currents: Vec<f64> = cells.iter().map(|c| c.0).collect();
    currents.sort_by(f64::total_cmp);
    currents.dedup();
    let rows: Vec<Vec<String>> = groups
        .iter()
        .map(|g| {
            let mut row = vec![esc(&g.label())];
            for &c in &currents {
                let found = cells.iter().find(|(cur, a)| {
                    *cur == c
                        && close(g.amplitude_m, a.excitation.amplitude_m)
                        && (close(g.frequency_hz, a.excitation.frequency_hz)
                            || !g.frequency_hz.is_finite())
                });
                row.push(found.map_or("–".into(), |(_, a)| {
                    format!(
                        "{:.1} % · ρ {:.2} · {:.0} %",
                        100.0 * a.residual_rms_n / a.peak_force_n,
                        a.lag1_autocorrelation,
                        100.0 * a.inside_p95
                    )
                }));
            }
            row
        })
        .collect();
    let header: Vec<String> = std::iter::once("excitation".to_string())
        .chain(currents.iter().map(|c| format!("{} A", num(*c, 2))))
        .collect();
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    page.table(&header, &rows);
}

/// The parameters of the damper laws of `entries`, each once, in the
/// order of the first law that has it.
fn law_parameters(entries: &[Entry]) -> Vec<&'static str> {
    let mut names: Vec<&'static str> = Vec::new();
    for e in entries {
        for name in e.cal.settings.parameter_model().law().law().names() {
            if !names.contains(&name) {
                names.push(name);
            }
        }
    }
    names
}

/// A forest plot per parameter of the damper laws: each calibration's
/// median and 90 % interval, one row per calibration, named on the y axis.
fn forest(out: &Path, entries: &[Entry], figs: &mut Figures) -> Result<()> {
    let labels: Vec<String> = entries.iter().map(|e| e.label.clone()).collect();
    let mut panels = Vec::new();
    for name in law_parameters(entries) {
        let mut c = Chart::new(name, format!("{name} ({})", unit_of(name)), "");
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (k, e) in entries.iter().enumerate() {
            if let Some(r) = e.cal.summary.iter().find(|r| r.parameter == name) {
                let y = (entries.len() - k) as f64;
                let color = PALETTE[k % 8];
                c.series
                    .push(Series::line(None, color, vec![r.q05, r.q95], vec![y, y]).with_width(3));
                c.series.push(Series::points(None, color, vec![r.q50], vec![y]).with_width(5));
                (lo, hi) = (lo.min(r.q05), hi.max(r.q95));
            }
        }
        if lo < hi {
            let pad = 0.12 * (hi - lo);
            c.x_range = Some((lo - pad, hi + pad));
        }
        c.y_range = Some((0.4, entries.len() as f64 + 0.6));
        // row k from the top is at y = n − k
        c.y_names = Some(labels.iter().rev().cloned().collect());
        c.legend = false;
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &out.join("forest"))?;
    figs.push("forest", "Forest plot: median (dot) and 90 % credible interval (bar) of each parameter in each calibration, named on the left.");
    Ok(())
}

/// Each parameter of the damper laws against the coil current: every
/// current law's band beside
/// the per-current calibrations, and the between-run layer's typical test
/// and new test where there is one.
fn against_current(
    out: &Path,
    entries: &[Entry],
    typical: Option<&[TypicalRow]>,
    figs: &mut Figures,
) -> Result<()> {
    let names = law_parameters(entries);
    let laws: Vec<(&Entry, Vec<CurrentRow>)> = entries
        .iter()
        .filter(|e| e.is_law())
        .map(|e| (e, compare::against_current(&e.cal.sample, &e.positions, &e.cal.record.currents)))
        .collect();
    let mut curves: Vec<LawCurves> = laws
        .iter()
        .map(|(e, rows)| LawCurves {
            label: &e.label,
            rows,
            calibrated_a: &e.cal.record.currents,
            color: None,
        })
        .collect();
    // the layer's two bands, as a law's rows (quantiles only)
    let as_rows = |pick: fn(&TypicalRow) -> [f64; 3]| -> Vec<CurrentRow> {
        typical
            .unwrap_or_default()
            .iter()
            .map(|r| {
                let [q05, q50, q95] = pick(r);
                CurrentRow {
                    parameter: r.parameter.clone(),
                    current_a: r.current_a,
                    kind: r.kind,
                    mean: f64::NAN,
                    sd: f64::NAN,
                    q05,
                    q50,
                    q95,
                }
            })
            .collect()
    };
    let (centre, new_test) = (as_rows(|r| r.centre), as_rows(|r| r.new_test));
    let calibrated: Vec<f64> = centre
        .iter()
        .filter(|r| r.kind == compare::CurrentKind::Calibrated && r.parameter == names[0])
        .map(|r| r.current_a)
        .collect();
    if typical.is_some() {
        curves.push(LawCurves {
            label: "a new test (between-run layer)",
            rows: &new_test,
            calibrated_a: &calibrated,
            color: Some(PALETTE[3]),
        });
        curves.push(LawCurves {
            label: "typical test (between-run layer)",
            rows: &centre,
            calibrated_a: &calibrated,
            color: Some(PALETTE[2]),
        });
    }
    let per_current: Vec<AtCurrent> = entries
        .iter()
        .filter(|e| !e.is_law())
        .map(|e| AtCurrent {
            current_a: e.cal.record.current_a,
            quantiles: names
                .iter()
                .map(|name| {
                    e.cal
                        .summary
                        .iter()
                        .find(|r| r.parameter == *name)
                        .map(|r| [r.q05, r.q50, r.q95])
                })
                .collect(),
        })
        .collect();
    let mut more = String::new();
    if !laws.is_empty() {
        more.push_str(" A law's values are in against_current.parquet of its folder.");
    }
    if typical.is_some() {
        more.push_str(" The between-run layer (each run calibrated alone, --per-run): a typical test of this damper (the layer's centre, green) and a new test (centre and between-test spread, purple), read off its curve in the current between and beyond the calibrated currents; the values are in typical_test.parquet of each current's folder.");
    }
    super::figures::against_current(out, &names, &curves, &per_current, &more, figs)
}

/// The predictive bands of every per-current calibration at one crank
/// speed, over one another (τ against time over the first revolution).
fn overlay(out: &Path, entries: &[Entry], rpm: Option<f64>, figs: &mut Figures) -> Result<()> {
    // every record of the per-current calibrations with its crank speed
    let records: Vec<(&Entry, Vec<(&RunBands, f64)>)> = entries
        .iter()
        .filter(|e| !e.is_law())
        .filter_map(|e| {
            e.prediction.as_ref().map(|p| {
                (e, p.bands.iter().map(|b| (b, rpm_of(&b.time, &b.displacement))).collect())
            })
        })
        .collect();
    let mut speeds: Vec<f64> = records
        .iter()
        .flat_map(|(_, r)| r.iter().map(|(_, v)| *v))
        .filter(|v| v.is_finite())
        .collect();
    if speeds.is_empty() {
        return Ok(());
    }
    speeds.sort_by(f64::total_cmp);
    let target = rpm.unwrap_or(speeds[speeds.len() / 2]);
    let chosen: Vec<(&Entry, &RunBands, f64)> = records
        .iter()
        .filter_map(|(e, r)| {
            r.iter()
                .min_by(|a, b| (a.1 - target).abs().total_cmp(&(b.1 - target).abs()))
                .map(|&(b, v)| (*e, b, v))
        })
        .collect();
    let mut c = Chart::new(
        format!("stress at about {target:.0} rpm"),
        "shear strain γ (-)",
        "shear stress τ (kPa)",
    );
    for (k, (e, b, _)) in chosen.iter().enumerate() {
        let color = PALETTE[k % 8];
        let kpa = |v: &[f64]| v.iter().map(|x| x * 1e-3).collect::<Vec<f64>>();
        c.series.extend(super::figures::loop_band(
            &format!("{} 95 % predictive", e.label),
            color,
            &b.gamma_model,
            &kpa(&b.predictive[0]),
            &kpa(&b.predictive[1]),
            0.35,
        ));
        c.series
            .push(Series::line(None, color, b.gamma_model.clone(), kpa(&b.model[2])).with_width(1));
    }
    c.legend_at = LegendAt::Middle;
    plot::save(&Figure::single(c), &out.join("overlay"))?;
    let which: Vec<String> =
        chosen.iter().map(|(e, b, r)| format!("{} {} ({r:.0} rpm)", e.label, b.run)).collect();
    figs.push(
        "overlay",
        &format!(
            "Predictive bands of the calibrations over one another at about {target:.0} rpm: {}.",
            which.join(", ")
        ),
    );
    Ok(())
}

/// The held-out runs of every current law, with their bands.
fn held_out_figures(out: &Path, entries: &[Entry], figs: &mut Figures) -> Result<()> {
    for law in entries.iter().filter(|e| e.is_law()) {
        let Some(Prediction { bands, coverage: cov, .. }) = &law.prediction else { continue };
        let held: Vec<&RunBands> =
            bands.iter().filter(|b| cov.iter().any(|r| r.run == b.run && !r.calibrated)).collect();
        if held.is_empty() {
            continue;
        }
        let panels: Vec<Chart> = held
            .iter()
            .map(|b| {
                let kpa = |v: &[f64]| v.iter().map(|x| x * 1e-3).collect::<Vec<f64>>();
                let step = b.time.len().div_ceil(1500).max(1);
                let mut c = Chart::new(
                    format!("{} (held out)", b.run),
                    "shear strain γ (-)",
                    "shear stress τ (kPa)",
                );
                c.series.extend(super::figures::loop_band(
                    "95 % predictive",
                    PALETTE[5],
                    &b.gamma_model,
                    &kpa(&b.predictive[0]),
                    &kpa(&b.predictive[1]),
                    0.4,
                ));
                c.series.push(
                    Series::points(
                        Some("measured".into()),
                        plot::BLACK_,
                        b.gamma.iter().step_by(step).copied().collect(),
                        b.tau_obs.iter().step_by(step).map(|v| v * 1e-3).collect(),
                    )
                    .with_width(1),
                );
                c.series.push(
                    Series::line(
                        Some("law median".into()),
                        PALETTE[1],
                        b.gamma_model.clone(),
                        kpa(&b.model[2]),
                    )
                    .with_width(1),
                );
                c.legend_at = LegendAt::Middle;
                c
            })
            .collect();
        let stem = format!("held_out_{}", law.label);
        plot::save(&Figure::grid(panels, 3), &out.join(&stem))?;
        figs.push(&stem, &format!("{}: runs at currents it never saw, predicted by the current law with its 95 % predictive band.", law.label));
    }
    Ok(())
}
