//! `mrbp compare`: tables, figures and one HTML report over several
//! calibration folders (current levels, dampers, settings, a current law).

use std::path::{Path, PathBuf};

use super::html::{esc, num, Mark, Page};
use super::Figures;
use crate::compare::difference;
use crate::data::loading_branches;
use crate::error::{Error, Result};
use crate::model::PARAM_NAMES;
use crate::output::plot::{self, Chart, Figure, LegendAt, Series, PALETTE};
use crate::output::prediction::{read_bands, read_coverage, CoverageRow, StoredBands};
use crate::output::{atomic_write, write_parquet, Table};
use crate::sampler::quantile;
use crate::stored::StoredCalibration;

/// Posterior draws per calibration for differences and figures.
const DRAWS: usize = 4000;

/// One calibration as the comparison sees it.
struct Entry {
    label: String,
    cal: StoredCalibration,
    positions: Vec<(usize, usize)>,
    bands: Option<Vec<StoredBands>>,
    coverage: Option<Vec<CoverageRow>>,
}

impl Entry {
    fn draws(&self, name: &str) -> Option<Vec<f64>> {
        let i = self.cal.chains.index(name)?;
        Some(self.positions.iter().map(|&(s, c)| self.cal.chains.at(i, s, c)).collect())
    }

    fn is_law(&self) -> bool {
        self.cal.is_current_law()
    }
}

