//! The figures of a calibration report, drawn from the files of the
//! calibration folder: bands per run (τ–γ and F–x), residuals against time,
//! trace plots, the corner plot and the marginals against their priors.

use std::path::Path;

use crate::compare::{CurrentKind, CurrentRow};
use crate::error::Result;
use crate::plot::{self, Chart, Figure, LegendAt, Series, GREY, PALETTE};
use crate::posterior::{unit_of, PosteriorSample, Prior};
use crate::predict::RunBands;
use crate::sampler::quantile;
use crate::validate::consistency::ParameterConsistency;

/// Figures written so far: file stem and caption, in report order.
#[derive(Default)]
pub struct Figures {
    pub items: Vec<(String, String)>,
}

impl Figures {
    pub fn push(&mut self, stem: &str, caption: &str) {
        self.items.push((stem.to_string(), caption.to_string()));
    }
}

/// At most this many observations are drawn as points per panel (the PNG
/// would show no more; the SVG stays small).
const MAX_POINTS: usize = 1500;

/// Points per pair panel of the corner plot.
const CORNER_POINTS: usize = 600;

/// At most this many vertices per band or line drawn over a record: a
/// panel is ~500 px wide, so more add file size, not detail.
pub(crate) const MAX_VERTICES: usize = 2500;

pub(crate) fn every(n: usize, max: usize) -> usize {
    n.div_ceil(max.max(1)).max(1)
}

/// Splits a band over a hysteresis loop into pieces along which `x` is
/// monotone, so each piece is a simple polygon (a loop drawn as one polygon
/// would fill its inside).
pub(crate) fn loop_band(
    label: &str,
    color: plot::RGBColor,
    x: &[f64],
    lo: &[f64],
    hi: &[f64],
    opacity: f64,
) -> Vec<Series> {
    let mut out = Vec::new();
    let mut start = 0;
    let dir = |k: usize| (x[k + 1] - x[k]).signum();
    let mut k = 0;
    while k + 1 < x.len() {
        let d = dir(k);
        let mut end = k + 1;
        while end + 1 < x.len() && (dir(end) == d || dir(end) == 0.0) {
            end += 1;
        }
        let r = start..=end;
        let s = Series::band(
            (out.is_empty()).then(|| label.to_string()),
            color,
            x[r.clone()].to_vec(),
            lo[r.clone()].to_vec(),
            hi[r].to_vec(),
        )
        .with_opacity(opacity);
        out.push(s);
        start = end;
        k = end;
    }
    out
}

/// One figure per run. Top: the τ–γ, F–x and F–v loops with the 95 %
/// predictive band, the 95 % and 50 % model bands, the posterior median and
/// the record. Bottom, where the bands are wide enough to see: both bands
/// about the median against time, and the stress against time over the
/// first loading and around the first reversal.
pub fn bands(
    dir: &Path,
    bands: &[RunBands],
    area_m2: f64,
    gap_m: f64,
    figs: &mut Figures,
) -> Result<()> {
    for b in bands {
        let step = every(b.time.len(), MAX_POINTS);
        let pick = |v: &[f64], s: f64| v.iter().step_by(step).map(|x| x * s).collect::<Vec<f64>>();
        let thin = every(b.time.len(), MAX_VERTICES);
        let panel = |title: String,
                     xl: &str,
                     yl: &str,
                     x: &[f64],
                     xobs: &[f64],
                     yscale: f64,
                     legend_at: LegendAt| {
            let scaled =
                |v: &[f64]| v.iter().step_by(thin).map(|y| y * yscale).collect::<Vec<f64>>();
            let x = &x.iter().step_by(thin).copied().collect::<Vec<f64>>();
            let mut c = Chart::new(title, xl, yl);
            c.series.extend(loop_band(
                "95 % predictive",
                PALETTE[5],
                x,
                &scaled(&b.predictive[0]),
                &scaled(&b.predictive[1]),
                0.25,
            ));
            c.series.extend(loop_band(
                "95 % model",
                PALETTE[0],
                x,
                &scaled(&b.model[0]),
                &scaled(&b.model[4]),
                0.35,
            ));
            c.series.extend(loop_band(
                "50 % model",
                PALETTE[0],
                x,
                &scaled(&b.model[1]),
                &scaled(&b.model[3]),
                0.6,
            ));
            c.series.push(
                Series::points(
                    Some("measured".into()),
                    plot::BLACK_,
                    pick(xobs, 1.0),
                    pick(&b.tau_obs, yscale),
                )
                .with_width(1),
            );
            c.series.push(
                Series::line(
                    Some("posterior median".into()),
                    PALETTE[1],
                    x.clone(),
                    scaled(&b.model[2]),
                )
                .with_width(1),
            );
            c.legend_at = legend_at;
            c
        };
        let (x_model, v_model) = crate::predict::adequacy::kinematics(b, gap_m);
        let mm = |v: &[f64]| v.iter().map(|x| x * 1e3).collect::<Vec<f64>>();
        let x_obs = mm(&b.displacement);
        let tau_gamma = panel(
            format!("{}: stress against strain", b.run),
            "shear strain γ (-)",
            "shear stress τ (kPa)",
            &b.gamma_model,
            &b.gamma,
            1e-3,
            LegendAt::Middle,
        );
        let force_disp = panel(
            format!("{}: force against displacement", b.run),
            "displacement x (mm)",
            "force F = τA (N)",
            &mm(&x_model),
            &x_obs,
            area_m2,
            LegendAt::Middle,
        );
        // the measured velocity would be noise; the model's drives both
        let force_vel = panel(
            format!("{}: force against velocity", b.run),
            "velocity v (mm/s)",
            "force F = τA (N)",
            &mm(&v_model),
            &mm(&v_model),
            area_m2,
            LegendAt::UpperLeft,
        );
        let around = band_about_median(b, &b.run);
        let yield_zoom =
            zoom(b, first_loading(b), &format!("{}: first loading", b.run), LegendAt::LowerRight);
        let reversal_zoom =
            zoom(b, first_reversal(b), &format!("{}: first reversal", b.run), LegendAt::UpperRight);
        let stem = format!("bands_{}", b.run);
        let mut panels = vec![tau_gamma, force_disp, force_vel, around, yield_zoom, reversal_zoom];
        let mut caption = format!(
            "{} ({} A): posterior bands of the model stress and the 95 % band of a new measurement, with the record (one sample in {} shown in the loops). \
             The second row shows the bands where they are easiest to read: about the posterior median over the whole record, \
             and the stress against time over the first loading and around the first reversal.",
            b.run, b.current_a, step
        );
        if let Some(current) = &b.coil_current_a {
            panels.push(coil_current(&format!("{}: coil current", b.run), &b.time, current));
            caption.push_str(" Its coil current changes within the record (the last panel): the law was driven along it.");
        }
        plot::save(&Figure::grid(panels, 3), &dir.join(&stem))?;
        figs.push(&stem, &caption);
    }
    Ok(())
}

