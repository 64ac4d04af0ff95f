//! The "Model adequacy" section of a calibration report: where the
//! calibrated B-P law does not describe the damper, in numbers, figures and
//! plain words (see [`crate::predict::adequacy`] for what is measured).

use std::path::Path;

use super::figures::loop_band;
use super::figures::Figures;
use super::html::{esc, num, Page};
use crate::data::Geometry;
use crate::error::Result;
use crate::plot::{self, Chart, Figure, LegendAt, Series, GREY, PALETTE};
use crate::posterior::{Allowance, LikelihoodSettings};
use crate::predict::adequacy::{self, AdequacyRow};
use crate::predict::RunBands;

/// Lag-1 autocorrelation above which the report says the noise model
/// ignores the residuals' memory (an AR(1) with ρ = 0.5 makes intervals
/// too narrow by √3 ≈ 1.7).
pub const CORRELATED: f64 = 0.5;

/// A reversal RMS this many times the mid-stroke RMS is called a yield
/// timing misfit.
const REVERSAL_RATIO: f64 = 1.5;

/// A trend r ≈ a + k·x + c·v explaining this share of the residual
/// variance is called a missing force.
const TREND_SHARE: f64 = 0.2;

/// The section: plain-words findings, the table and one figure per run
/// (`rows` the adequacy of `bands`, in their order).
/// `likelihood` is the calibration's: whether its intervals already allow
/// for the residuals' memory (the tempered or adjusted likelihood).
pub fn section(
    page: &mut Page,
    dir: &Path,
    bands: &[RunBands],
    rows: &[AdequacyRow],
    geometry: &Geometry,
    likelihood: &LikelihoodSettings,
) -> Result<()> {
    page.section("adequacy", "Model adequacy");
    page.para(
        "Where the calibrated law misses the records, in force (F = τA). The residual is the measured force minus the posterior-median model; \
         reversals are the samples slower than a fifth of the peak speed, where the law times yield.",
    );
    for finding in findings(rows, likelihood.allowance()) {
        page.para(&finding);
    }
    let table: Vec<Vec<String>> = rows
        .iter()
        .map(|a| {
            vec![
                esc(&a.run),
                esc(&a.excitation.label()),
                num(a.peak_force_n, 3),
                format!(
                    "{} ({:.1} %)",
                    num(a.residual_rms_n, 3),
                    100.0 * a.residual_rms_n / a.peak_force_n
                ),
                match a.innovation_lag1.is_finite() {
                    true => format!("{:.2} ({:.2})", a.lag1_autocorrelation, a.innovation_lag1),
                    false => format!("{:.2}", a.lag1_autocorrelation),
                },
                format!("{:.1}", a.interval_inflation),
                format!("{} / {}", num(a.reversal_rms_n, 3), num(a.stroke_rms_n, 3)),
                format!(
                    "{:.0} / {:.0} / {:.0}",
                    100.0 * a.inside_p95,
                    100.0 * a.inside_p95_reversal,
                    100.0 * a.inside_p95_stroke
                ),
                format!(
                    "{} / {} / {}",
                    num(a.trend_offset_n, 2),
                    num(a.trend_stiffness_n_per_m, 2),
                    num(a.trend_damping_n_s_per_m, 2)
                ),
                format!("{:.0}", 100.0 * a.trend_share),
            ]
        })
        .collect();
    page.table(
        &[
            "run",
            "excitation",
            "peak force (N)",
            "residual RMS (N)",
            if rows.iter().any(|a| a.innovation_lag1.is_finite()) {
                "lag-1 ρ (of the innovations)"
            } else {
                "lag-1 ρ"
            },
            "intervals too narrow by ×",
            "RMS reversal / stroke (N)",
            "inside 95 % predictive: all / reversal / stroke (%)",
            "trend offset (N) / k (N/m) / c (N·s/m)",
            "trend share (%)",
        ],
        &table,
    );
    page.note("adequacy.parquet in the folder holds these numbers, one row per run.");
    let mut figs = Figures::default();
    figures(dir, bands, rows, geometry, &mut figs)?;
    for (stem, caption) in &figs.items {
        page.figure(&dir.join(format!("{stem}.png")), caption)?;
    }
    Ok(())
}

fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    v.filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)))
}

fn spread(lo: f64, hi: f64, digits: usize) -> String {
    if num(lo, digits) == num(hi, digits) {
        num(lo, digits)
    } else {
        format!("{}–{}", num(lo, digits), num(hi, digits))
    }
}

/// What the numbers say, as sentences a reader can act on; `allowance`
/// how the likelihood allowed for the residuals' memory (tempered or
/// adjusted), if it did.
pub fn findings(rows: &[AdequacyRow], allowance: Option<Allowance>) -> Vec<String> {
    if rows.is_empty() {
        return Vec::new();
    }
    [size(rows), memory(rows, allowance), reversals(rows), missing_force(rows), excitation(rows)]
        .into_iter()
        .flatten()
        .collect()
}

/// The misfit's size and the band's coverage.
fn size(rows: &[AdequacyRow]) -> Option<String> {
    let (clo, chi) = range(rows.iter().map(|a| 100.0 * a.inside_p95));
    let (slo, shi) = range(rows.iter().map(|a| 100.0 * a.residual_rms_n / a.peak_force_n));
    let (flo, fhi) = range(rows.iter().map(|a| a.residual_rms_n));
    Some(format!(
        "Size: the residual force is {} N RMS, {} % of the peak force; the 95 % predictive band holds {} % of the samples.",
        spread(flo, fhi, 3),
        spread(slo, shi, 2),
        spread(clo, chi, 3)
    ))
}

/// Whether the residuals remember their past, and what that does to the
/// intervals.
fn memory(rows: &[AdequacyRow], allowance: Option<Allowance>) -> Option<String> {
    let worst =
        rows.iter().max_by(|a, b| a.lag1_autocorrelation.total_cmp(&b.lag1_autocorrelation))?;
    if rows.iter().all(|a| a.innovation_lag1.is_finite()) {
        return Some(left_memory(rows, worst));
    }
    match allowance {
        Some(Allowance::Tempered { lo, hi }) => return Some(format!(
            "Memory: the residuals are correlated in time (lag-1 autocorrelation up to {:.2} on {}), and the likelihood was tempered for it: each run's log-likelihood divided by the integrated autocorrelation time of its residuals at the MAP ({} samples), which widens the intervals by its square root. That allows for the memory, not for a bias a missing force puts into θ.",
            worst.lag1_autocorrelation,
            esc(&worst.run),
            spread(lo, hi, 2)
        )),
        Some(Allowance::Adjusted { lo, hi }) => return Some(format!(
            "Memory: the residuals are correlated in time (lag-1 autocorrelation up to {:.2} on {}), and the likelihood was adjusted for it: its curvature at the MAP set to the covariance of its score given the residuals' memory (the sandwich H⁻¹VH⁻¹), which inflates the posterior variance by {} along its principal directions, each parameter by the memory of the part of the records that informs it. That allows for the memory, not for a bias a missing force puts into θ.",
            worst.lag1_autocorrelation,
            esc(&worst.run),
            spread(lo, hi, 2)
        )),
        None => {}
    }
    if worst.lag1_autocorrelation <= CORRELATED {
        return Some(format!(
            "Memory: the residuals are close to independent (lag-1 autocorrelation at most {:.2}), as the noise model assumes.",
            worst.lag1_autocorrelation
        ));
    }
    let (ilo, ihi) = range(rows.iter().map(|a| a.interval_inflation));
    let (dlo, dhi) = range(rows.iter().map(|a| 1e3 * a.decorrelation_s));
    Some(format!(
        "Memory: the residuals are correlated in time (lag-1 autocorrelation up to {:.2} on {}; they decorrelate after {} ms), \
         while the noise model takes them as independent. The parameter intervals are therefore too narrow, by a factor of about {} \
         (√((1 + ρ)/(1 − ρ))): read the posterior sd as a lower bound. The predictive band is set by the residual spread and is \
         less affected, but its coverage is not evidence that the law is right.",
        worst.lag1_autocorrelation,
        esc(&worst.run),
        spread(dlo, dhi, 2),
        spread(ilo, ihi, 2)
    ))
}