/// The crank speed of a record (rpm) from its loading branches: each is
/// half a revolution.
fn rpm_of(time: &[f64], displacement: &[f64]) -> f64 {
    let branches = loading_branches(displacement, 0.1);
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

/// Writes `comparison.parquet`, `differences.parquet`, the figures and
/// `report.html` into `out`. `rpm` picks the runs whose bands are overlaid.
pub fn write(dirs: &[PathBuf], out: &Path, rpm: Option<f64>) -> Result<PathBuf> {
    if dirs.len() < 2 {
        return Err(Error::Usage("compare needs at least two calibration folders".into()));
    }
    let mut entries = Vec::new();
    for d in dirs {
        let cal = StoredCalibration::open(d)?;
        let positions = cal.draw_positions(DRAWS);
        let bands = d.join("bands.parquet").exists().then(|| read_bands(&d.join("bands.parquet"))).transpose()?;
        let coverage = d.join("coverage.parquet").exists().then(|| read_coverage(&d.join("coverage.parquet"))).transpose()?;
        let mut label = cal.label();
        if entries.iter().any(|e: &Entry| e.label == label) {
            label = d.display().to_string();
        }
        entries.push(Entry { label, cal, positions, bands, coverage });
    }
    std::fs::create_dir_all(out).map_err(|e| Error::output(out, e))?;

    // comparison.parquet: the summary of every calibration, one row per parameter
    let mut t = (vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![]);
    for e in &entries {
        for r in &e.cal.summary {
            t.0.push(e.label.clone());
            t.1.push(e.cal.record.current_a);
            t.2.push(r.parameter.clone());
            t.3.push(r.mean);
            t.4.push(r.sd);
            t.5.push(r.q05);
            t.6.push(r.q50);
            t.7.push(r.q95);
        }
    }
    write_parquet(
        &out.join("comparison.parquet"),
        Table::new().str("calibration", t.0).f64("current_a", t.1).str("parameter", t.2).f64("mean", t.3).f64("sd", t.4).f64("q05", t.5).f64("q50", t.6).f64("q95", t.7),
    )?;

    // differences.parquet: every pair, every parameter both have (noise scales are per run)
    let mut rows = Vec::new();
    for (i, a) in entries.iter().enumerate() {
        for b in &entries[i + 1..] {
            for name in a.cal.chains.names.iter().filter(|n| !n.starts_with("sigma_") && !n.starts_with("rho_")) {
                if let (Some(da), Some(db)) = (a.draws(name), b.draws(name)) {
                    rows.push((a.label.clone(), b.label.clone(), name.clone(), difference(&da, &db)));
                }
            }
        }
    }
    let col = |f: &dyn Fn(&crate::compare::Difference) -> f64| rows.iter().map(|r| f(&r.3)).collect::<Vec<f64>>();
    write_parquet(
        &out.join("differences.parquet"),
        Table::new()
            .str("calibration_a", rows.iter().map(|r| r.0.clone()).collect())
            .str("calibration_b", rows.iter().map(|r| r.1.clone()).collect())
            .str("parameter", rows.iter().map(|r| r.2.clone()).collect())
            .f64("diff_q05", col(&|d| d.diff_q05))
            .f64("diff_q50", col(&|d| d.diff_q50))
            .f64("diff_q95", col(&|d| d.diff_q95))
            .f64("ratio_q05", col(&|d| d.ratio_q05))
            .f64("ratio_q50", col(&|d| d.ratio_q50))
            .f64("ratio_q95", col(&|d| d.ratio_q95))
            .f64("p_greater", col(&|d| d.p_greater)),
    )?;

    let mut figs = Figures::default();
    forest(out, &entries, &mut figs)?;
    against_current(out, &entries, &mut figs)?;
    overlay(out, &entries, rpm, &mut figs)?;
    held_out_figures(out, &entries, &mut figs)?;

    // the report
    let mut page = Page::new(&format!("mrbp comparison of {} calibrations", entries.len()));
    page.section("calibrations", "Calibrations");
    let rows_html: Vec<Vec<String>> = entries
        .iter()
        .map(|e| {
            let (rhat, ess) = (e.cal.max_rhat(), e.cal.min_ess());
            vec![
                esc(&e.label),
                if e.is_law() { "current law".into() } else { "per current".into() },
                if e.is_law() { format!("{:?}", e.cal.record.currents) } else { num(e.cal.record.current_a, 2) },
                esc(&e.cal.record.runs.join(", ")),
                format!("{rhat:.4}"),
                format!("{ess:.0}"),
                Mark::of(rhat < 1.01 && ess >= e.cal.settings.sampler.min_ess).html().into(),
            ]
        })
        .collect();
    page.table(&["calibration", "model", "current (A)", "runs", "max R̂", "min ESS", ""], &rows_html);

    page.section("parameters", "Parameters");
    page.para("Posterior median and 90 % credible interval of each B-P parameter (SI units). In a current law, R0, R1 and D1 are the values at its reference current.");
    let mut header = vec!["parameter".to_string()];
    header.extend(entries.iter().map(|e| e.label.clone()));
    let names: Vec<String> = {
        let mut n: Vec<String> = Vec::new();
        for e in &entries {
            for r in &e.cal.summary {
                if !r.parameter.starts_with("sigma_") && !r.parameter.starts_with("rho_") && !n.contains(&r.parameter) {
                    n.push(r.parameter.clone());
                }
            }
        }
        n
    };
    let table: Vec<Vec<String>> = names
        .iter()
        .map(|n| {
            let mut row = vec![esc(n)];
            for e in &entries {
                row.push(match e.cal.summary.iter().find(|r| &r.parameter == n) {
                    Some(r) => format!("{} [{}, {}]", num(r.q50, 3), num(r.q05, 3), num(r.q95, 3)),
                    None => "–".into(),
                });
            }
            row
        })
        .collect();
    page.table(&header.iter().map(String::as_str).collect::<Vec<_>>(), &table);

    page.section("differences", "Differences");
    page.para("For each pair a, b and each parameter both have: the 90 % interval of a − b and of a / b, and P(a > b). Probabilities beyond 0.99 or below 0.01 (bold) mean the records tell the two apart.");
    let table: Vec<Vec<String>> = rows
        .iter()
        .map(|(a, b, p, d)| {
            let sure = d.p_greater > 0.99 || d.p_greater < 0.01;
            let pg = format!("{:.3}", d.p_greater);
            vec![
                esc(a),
                esc(b),
                esc(p),
                format!("{} [{}, {}]", num(d.diff_q50, 3), num(d.diff_q05, 3), num(d.diff_q95, 3)),
                format!("{} [{}, {}]", num(d.ratio_q50, 3), num(d.ratio_q05, 3), num(d.ratio_q95, 3)),
                if sure { format!("<b>{pg}</b>") } else { pg },
            ]
        })
        .collect();
    page.table(&["a", "b", "parameter", "a − b: median [5 %, 95 %]", "a / b: median [5 %, 95 %]", "P(a > b)"], &table);

    page.section("current-law", "Current law and held-out currents");
    law_section(&mut page, &entries);
    for (stem, caption) in figs.items.iter().filter(|f| f.0.starts_with("held_out")) {
        page.figure(&out.join(format!("{stem}.png")), caption)?;
    }

    page.section("figures", "Figures");
    for (stem, caption) in figs.items.iter().filter(|f| !f.0.starts_with("held_out")) {
        page.figure(&out.join(format!("{stem}.png")), caption)?;
    }

    page.section("reproduce", "Reproduce");
    let mut rows_html = vec![vec!["command".to_string(), format!("<code>{}</code>", esc(&crate::output::calibration::command_line()))]];
    rows_html.push(vec!["mrbp version".into(), esc(env!("CARGO_PKG_VERSION"))]);
    for e in &entries {
        rows_html.push(vec![esc(&e.label), format!("<code>{}</code> (seed {})", esc(&e.cal.record.command), e.cal.record.seed)]);
    }
    page.table(&["", ""], &rows_html);

    let path = out.join("report.html");
    atomic_write(&path, page.finish().as_bytes())?;
    Ok(path)
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
        let Some(cov) = &law.coverage else {
            page.para(&format!("{}: no bands yet (run `mrbp predict` on it).", law.label));
            continue;
        };
        page.para(&format!(
            "{}: the current law calibrated on the runs at {:?} A. Runs it did not see are predicted at their current; the per-current calibration of the same runs saw them (in-sample), so it is the best that seven free parameters per current can do.",
            law.label, law.cal.record.currents
        ));
        let mut table = Vec::new();
        for r in cov {
            let per_current = entries
                .iter()
                .filter(|e| !e.is_law())
                .find_map(|e| e.coverage.as_ref().and_then(|c| c.iter().find(|x| x.run == r.run)).map(|x| (e.label.clone(), x.clone())));
            let ok = r.inside_p95 >= 0.8;
            table.push(vec![
                esc(&r.run),
                num(r.current_a, 2),
                if r.calibrated { "calibrated on".into() } else { "<b>held out</b>".into() },
                format!("{:.1}", 100.0 * r.inside_p95),
                num(r.rmse_q50_pa, 3),
                per_current.as_ref().map_or("–".into(), |(l, x)| format!("{:.1} ({})", 100.0 * x.inside_p95, esc(l))),
                per_current.as_ref().map_or("–".into(), |(_, x)| num(x.rmse_q50_pa, 3)),
                if r.calibrated { String::new() } else { Mark::of(ok).html().into() },
            ]);
        }
        page.table(
            &["run", "current (A)", "law", "law: inside 95 % (%)", "law: RMS to median (Pa)", "per-current: inside 95 % (%)", "per-current: RMS (Pa)", "held out ≥ 80 %"],
            &table,
        );
    }
}