/// The coil current of a run whose current changes, against `time`.
pub(super) fn coil_current(title: &str, time: &[f64], current: &[f64]) -> Chart {
    let thin = every(time.len(), MAX_VERTICES);
    let mut c = Chart::new(title, "time t (s)", "coil current I (A)");
    c.series.push(
        Series::line(
            Some("current".into()),
            PALETTE[2],
            time.iter().step_by(thin).copied().collect(),
            current.iter().step_by(thin).copied().collect(),
        )
        .with_width(1),
    );
    c.legend_at = LegendAt::UpperRight;
    c
}

/// The first loading: from the start to the first reversal, where the
/// stress first rises through yield.
fn first_loading(b: &RunBands) -> std::ops::Range<usize> {
    let n = b.tau_obs.len();
    0..(first_reversal_at(b) + 1).clamp(10.min(n), n)
}

/// The sample of the first reversal of the strain that drove the model,
/// as the record's loading branches are cut (the last sample if none).
fn first_reversal_at(b: &RunBands) -> usize {
    crate::data::loading_branches(&b.gamma_model, crate::data::REVERSAL_SHARE)
        .first()
        .map_or(0, |r| r.end.saturating_sub(1))
}

/// The samples around the first reversal: from a third of the first
/// loading before it to as long again after it.
fn first_reversal(b: &RunBands) -> std::ops::Range<usize> {
    let n = b.tau_obs.len();
    let extreme = first_reversal_at(b);
    let loading = first_loading(b).end;
    extreme.saturating_sub(loading / 3)..(extreme + loading).min(n)
}

/// τ against time over `r` with both bands, the record and the median.
fn zoom(b: &RunBands, r: std::ops::Range<usize>, title: &str, legend_at: LegendAt) -> Chart {
    let t: Vec<f64> = b.time[r.clone()].to_vec();
    let kpa = |v: &[f64]| v[r.clone()].iter().map(|x| x * 1e-3).collect::<Vec<f64>>();
    let mut c = Chart::new(title, "time t (s)", "shear stress τ (kPa)");
    c.series.push(
        Series::band(
            Some("95 % predictive".into()),
            PALETTE[5],
            t.clone(),
            kpa(&b.predictive[0]),
            kpa(&b.predictive[1]),
        )
        .with_opacity(0.25),
    );
    c.series.push(
        Series::band(
            Some("95 % model".into()),
            PALETTE[0],
            t.clone(),
            kpa(&b.model[0]),
            kpa(&b.model[4]),
        )
        .with_opacity(0.45),
    );
    c.series.push(
        Series::points(Some("measured".into()), plot::BLACK_, t.clone(), kpa(&b.tau_obs))
            .with_width(2),
    );
    c.series.push(
        Series::line(Some("posterior median".into()), PALETTE[1], t, kpa(&b.model[2]))
            .with_width(1),
    );
    c.legend_at = legend_at;
    c
}

