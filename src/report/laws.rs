//! The report of damper laws side by side (`mrbp run --law A,B,…`): the
//! verdict in plain words, each law's standing at each current (held-out
//! log predictive density and its difference from the best with its
//! standard error, coverage, the band's width, the error measures in
//! sample and held out, cost), the records one by one, and each record's
//! loop and residuals with every law's prediction beside the measurement.

use std::path::{Path, PathBuf};

use super::html::{esc, num, Page};
use crate::atomic;
use crate::error::Result;
use crate::laws::LawKind;
use crate::plot::{self, Chart, Figure, LegendAt, Series, BLACK_, PALETTE};
use crate::predict::RunBands;
use crate::validate::laws::{verdict, Kind, LawRow, Standing};

/// What the report shows.
pub struct LawsReport<'a> {
    pub dir: &'a Path,
    pub campaign: &'a str,
    pub rows: &'a [LawRow],
    pub standings: &'a [Standing],
    /// Each law's predictions of the records: held out where the study was
    /// made with leave-one-out, else in sample.
    pub predictions: &'a [(LawKind, Vec<RunBands>)],
    pub area_m2: f64,
    /// Each law's whole job (s), its calibrations, bands, leave-one-out and
    /// reports at every current.
    pub job_seconds: &'a [(LawKind, f64)],
    pub command: &'a str,
    /// Whether the records were held out (leave-one-out).
    pub held_out: bool,
    /// The calibrations compared, `law/I<c>A` and id (named in the page,
    /// for `mrbp status`).
    pub calibration_ids: &'a [(String, String)],
}

/// Writes the figures and `report.html` into the study's folder.
pub fn write(r: &LawsReport) -> Result<PathBuf> {
    let dir = r.dir;
    atomic::remove(&dir.join(super::html::REPORT))?;
    let mut page = Page::new(&format!("mrbp: damper laws on {}", r.campaign));
    for (_, id) in r.calibration_ids {
        page.derived_from(id);
    }
    let laws: Vec<String> = r.job_seconds.iter().map(|(l, _)| l.name()).collect();
    page.para(&format!(
        "The laws {} calibrated on the records of {} current by current (one parameter set per current, the same likelihood, noise model and model terms), {}.",
        laws.join(", "),
        r.campaign,
        if r.held_out {
            "each record then held out in turn and predicted by the law calibrated on the others (leave-one-out)"
        } else {
            "and judged in sample only: run with --leave-one-out to rank them on records they did not see"
        }
    ));
    page.section("verdict", "Verdict");
    if r.held_out {
        for line in verdict(r.standings) {
            page.para(&line);
        }
        page.note("Held-out log predictive density judges a law's whole predictive distribution (its path and its noise) on tests it did not see; with residuals that keep memory (the report of each law's calibration says how much) every law's noise is taken as more certain than it is, so differences of a few standard errors may not survive a likelihood that allows for the memory. The log evidence (marginal likelihood) of each law: by sequential Monte Carlo where its calibrations were sampled so (--sampler smc), else by bridge sampling from the ensemble sampler's chains (marked b).");
    } else {
        page.para("No verdict without records held out.");
    }
    page.section("standings", "Standings");
    let header = [
        "current (A)", "rank", "law", "held-out elpd", "Δ elpd ± se", "nRMSE in sample",
        "nRMSE held out", "held out in 95 % band", "band width / peak", "log evidence ± se",
        "calibration (s)",
    ];
    let rows: Vec<Vec<String>> = r
        .standings
        .iter()
        .map(|s| {
            vec![
                num(s.current_a, 3),
                s.rank.to_string(),
                esc(&s.law.name()),
                num(s.elpd, 4),
                if s.rank == 1 {
                    "0".into()
                } else {
                    format!("{} ± {}", num(s.elpd_diff, 3), num(s.elpd_diff_se, 2))
                },
                format!("{:.1} %", 100.0 * s.nrmse_in),
                format!("{:.1} %", 100.0 * s.nrmse_out),
                format!("{:.1} %", 100.0 * s.inside_p95_out),
                format!("{:.0} %", 100.0 * s.band_width_out),
                s.evidence.map_or("—".into(), |e| {
                    format!(
                        "{} ± {}{}{}",
                        num(e.log_evidence, 7),
                        num(e.se, 2),
                        if e.by == crate::validate::laws::BRIDGE { " b" } else { "" },
                        if e.pseudo { " (pseudo)" } else { "" }
                    )
                }),
                num(s.seconds, 3),
            ]
        })
        .collect();
    page.table(&header, &rows);
    let jobs: Vec<String> =
        r.job_seconds.iter().map(|(l, s)| format!("{} {:.0} s", l.name(), s)).collect();
    page.para(&format!("Each law's whole job (calibration, bands, leave-one-out and reports at every current): {}.", jobs.join(", ")));
    page.section("records", "Records");
    page.para("Per record: nRMSE = RMS(F − F̂)/max|F|; E_t, E_x and E_v the RMS error over the force's own spread, as a function of time, of displacement (samples weighted by |ẋ|) and of velocity (by |ẍ|), after Spencer et al. (1997); the share inside the 95 % predictive band; lppd the record's log pointwise predictive density.");
    let header = [
        "law", "current (A)", "record", "kind", "nRMSE", "E_t", "E_x", "E_v", "in 95 % band",
        "lppd",
    ];
    let rows: Vec<Vec<String>> = r
        .rows
        .iter()
        .map(|x| {
            vec![
                esc(&x.law.name()),
                num(x.current_a, 3),
                esc(&x.run),
                x.kind.name().into(),
                format!("{:.1} %", 100.0 * x.measures.nrmse),
                num(x.measures.e_t, 3),
                num(x.measures.e_x, 3),
                num(x.measures.e_v, 3),
                format!("{:.1} %", 100.0 * x.measures.inside_p95),
                num(x.lppd, 5),
            ]
        })
        .collect();
    page.table(&header, &rows);
    page.section("figures", "Loops and residuals");
    let kind = if r.held_out { Kind::HeldOut } else { Kind::InSample };
    for (stem, caption) in figures(dir, r.predictions, r.area_m2, kind)? {
        page.figure(&dir.join(format!("{stem}.png")), &caption)?;
    }
    page.section("reproduce", "Reproduce");
    page.pre(r.command);
    let path = dir.join(super::html::REPORT);
    atomic::write(&path, page.finish().as_bytes())?;
    Ok(path)
}