/// A forest plot per B-P parameter: each calibration's median and 90 %
/// interval.
fn forest(out: &Path, entries: &[Entry], figs: &mut Figures) -> Result<()> {
    let mut panels = Vec::new();
    for name in PARAM_NAMES {
        let mut c = Chart::new(name, format!("{name} (SI)"), "calibration");
        for (k, e) in entries.iter().enumerate() {
            if let Some(r) = e.cal.summary.iter().find(|r| r.parameter == name) {
                let y = (entries.len() - k) as f64;
                let color = PALETTE[k % 8];
                c.series.push(Series::line(Some(e.label.clone()), color, vec![r.q05, r.q95], vec![y, y]).with_width(3));
                c.series.push(Series::points(None, color, vec![r.q50], vec![y]).with_width(5));
            }
        }
        c.y_range = Some((0.3, entries.len() as f64 + 0.7));
        c.legend_at = LegendAt::UpperRight;
        c.legend = panels.is_empty();
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &out.join("forest"))?;
    figs.push("forest", "Forest plot: median (dot) and 90 % credible interval (bar) of each parameter in each calibration, top to bottom in the order given.");
    Ok(())
}

/// Each B-P parameter against the coil current: per-current calibrations as
/// medians with 90 % bars, current laws as a 90 % band over the current.
fn against_current(out: &Path, entries: &[Entry], figs: &mut Figures) -> Result<()> {
    let per_current: Vec<&Entry> = entries.iter().filter(|e| !e.is_law()).collect();
    let top = entries.iter().flat_map(|e| e.cal.record.currents.iter().copied().chain([e.cal.record.current_a])).fold(0.0f64, f64::max);
    if top <= 0.0 {
        return Ok(());
    }
    let grid: Vec<f64> = (1..=60).map(|i| 1.15 * top * i as f64 / 60.0).collect();
    let laws: Vec<&Entry> = entries.iter().filter(|e| e.is_law()).collect();
    // each law's B-P parameters at each current of the grid, over 400 of its draws
    let law_params: Vec<Vec<Vec<[f64; 7]>>> = laws
        .iter()
        .map(|law| {
            let take: Vec<(usize, usize)> = law.positions.iter().step_by((law.positions.len() / 400).max(1)).copied().collect();
            grid.iter()
                .map(|&i| take.iter().filter_map(|&(s, ch)| law.cal.params_at(s, ch, i).ok()).map(|p| p.to_array()).collect())
                .collect()
        })
        .collect();
    let mut panels = Vec::new();
    for (k, name) in PARAM_NAMES.iter().enumerate() {
        let mut c = Chart::new(*name, "coil current I (A)", format!("{name} (SI)"));
        for (j, (law, at_grid)) in laws.iter().zip(&law_params).enumerate() {
            let (mut lo, mut mid, mut hi) = (Vec::new(), Vec::new(), Vec::new());
            for draws in at_grid {
                let v: Vec<f64> = draws.iter().map(|p| p[k]).collect();
                lo.push(quantile(&v, 0.05));
                mid.push(quantile(&v, 0.5));
                hi.push(quantile(&v, 0.95));
            }
            let color = PALETTE[(4 + j) % 8];
            c.series.push(Series::band(Some(format!("{} (90 %)", law.label)), color, grid.clone(), lo, hi).with_opacity(0.3));
            c.series.push(Series::line(None, color, grid.clone(), mid).with_width(2));
        }
        let (mut x, mut y) = (vec![], vec![]);
        for e in &per_current {
            if let Some(r) = e.cal.summary.iter().find(|r| r.parameter == *name) {
                c.series.push(Series::line(None, PALETTE[0], vec![e.cal.record.current_a; 2], vec![r.q05, r.q95]).with_width(2));
                x.push(e.cal.record.current_a);
                y.push(r.q50);
            }
        }
        c.series.push(Series::points(Some("per-current (median, 90 %)".into()), PALETTE[0], x, y).with_width(5));
        c.x_range = Some((0.0, 1.15 * top));
        c.legend = panels.is_empty();
        c.legend_at = LegendAt::LowerRight;
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &out.join("against_current"))?;
    figs.push("against_current", "Each B-P parameter against the coil current: per-current calibrations (median and 90 % interval) and, where given, the current law's 90 % band.");
    Ok(())
}