/// The 95 % predictive and model bands and the residuals about the
/// posterior median, against time: the bands' width made visible.
fn band_about_median(b: &RunBands, title: &str) -> Chart {
    let step = every(b.time.len(), MAX_POINTS);
    let thin = every(b.time.len(), MAX_VERTICES);
    let rel_all =
        |v: &[f64]| v.iter().zip(&b.model[2]).map(|(y, m)| (y - m) * 1e-3).collect::<Vec<f64>>();
    let rel = |v: &[f64]| rel_all(v).into_iter().step_by(thin).collect::<Vec<f64>>();
    let t = &b.time.iter().step_by(thin).copied().collect::<Vec<f64>>();
    let res = rel_all(&b.tau_obs);
    let mut c = Chart::new(
        format!("{title}: about the median"),
        "time t (s)",
        "τ − posterior median (kPa)",
    );
    c.series.push(
        Series::band(
            Some("95 % predictive".into()),
            PALETTE[5],
            t.clone(),
            rel(&b.predictive[0]),
            rel(&b.predictive[1]),
        )
        .with_opacity(0.35),
    );
    c.series.push(
        Series::band(
            Some("95 % model".into()),
            PALETTE[0],
            t.clone(),
            rel(&b.model[0]),
            rel(&b.model[4]),
        )
        .with_opacity(0.6),
    );
    c.series.push(
        Series::points(
            Some("measured − median".into()),
            plot::BLACK_,
            b.time.iter().step_by(step).copied().collect(),
            res.iter().step_by(step).copied().collect(),
        )
        .with_width(1),
    );
    c.legend_at = LegendAt::UpperRight;
    c
}

/// Residuals τ_obs − median against time, one panel per run, with the 95 %
/// predictive and model bands about the median.
pub fn residuals(dir: &Path, bands: &[RunBands], figs: &mut Figures) -> Result<()> {
    let panels: Vec<Chart> = bands.iter().map(|b| band_about_median(b, &b.run)).collect();
    if panels.is_empty() {
        return Ok(());
    }
    plot::save(&Figure::grid(panels, 3.min(bands.len())), &dir.join("residuals"))?;
    figs.push("residuals", "Residuals against time: structure over a cycle shows where the B-P law misses the record; the bands are the 95 % predictive and model bands about the posterior median.");
    Ok(())
}