/// Memory with a noise model that has a force of its own: what the
/// residuals carry, and what its innovations leave.
fn left_memory(rows: &[AdequacyRow], worst: &AdequacyRow) -> String {
    let left =
        rows.iter().max_by(|a, b| a.innovation_lag1.total_cmp(&b.innovation_lag1)).unwrap_or(worst);
    let carried = format!(
        "Memory: the residuals about the median model are correlated in time (lag-1 autocorrelation up to {:.2} on {}), \
         and the noise model takes that as a force the law lacks (the discrepancy, drawn below with its band).",
        worst.lag1_autocorrelation,
        esc(&worst.run)
    );
    if left.innovation_lag1 <= CORRELATED {
        format!(
            "{carried} What it leaves, its one-step-ahead innovations, is close to independent (lag-1 autocorrelation at most {:.2}): \
         the intervals account for the memory.",
            left.innovation_lag1
        )
    } else {
        let (ilo, ihi) = range(rows.iter().map(|a| a.interval_inflation));
        format!(
            "{carried} Its one-step-ahead innovations still remember (lag-1 autocorrelation up to {:.2} on {}): memory it does not \
             explain, so the intervals are too narrow by a factor of about {} (√((1 + ρ)/(1 − ρ)) of the innovations).",
            left.innovation_lag1,
            esc(&left.run),
            spread(ilo, ihi, 2)
        )
    }
}

/// Runs whose misfit concentrates at the reversals.
fn reversals(rows: &[AdequacyRow]) -> Option<String> {
    let at_reversal: Vec<&AdequacyRow> =
        rows.iter().filter(|a| a.reversal_rms_n > REVERSAL_RATIO * a.stroke_rms_n).collect();
    if at_reversal.is_empty() {
        return None;
    }
    let list: Vec<String> = at_reversal
        .iter()
        .map(|a| {
            format!(
                "{} ({} N against {} N, band holds {:.0} % against {:.0} %)",
                esc(&a.run),
                num(a.reversal_rms_n, 3),
                num(a.stroke_rms_n, 3),
                100.0 * a.inside_p95_reversal,
                100.0 * a.inside_p95_stroke
            )
        })
        .collect();
    Some(format!(
        "Reversals: the misfit concentrates where the motion reverses and the fluid yields again — {}. \
         The law's transition from elastic to plastic flow is timed or shaped differently from the damper's there.",
        list.join("; ")
    ))
}

/// Runs whose residual a force linear in displacement and velocity explains.
fn missing_force(rows: &[AdequacyRow]) -> Option<String> {
    let trended: Vec<&AdequacyRow> = rows.iter().filter(|a| a.trend_share > TREND_SHARE).collect();
    if trended.is_empty() {
        return None;
    }
    let list: Vec<String> = trended
        .iter()
        .map(|a| {
            format!(
                "{} ({:.0} % of the residual variance: k = {} N/m, c = {} N·s/m, offset {} N)",
                esc(&a.run),
                100.0 * a.trend_share,
                num(a.trend_stiffness_n_per_m, 2),
                num(a.trend_damping_n_s_per_m, 2),
                num(a.trend_offset_n, 2)
            )
        })
        .collect();
    Some(format!(
        "Missing force: a force linear in displacement and velocity explains much of the residual on {}. A spring (k) is what a gas \
         accumulator adds, an offset what seal friction or a load-cell zero adds (both are model terms: [terms] in the settings); \
         a viscous part (c) is flow the law does not carry.",
        list.join("; ")
    ))
}