/// The predictive bands of every per-current calibration at one crank
/// speed, over one another (τ against time over the first revolution).
fn overlay(out: &Path, entries: &[Entry], rpm: Option<f64>, figs: &mut Figures) -> Result<()> {
    // every record of the per-current calibrations with its crank speed
    let records: Vec<(&Entry, Vec<(&StoredBands, f64)>)> = entries
        .iter()
        .filter(|e| !e.is_law())
        .filter_map(|e| e.bands.as_ref().map(|bands| (e, bands.iter().map(|b| (b, rpm_of(&b.time, &b.displacement))).collect())))
        .collect();
    let mut speeds: Vec<f64> = records.iter().flat_map(|(_, r)| r.iter().map(|(_, v)| *v)).filter(|v| v.is_finite()).collect();
    if speeds.is_empty() {
        return Ok(());
    }
    speeds.sort_by(f64::total_cmp);
    let target = rpm.unwrap_or(speeds[speeds.len() / 2]);
    let chosen: Vec<(&Entry, &StoredBands, f64)> = records
        .iter()
        .filter_map(|(e, r)| {
            r.iter().min_by(|a, b| (a.1 - target).abs().total_cmp(&(b.1 - target).abs())).map(|&(b, v)| (*e, b, v))
        })
        .collect();
    let mut c = Chart::new(format!("stress at about {target:.0} rpm"), "shear strain γ (-)", "shear stress τ (kPa)");
    for (k, (e, b, _)) in chosen.iter().enumerate() {
        let color = PALETTE[k % 8];
        let kpa = |v: &[f64]| v.iter().map(|x| x * 1e-3).collect::<Vec<f64>>();
        c.series.extend(super::figures::loop_band(&format!("{} 95 % predictive", e.label), color, &b.gamma_model, &kpa(&b.predictive[0]), &kpa(&b.predictive[1]), 0.35));
        c.series.push(Series::line(None, color, b.gamma_model.clone(), kpa(&b.model[2])).with_width(1));
    }
    c.legend_at = LegendAt::Middle;
    plot::save(&Figure::single(c), &out.join("overlay"))?;
    let which: Vec<String> = chosen.iter().map(|(e, b, r)| format!("{} {} ({r:.0} rpm)", e.label, b.run)).collect();
    figs.push("overlay", &format!("Predictive bands of the calibrations over one another at about {target:.0} rpm: {}.", which.join(", ")));
    Ok(())
}