/// The diagnostics ArviZ users look for: the log-posterior trace, and per
/// B-P parameter a rank plot by ensemble (each ensemble's share of the
/// pooled ranks in 20 bins: flat near 1 when the ensembles agree) and the
/// walker-averaged autocorrelation with its integrated time τ.
pub fn diagnostics(
    dir: &Path,
    sample: &PosteriorSample,
    burn_in: usize,
    tau: &[f64],
    figs: &mut Figures,
) -> Result<()> {
    let chains = &sample.chains;
    let (n, steps) = (chains.chains(), chains.steps());
    if steps <= burn_in + 4 {
        return Ok(());
    }
    let shown: Vec<usize> = (0..8.min(n)).map(|i| i * n / 8.min(n)).collect();
    let xs: Vec<f64> = (0..steps).map(|s| s as f64).collect();
    let mut lp = Chart::new("log posterior", "step", "ln p(θ | records)");
    for (k, &ch) in shown.iter().enumerate() {
        let trace: Vec<f64> = (0..steps).map(|s| chains.log_prob[s * n + ch]).collect();
        lp.series.push(Series::line(None, PALETTE[k % 7], xs.clone(), trace).with_width(1));
    }
    lp.series.push(
        Series::vlines(Some("end of burn-in".into()), GREY, vec![burn_in as f64]).with_width(1),
    );
    // the burn-in's first steps can sit far below: show the kept range
    let kept: Vec<f64> =
        (burn_in * n..steps * n).map(|i| chains.log_prob[i]).filter(|v| v.is_finite()).collect();
    if !kept.is_empty() {
        let (lo, hi) = (quantile(&kept, 0.001), quantile(&kept, 1.0));
        lp.y_range = Some((lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo)));
    }
    lp.legend_at = LegendAt::LowerRight;
    // four columns: every parameter's rank plot and autocorrelation side by side
    let mut panels = vec![lp, Chart::blank()];
    let ensembles = chains.ensembles.max(1);
    let walkers = n / ensembles;
    for (i, name) in sample.layout.theta_names().iter().enumerate() {
        let traces = chains.traces(i, burn_in);
        // rank plot: pooled ranks, each ensemble's histogram over uniform
        let mut all: Vec<(f64, usize)> = traces
            .iter()
            .enumerate()
            .flat_map(|(c, t)| t.iter().map(move |v| (*v, c / walkers.max(1))))
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
        const BINS: usize = 20;
        let mut counts = vec![vec![0.0; BINS]; ensembles];
        for (rank, (_, e)) in all.iter().enumerate() {
            counts[(*e).min(ensembles - 1)][rank * BINS / all.len()] += 1.0;
        }
        let expected = all.len() as f64 / (BINS * ensembles) as f64;
        let centres: Vec<f64> = (0..BINS).map(|b| (b as f64 + 0.5) / BINS as f64).collect();
        let mut rank = Chart::new(
            format!("{name}: ranks by ensemble"),
            "pooled rank (fraction)",
            "count / uniform",
        );
        for (e, c) in counts.iter().enumerate() {
            rank.series.push(
                Series::line(
                    None,
                    PALETTE[e % 7],
                    centres.clone(),
                    c.iter().map(|v| v / expected).collect(),
                )
                .with_width(1),
            );
        }
        rank.series.push(
            Series::dashed(Some("uniform".into()), GREY, vec![0.0, 1.0], vec![1.0, 1.0])
                .with_width(1),
        );
        rank.y_range = Some((0.0, 2.0));
        rank.legend_at = LegendAt::UpperRight;
        panels.push(rank);
        // autocorrelation averaged over walkers, to a few τ
        let len = traces[0].len();
        let t = tau.get(i).copied().filter(|t| t.is_finite()).unwrap_or(1.0);
        let lags = ((5.0 * t).ceil() as usize).max(10).min(len.saturating_sub(1).max(1));
        let mut acf = vec![0.0; lags];
        for tr in &traces {
            for (a, r) in acf.iter_mut().zip(crate::sampler::diagnostics::autocorrelation(tr)) {
                *a += r / n as f64;
            }
        }
        let mut c = Chart::new(
            format!("{name}: autocorrelation, τ = {}", plot::tick(plot::significant(t, 2))),
            "lag (steps)",
            "autocorrelation",
        );
        c.series.push(
            Series::line(None, PALETTE[0], (0..lags).map(|l| l as f64).collect(), acf)
                .with_width(2),
        );
        c.series.push(Series::vlines(Some("τ".into()), GREY, vec![t]).with_width(1));
        c.y_range = Some((-0.2, 1.05));
        c.legend_at = LegendAt::UpperRight;
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &dir.join("diagnostics"))?;
    figs.push(
        "diagnostics",
        &format!(
            "Sampler diagnostics: the log-posterior of {} walkers (burn-in before the grey line); per B-P parameter, the rank plot of the {ensembles} independent ensembles \
             (each line is one ensemble's share of the pooled ranks; flat near 1 when they agree, which is what R̂ measures) and the autocorrelation averaged over walkers, with τ.",
            shown.len()
        ),
    );
    Ok(())
}

/// Trace plots of every parameter: eight chains spread over the ensembles,
/// and the end of the burn-in.
pub fn traces(
    dir: &Path,
    sample: &PosteriorSample,
    burn_in: usize,
    figs: &mut Figures,
) -> Result<()> {
    let chains = &sample.chains;
    let n = chains.chains();
    let shown: Vec<usize> = (0..8.min(n)).map(|i| i * n / 8.min(n)).collect();
    let steps: Vec<f64> = (0..chains.steps()).map(|s| s as f64).collect();
    let panels: Vec<Chart> = sample
        .layout
        .names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let mut c = Chart::new(
                name.clone(),
                "step",
                format!("{name} ({})", crate::posterior::unit_of(name)),
            );
            for (k, &ch) in shown.iter().enumerate() {
                let trace = (0..chains.steps()).map(|s| chains.at(s, ch, i)).collect();
                c.series
                    .push(Series::line(None, PALETTE[k % 7], steps.clone(), trace).with_width(1));
            }
            c.series.push(
                Series::vlines(Some("end of burn-in".into()), GREY, vec![burn_in as f64])
                    .with_width(1),
            );
            c.legend_at = LegendAt::UpperRight;
            c
        })
        .collect();
    plot::save(&Figure::grid(panels, 3), &dir.join("traces"))?;
    figs.push("traces", &format!("Trace plots: {} of {} walkers, spread over the ensembles; steps before the grey line are burn-in.", shown.len(), n));
    Ok(())
}