/// Per record, its force-displacement loop and its residuals against time,
/// the measurement beside every law's median prediction: `loops_<run>`.
fn figures(
    dir: &Path,
    predictions: &[(LawKind, Vec<RunBands>)],
    area: f64,
    kind: Kind,
) -> Result<Vec<(String, String)>> {
    let Some((_, first)) = predictions.first() else { return Ok(Vec::new()) };
    let mut out = Vec::new();
    for b in first {
        let mut loop_chart = Chart::new(
            format!("{}: force against displacement", b.run),
            "piston displacement x (mm)",
            "damper force F (kN)",
        );
        loop_chart.legend_at = LegendAt::Middle;
        let mm: Vec<f64> = b.displacement.iter().map(|x| x * 1e3).collect();
        loop_chart.series.push(
            Series::line(
                Some("measured".into()),
                BLACK_,
                mm.clone(),
                b.force.iter().map(|f| f * 1e-3).collect(),
            )
            .with_width(1),
        );
        let mut residuals = Chart::new(
            format!("{}: residual force F − F̂", b.run),
            "time t (s)",
            "residual force (N)",
        );
        for (k, (law, bands)) in predictions.iter().enumerate() {
            let Some(own) = bands.iter().find(|o| o.run == b.run) else { continue };
            let model: Vec<f64> = own.model[2].iter().map(|t| t * area).collect();
            let color = PALETTE[k % PALETTE.len()];
            loop_chart.series.push(Series::line(
                Some(law.name()),
                color,
                own.displacement.iter().map(|x| x * 1e3).collect(),
                model.iter().map(|f| f * 1e-3).collect(),
            ));
            residuals.series.push(
                Series::line(
                    Some(law.name()),
                    color,
                    own.time.clone(),
                    own.force.iter().zip(&model).map(|(f, m)| f - m).collect(),
                )
                .with_width(1),
            );
        }
        let stem = format!("loops_{}", b.run);
        plot::save(&Figure::grid(vec![loop_chart, residuals], 2), &dir.join(&stem))?;
        out.push((
            stem,
            format!(
                "{}: the measured loop and each law's median ({}), and the residuals against time.",
                b.run,
                kind.name()
            ),
        ));
    }
    Ok(out)
}