/// The held-out runs of every current law, with their bands.
fn held_out_figures(out: &Path, entries: &[Entry], figs: &mut Figures) -> Result<()> {
    for law in entries.iter().filter(|e| e.is_law()) {
        let (Some(bands), Some(cov)) = (&law.bands, &law.coverage) else { continue };
        let held: Vec<&StoredBands> = bands.iter().filter(|b| cov.iter().any(|r| r.run == b.run && !r.calibrated)).collect();
        if held.is_empty() {
            continue;
        }
        let panels: Vec<Chart> = held
            .iter()
            .map(|b| {
                let kpa = |v: &[f64]| v.iter().map(|x| x * 1e-3).collect::<Vec<f64>>();
                let step = b.time.len().div_ceil(1500).max(1);
                let mut c = Chart::new(format!("{} (held out)", b.run), "shear strain γ (-)", "shear stress τ (kPa)");
                c.series.extend(super::figures::loop_band("95 % predictive", PALETTE[5], &b.gamma_model, &kpa(&b.predictive[0]), &kpa(&b.predictive[1]), 0.4));
                c.series.push(Series::points(Some("measured".into()), plot::BLACK_, b.gamma.iter().step_by(step).copied().collect(), b.tau_obs.iter().step_by(step).map(|v| v * 1e-3).collect()).with_width(1));
                c.series.push(Series::line(Some("law median".into()), PALETTE[1], b.gamma_model.clone(), kpa(&b.model[2])).with_width(1));
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