/// The corner plot of the θ parameters (the seven B-P ones or a current law's): marginal histograms on the
/// diagonal, pairs below it; the identification and the MAP marked where
/// they fall inside the plotted range.
pub fn corner(
    dir: &Path,
    sample: &PosteriorSample,
    names: &[String],
    positions: &[(usize, usize)],
    identification: &[f64],
    map: &[f64],
    figs: &mut Figures,
) -> Result<()> {
    let k = names.len();
    if k == 0 {
        return Ok(());
    }
    let draws: Vec<Vec<f64>> = names.iter().filter_map(|n| sample.values(n, positions)).collect();
    let ranges: Vec<(f64, f64)> = draws
        .iter()
        .map(|d| {
            let (lo, hi) = (quantile(d, 0.002), quantile(d, 0.998));
            let pad = 0.08 * (hi - lo).max(hi.abs() * 1e-9);
            (lo - pad, hi + pad)
        })
        .collect();
    let inside = |v: f64, r: (f64, f64)| v >= r.0 && v <= r.1;
    let mut panels = Vec::new();
    for row in 0..k {
        for col in 0..k {
            if col > row {
                panels.push(Chart::blank());
                continue;
            }
            let x_label = if row == k - 1 { names[col].clone() } else { String::new() };
            let mut c = Chart::new("", x_label, "");
            c.compact = true;
            c.legend = false;
            c.x_range = Some(ranges[col]);
            if col == row {
                let (edges, heights) = histogram(&draws[col], ranges[col], 30);
                c.series.push(Series::bars(None, PALETTE[0], edges, heights));
                c.hide_y_ticks = true;
                for (v, color) in [(identification[col], PALETTE[1]), (map[col], PALETTE[2])] {
                    if inside(v, ranges[col]) {
                        c.series.push(Series::vlines(None, color, vec![v]).with_width(2));
                    }
                }
            } else {
                if col == 0 {
                    c.y_label = names[row].clone();
                }
                c.y_range = Some(ranges[row]);
                // the regions carry the density; a few hundred points show the outskirts
                let thin = every(draws[col].len(), CORNER_POINTS);
                let (xs, ys) = (
                    draws[col].iter().step_by(thin).copied().collect(),
                    draws[row].iter().step_by(thin).copied().collect(),
                );
                c.series.push(Series::points(None, PALETTE[0].mix_rgb(), xs, ys).with_width(1));
                for (level, opacity) in [(0.9, 0.35), (0.5, 0.55)] {
                    let (xs, ys, size) =
                        credible_cells(&draws[col], &draws[row], ranges[col], ranges[row], level);
                    c.series.push(Series::cells(None, PALETTE[0], xs, ys, size, opacity));
                }
                for (p, color) in [(identification, PALETTE[1]), (map, PALETTE[2])] {
                    if inside(p[col], ranges[col]) && inside(p[row], ranges[row]) {
                        c.series.push(
                            Series::points(None, color, vec![p[col]], vec![p[row]]).with_width(5),
                        );
                    }
                }
            }
            panels.push(c);
        }
    }
    let mut fig = Figure::grid(panels, k);
    fig.panel_size = (200, 180);
    plot::save(&fig, &dir.join("corner"))?;
    figs.push(
        "corner",
        &format!(
            "Corner plot of {} posterior draws (SI units): marginal histograms and pairs, with the smallest regions of a 20 × 20 grid (counts smoothed over neighbouring cells) that hold 50 % (dark) and 90 % (light) of the draws; orange marks the deterministic identification, green the MAP (each where it falls inside the plotted 0.2–99.8 % range).",
            positions.len()
        ),
    );
    Ok(())
}

/// The cells of a 20 × 20 grid over `rx` × `ry` that hold `level` of the
/// draws, densest first (a highest-density region of the counts smoothed
/// over each cell's neighbours, so a few hundred draws give a smooth
/// region): their lower-left corners and their size.
fn credible_cells(
    x: &[f64],
    y: &[f64],
    rx: (f64, f64),
    ry: (f64, f64),
    level: f64,
) -> (Vec<f64>, Vec<f64>, (f64, f64)) {
    const BINS: usize = 20;
    let (w, h) = ((rx.1 - rx.0) / BINS as f64, (ry.1 - ry.0) / BINS as f64);
    let mut counts = vec![0usize; BINS * BINS];
    for (a, b) in x.iter().zip(y) {
        let (i, j) = (((a - rx.0) / w).floor(), ((b - ry.0) / h).floor());
        if (0.0..BINS as f64).contains(&i) && (0.0..BINS as f64).contains(&j) {
            counts[j as usize * BINS + i as usize] += 1;
        }
    }
    // 3 × 3 smoothing with weights 4 (centre), 2 (sides), 1 (corners)
    let mut mass = vec![0.0f64; BINS * BINS];
    for j in 0..BINS {
        for i in 0..BINS {
            for (dj, di) in (-1i64..=1).flat_map(|a| (-1i64..=1).map(move |b| (a, b))) {
                let (jj, ii) = (j as i64 + dj, i as i64 + di);
                if (0..BINS as i64).contains(&jj) && (0..BINS as i64).contains(&ii) {
                    let w = [4.0, 2.0, 1.0][(dj.abs() + di.abs()) as usize];
                    mass[j * BINS + i] += w * counts[jj as usize * BINS + ii as usize] as f64;
                }
            }
        }
    }
    let total: f64 = mass.iter().sum();
    let mut order: Vec<usize> = (0..mass.len()).filter(|&c| mass[c] > 0.0).collect();
    order.sort_by(|a, b| mass[*b].total_cmp(&mass[*a]));
    let target = level * total;
    let mut held = 0.0;
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for c in order {
        if held >= target {
            break;
        }
        held += mass[c];
        xs.push(rx.0 + (c % BINS) as f64 * w);
        ys.push(ry.0 + (c / BINS) as f64 * h);
    }
    (xs, ys, (w, h))
}