/// Which excitation the law fits worst and best.
fn excitation(rows: &[AdequacyRow]) -> Option<String> {
    let labels: std::collections::BTreeSet<String> =
        rows.iter().map(|a| a.excitation.label()).collect();
    if labels.len() <= 1 {
        return None;
    }
    // Coverage is near 95 % on every run by construction (each run has its
    // own noise scale), so compare the misfit itself.
    let relative = |a: &AdequacyRow| a.residual_rms_n / a.peak_force_n;
    let worst = rows.iter().max_by(|a, b| relative(a).total_cmp(&relative(b)))?;
    let best = rows.iter().min_by(|a, b| relative(a).total_cmp(&relative(b)))?;
    Some(format!(
        "Excitation: the law fits {} ({}) worst, {:.1} % of its peak force RMS, and {} ({}) best, {:.1} %. {}",
        esc(&worst.run),
        esc(&worst.excitation.label()),
        100.0 * relative(worst),
        esc(&best.run),
        esc(&best.excitation.label()),
        100.0 * relative(best),
        if relative(worst) > 1.5 * relative(best) {
            "One parameter set does not serve these excitations equally: the law's rate and amplitude dependence differs from the damper's."
        } else {
            "One parameter set serves these excitations about equally."
        }
    ))
}

/// One figure per run: force against velocity with the 95 % predictive
/// band (the loop a damper engineer reads), the residual against
/// displacement and against velocity, and its autocorrelation over a cycle.
fn figures(
    dir: &Path,
    bands: &[RunBands],
    rows: &[AdequacyRow],
    geometry: &Geometry,
    figs: &mut Figures,
) -> Result<()> {
    let area = geometry.area_m2;
    for (b, a) in bands.iter().zip(rows) {
        let (x, v) = adequacy::kinematics(b, geometry.gap_m);
        let residual = adequacy::residual_force(b, area);
        let step = b.time.len().div_ceil(1500).max(1);
        let pick =
            |s: &[f64], scale: f64| s.iter().step_by(step).map(|y| y * scale).collect::<Vec<f64>>();
        let newton = |s: &[f64]| s.iter().map(|t| t * area).collect::<Vec<f64>>();
        let v_mm: Vec<f64> = v.iter().map(|v| v * 1e3).collect();

        let mut loop_fv = Chart::new(
            format!("{}: force against velocity", b.run),
            "velocity v (mm/s)",
            "force F (N)",
        );
        loop_fv.series.extend(loop_band(
            "95 % predictive",
            PALETTE[5],
            &v_mm,
            &newton(&b.predictive[0]),
            &newton(&b.predictive[1]),
            0.3,
        ));
        loop_fv.series.push(
            Series::points(
                Some("measured".into()),
                plot::BLACK_,
                pick(&v, 1e3),
                pick(&b.tau_obs, area),
            )
            .with_width(1),
        );
        loop_fv.series.push(
            Series::line(
                Some("posterior median".into()),
                PALETTE[1],
                v_mm.clone(),
                newton(&b.model[2]),
            )
            .with_width(1),
        );
        loop_fv.legend_at = LegendAt::LowerRight;

        let against = |title: &str, label: &str, s: &[f64], scale: f64| {
            let mut c = Chart::new(
                format!("{}: residual against {title}", b.run),
                label,
                "F_obs − F_median (N)",
            );
            let xs = pick(s, scale);
            let (lo, hi) = range(xs.iter().copied());
            c.series
                .push(Series::points(None, plot::BLACK_, xs, pick(&residual, 1.0)).with_width(1));
            c.series
                .push(Series::line(None, PALETTE[1], vec![lo, hi], vec![0.0, 0.0]).with_width(1));
            c
        };
        let vs_x = against("displacement", "displacement x (mm)", &x, 1e3);
        let vs_v = against("velocity", "velocity v (mm/s)", &v, 1e3);

        let finite: Vec<f64> = residual.iter().copied().filter(|r| r.is_finite()).collect();
        let lags = adequacy::samples_per_cycle(&b.time, &a.excitation);
        let acf = adequacy::autocorrelation(&finite, lags);
        let dt = (b.time[b.time.len() - 1] - b.time[0]) / (b.time.len().max(2) - 1) as f64;
        let lag_s: Vec<f64> = (0..acf.len()).map(|k| k as f64 * dt).collect();
        let white = 1.96 / (finite.len().max(1) as f64).sqrt();
        let end = lag_s.last().copied().unwrap_or(1.0);
        let mut acf_chart = Chart::new(
            format!("{}: residual autocorrelation", b.run),
            "lag (s)",
            "autocorrelation",
        );
        acf_chart
            .series
            .push(Series::line(Some("residual".into()), PALETTE[0], lag_s, acf).with_width(2));
        acf_chart.series.push(Series::dashed(
            Some("independent noise (95 %)".into()),
            GREY,
            vec![0.0, end],
            vec![white, white],
        ));
        acf_chart.series.push(Series::dashed(None, GREY, vec![0.0, end], vec![-white, -white]));
        let mut panels = vec![loop_fv, vs_x, vs_v];
        if let Some([mean, sd, innovation]) = &b.discrepancy {
            let w: Vec<f64> = innovation.iter().copied().filter(|v| v.is_finite()).collect();
            let acf_w = adequacy::autocorrelation(&w, lags);
            let lag_w: Vec<f64> = (0..acf_w.len()).map(|k| k as f64 * dt).collect();
            acf_chart.series.push(
                Series::line(Some("innovations".into()), PALETTE[3], lag_w, acf_w).with_width(2),
            );
            panels.push(discrepancy_panel(b, &residual, mean, sd, area));
        }
        acf_chart.legend_at = LegendAt::UpperRight;
        panels.push(acf_chart);

        let stem = format!("adequacy_{}", b.run);
        plot::save(&Figure::grid(panels, 2), &dir.join(&stem))?;
        figs.push(
            &stem,
            &format!(
                "{} ({}, {} A): force–velocity loop with the 95 % predictive band; the residual force against displacement (a slope is a \
                 missing spring) and against velocity (spikes near v = 0 are yield timing);{} its autocorrelation over one cycle against the \
                 band of independent noise.",
                b.run,
                a.excitation.label(),
                b.current_a,
                if b.discrepancy.is_some() {
                    " the discrepancy the noise model finds in it over time (its posterior mean given the whole record, with a 90 % band, \
                     at the median model and noise), and the autocorrelation of the residual and of the model's one-step-ahead innovations:"
                } else {
                    ""
                }
            ),
        );
    }
    Ok(())
}