trait Lighter {
    fn mix_rgb(self) -> plot::RGBColor;
}

impl Lighter for plot::RGBColor {
    /// The colour halfway to white: dense clouds of points stay readable.
    fn mix_rgb(self) -> plot::RGBColor {
        let m = |c: u8| ((c as u16 + 255) / 2) as u8;
        plot::RGBColor(m(self.0), m(self.1), m(self.2))
    }
}

/// Bin edges and density heights of `v` over `range`.
fn histogram(v: &[f64], range: (f64, f64), bins: usize) -> (Vec<f64>, Vec<f64>) {
    let w = (range.1 - range.0) / bins as f64;
    let edges: Vec<f64> = (0..=bins).map(|i| range.0 + i as f64 * w).collect();
    let mut counts = vec![0.0; bins];
    for x in v {
        let b = ((x - range.0) / w).floor();
        if b >= 0.0 && (b as usize) < bins {
            counts[b as usize] += 1.0;
        }
    }
    let norm = 1.0 / (v.len().max(1) as f64 * w);
    (edges, counts.into_iter().map(|c| c * norm).collect())
}

/// Each B-P parameter's posterior against its prior, in two panels. Left,
/// on a log axis over the prior's range: the prior density (scaled to peak
/// 1), the posterior's 90 % credible interval shaded and its median; the
/// title gives how much the records narrowed the prior (posterior sd /
/// prior sd of ln θ). Right, zoomed on the posterior: its histogram, its
/// 90 % interval and median, and the prior's shape there.
pub fn marginals(
    dir: &Path,
    sample: &PosteriorSample,
    positions: &[(usize, usize)],
    priors: &[Prior],
    figs: &mut Figures,
) -> Result<()> {
    let mut panels = Vec::new();
    for (k, name) in sample.layout.theta_names().iter().enumerate() {
        let Some(values) = sample.values(name, positions) else { continue };
        let logs: Vec<f64> = values.iter().map(|v| v.ln()).collect();
        let (q05, q50, q95) = (quantile(&logs, 0.05), quantile(&logs, 0.5), quantile(&logs, 0.95));
        let mean = logs.iter().sum::<f64>() / logs.len().max(1) as f64;
        let sd = (logs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / logs.len().max(2) as f64)
            .sqrt();
        let prior = priors[k];
        let (blo, bhi) = (prior.bounds().0.ln(), prior.bounds().1.ln());
        let (range, prior_sd) = match prior.centre() {
            Some((m, s)) => (((m - 2.5 * s).max(blo), (m + 2.5 * s).min(bhi)), s),
            None => ((blo, bhi), (bhi - blo) / 12f64.sqrt()),
        };
        let range = (range.0.min(q05 - 0.1), range.1.max(q95 + 0.1));
        let xs: Vec<f64> =
            (0..=300).map(|j| range.0 + (range.1 - range.0) * j as f64 / 300.0).collect();
        let dens: Vec<f64> = xs.iter().map(|x| prior.log_density(*x).exp()).collect();
        let peak = dens.iter().fold(0.0f64, |m, d| m.max(*d)).max(1e-300);
        let mut c = Chart::new(
            format!(
                "{name}: posterior sd / prior sd = {}",
                plot::tick(plot::significant(sd / prior_sd, 2))
            ),
            format!("{name} (log axis)"),
            "scaled density",
        );
        c.log_x = true;
        c.y_range = Some((0.0, 1.15));
        c.hide_y_ticks = true;
        // narrower than a pixel column on this axis: say where to look
        let narrow = (q95 - q05) < 0.01 * (range.1 - range.0);
        let label = if narrow { "posterior 90 % (narrow: see zoom)" } else { "posterior 90 %" };
        c.series.push(Series::line(
            Some("prior".into()),
            PALETTE[1],
            xs.iter().map(|x| x.exp()).collect(),
            dens.iter().map(|d| d / peak).collect(),
        ));
        c.series.push(
            Series::band(
                Some(label.into()),
                PALETTE[0],
                vec![q05.exp(), q95.exp()],
                vec![0.0, 0.0],
                vec![1.0, 1.0],
            )
            .with_opacity(0.5),
        );
        c.series.push(
            Series::vlines(Some("posterior median".into()), PALETTE[0], vec![q50.exp()])
                .with_width(2),
        );
        c.legend_at = LegendAt::UpperRight;
        panels.push(c);
        panels.push(zoomed_marginal(name, &values, &prior));
    }
    plot::save(&Figure::grid(panels, 4), &dir.join("marginals"))?;
    figs.push(
        "marginals",
        "Posterior against prior for each B-P parameter. Left of each pair: the prior density (scaled to peak 1) over its ±2.5 sd range, \
         the posterior's 90 % credible interval and median; a small sd ratio means the records, not the prior, determine the parameter. \
         Right: zoomed on the posterior, its histogram with the 90 % interval and the prior's shape over that range (rescaled). The corner plot shows the joint shape.",
    );
    Ok(())
}

/// One parameter's posterior on a linear axis over its own 0.2–99.8 %
/// range, with the prior density there rescaled to the histogram's peak.
fn zoomed_marginal(name: &str, values: &[f64], prior: &Prior) -> Chart {
    let (lo, hi) = (quantile(values, 0.002), quantile(values, 0.998));
    let pad = 0.08 * (hi - lo).max(hi.abs() * 1e-9);
    let range = (lo - pad, hi + pad);
    let (edges, heights) = histogram(values, range, 40);
    let top = heights.iter().fold(0.0f64, |m, h| m.max(*h)).max(1e-300);
    let xs: Vec<f64> =
        (0..=100).map(|j| range.0 + (range.1 - range.0) * j as f64 / 100.0).collect();
    // the prior's density in θ (its density in ln θ over θ)
    let dens: Vec<f64> = xs
        .iter()
        .map(|x| if *x > 0.0 { (prior.log_density(x.ln()) - x.ln()).exp() } else { 0.0 })
        .collect();
    let dtop = dens.iter().fold(0.0f64, |m, d| m.max(*d));
    let mut c = Chart::new(
        format!("{name}: posterior, zoomed"),
        format!("{name} ({})", crate::posterior::unit_of(name)),
        "density",
    );
    c.hide_y_ticks = true;
    c.x_range = Some(range);
    c.y_range = Some((0.0, 1.2 * top));
    c.series.push(Series::bars(Some("posterior".into()), PALETTE[0], edges, heights));
    if dtop > 0.0 {
        c.series.push(Series::dashed(
            Some("prior (rescaled)".into()),
            PALETTE[1],
            xs,
            dens.iter().map(|d| d / dtop * 0.5 * top).collect(),
        ));
    }
    c.series.push(
        Series::vlines(Some("median, 90 %".into()), PALETTE[7], vec![quantile(values, 0.5)])
            .with_width(2),
    );
    c.series.push(
        Series::vlines(None, PALETTE[7], vec![quantile(values, 0.05), quantile(values, 0.95)])
            .with_width(1),
    );
    c.legend_at = LegendAt::UpperRight;
    c
}

/// Consistency across runs: per B-P parameter, each run calibrated alone,
/// the joint calibration and the between-run layer's new test, as medians
/// with 90 % bars on a log axis.
pub fn consistency(
    dir: &Path,
    parameters: &[ParameterConsistency],
    figs: &mut Figures,
) -> Result<()> {
    let Some(first) = parameters.first() else {
        return Ok(());
    };
    let mut labels: Vec<String> = first.runs.iter().map(|r| r.label.clone()).collect();
    labels.extend(["joint".to_string(), "new test".to_string()]);
    let rows = labels.len();
    let mut panels = Vec::new();
    for p in parameters {
        let mut c = Chart::new(
            format!("{}  (χ²/ν {:.1})", p.parameter, p.chi2_nu),
            format!("{} ({})", p.parameter, crate::posterior::unit_of(&p.parameter)),
            "",
        );
        let estimates = p.runs.iter().chain([&p.joint, &p.new_test]);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (k, e) in estimates.enumerate() {
            let y = (rows - k) as f64;
            let color = if k < p.runs.len() { PALETTE[k % 8] } else { GREY };
            c.series.push(Series::line(None, color, vec![e.q05, e.q95], vec![y, y]).with_width(3));
            c.series.push(Series::points(None, color, vec![e.q50], vec![y]).with_width(5));
            (lo, hi) = (lo.min(e.q05), hi.max(e.q95));
        }
        if lo > 0.0 && lo < hi {
            let pad = (hi / lo).powf(0.08);
            c.x_range = Some((lo / pad, hi * pad));
            c.log_x = true;
        }
        c.y_range = Some((0.4, rows as f64 + 0.6));
        c.y_names = Some(labels.iter().rev().cloned().collect());
        c.legend = false;
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &dir.join("consistency"))?;
    figs.push("consistency", "Consistency across runs: median (dot) and 90 % interval (bar) of each parameter from each run calibrated alone, from the joint calibration, and the between-run layer's prediction for a new test (grey). χ²/ν in each title: about 1 when one parameter set describes every run.");
    Ok(())
}