/// The residual force over time with the discrepancy the noise model finds
/// in it: its smoothed mean and a 90 % band (± 1.645 sd), in N.
fn discrepancy_panel(b: &RunBands, residual: &[f64], mean: &[f64], sd: &[f64], area: f64) -> Chart {
    // from the second sample (the first is the fixed initial state)
    let at: Vec<usize> = (1..b.time.len())
        .step_by(b.time.len().div_ceil(1500).max(1))
        .filter(|&k| mean[k].is_finite())
        .collect();
    let of = |f: &dyn Fn(usize) -> f64| -> Vec<f64> { at.iter().map(|&k| f(k)).collect() };
    let t = of(&|k| b.time[k]);
    let mut c = Chart::new(format!("{}: discrepancy over time", b.run), "time t (s)", "force (N)");
    c.series.push(
        Series::points(Some("residual".into()), plot::BLACK_, t.clone(), of(&|k| residual[k]))
            .with_width(1),
    );
    c.series.push(
        Series::band(
            Some("discrepancy, 90 %".into()),
            PALETTE[3],
            t.clone(),
            of(&|k| (mean[k] - 1.645 * sd[k]) * area),
            of(&|k| (mean[k] + 1.645 * sd[k]) * area),
        )
        .with_opacity(0.3),
    );
    c.series.push(
        Series::line(Some("discrepancy".into()), PALETTE[3], t, of(&|k| mean[k] * area))
            .with_width(2),
    );
    c.legend_at = LegendAt::UpperRight;
    c
}