/// A law's B-P parameters against the coil current, ready to draw.
pub struct LawCurves<'a> {
    pub label: &'a str,
    pub rows: &'a [CurrentRow],
    /// The currents it was calibrated on (A).
    pub calibrated_a: &'a [f64],
    /// Its colour; `None`: the next of the laws' colours.
    pub color: Option<plot::RGBColor>,
}

/// A per-current estimate drawn beside the laws: its current, and per
/// parameter (in the order of the figure's names) its 5 %, 50 % and 95 %
/// quantiles.
pub struct AtCurrent {
    pub current_a: f64,
    pub quantiles: Vec<Option<[f64; 3]>>,
}

/// Each damper-law parameter `names` against the coil current: every
/// current law's 90 % band and
/// median over its grid (its calibrated currents marked), and the
/// per-current estimates as medians with 90 % bars, into `dir/against_current`.
/// `more`: a sentence added to the caption (the bands beside the laws').
pub fn against_current(
    dir: &Path,
    names: &[&str],
    laws: &[LawCurves],
    per_current: &[AtCurrent],
    more: &str,
    figs: &mut Figures,
) -> Result<()> {
    let top = laws
        .iter()
        .flat_map(|l| l.rows.iter().map(|r| r.current_a))
        .chain(per_current.iter().map(|p| p.current_a))
        .fold(0.0f64, f64::max);
    if top <= 0.0 {
        return Ok(());
    }
    let mut panels = Vec::new();
    for (k, name) in names.iter().enumerate() {
        let mut c = Chart::new(*name, "coil current I (A)", format!("{name} ({})", unit_of(name)));
        for (j, law) in laws.iter().enumerate() {
            let rows: Vec<&CurrentRow> = law.rows.iter().filter(|r| r.parameter == *name).collect();
            let x: Vec<f64> = rows.iter().map(|r| r.current_a).collect();
            let color = law.color.unwrap_or(PALETTE[(4 + j) % 8]);
            let label = format!("{} (90 %)", law.label);
            c.series.push(
                Series::band(
                    Some(label),
                    color,
                    x.clone(),
                    rows.iter().map(|r| r.q05).collect(),
                    rows.iter().map(|r| r.q95).collect(),
                )
                .with_opacity(0.3),
            );
            c.series.push(
                Series::line(None, color, x, rows.iter().map(|r| r.q50).collect()).with_width(2),
            );
            let seen: Vec<&&CurrentRow> =
                rows.iter().filter(|r| r.kind == CurrentKind::Calibrated).collect();
            let mark = (j == 0).then(|| "calibrated currents".to_string());
            c.series.push(
                Series::points(
                    mark,
                    color,
                    seen.iter().map(|r| r.current_a).collect(),
                    seen.iter().map(|r| r.q50).collect(),
                )
                .with_width(4),
            );
            // the extrapolated part (below the lowest calibrated current and
            // above the highest) dashed over the band
            let (lo, hi) = law
                .calibrated_a
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
            for part in [
                rows.iter().filter(|r| r.current_a <= lo).collect::<Vec<_>>(),
                rows.iter().filter(|r| r.current_a >= hi).collect(),
            ] {
                if part.len() >= 2 {
                    c.series.push(
                        Series::dashed(
                            None,
                            GREY,
                            part.iter().map(|r| r.current_a).collect(),
                            part.iter().map(|r| r.q50).collect(),
                        )
                        .with_width(2),
                    );
                }
            }
        }
        let (mut x, mut y) = (vec![], vec![]);
        for p in per_current {
            if let Some(&Some([q05, q50, q95])) = p.quantiles.get(k) {
                c.series.push(
                    Series::line(None, PALETTE[0], vec![p.current_a; 2], vec![q05, q95])
                        .with_width(2),
                );
                x.push(p.current_a);
                y.push(q50);
            }
        }
        if !x.is_empty() {
            c.series.push(
                Series::points(Some("per-current (median, 90 %)".into()), PALETTE[0], x, y)
                    .with_width(5),
            );
        }
        c.x_range = Some((0.0, top));
        c.legend = panels.is_empty();
        c.legend_at = LegendAt::LowerRight;
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &dir.join("against_current"))?;
    let per = if per_current.is_empty() {
        ""
    } else {
        "; per-current calibrations as medians with 90 % bars"
    };
    figs.push(
        "against_current",
        &format!("Each parameter of the law against the coil current: median and 90 % credible band from the off-state (0 A) to 1.2× the highest calibrated current (dots: the currents calibrated on; grey dashes: extrapolated beyond them){per}.{more}"),
    );
    Ok(())
}
