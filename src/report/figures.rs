//! The figures of a calibration report, drawn from the files of the
//! calibration folder: bands per run (τ–γ and F–x), residuals against time,
//! trace plots, the corner plot and the marginals against their priors.

use std::path::Path;

use super::Figures;
use crate::error::Result;
use crate::plot::{self, Chart, Figure, LegendAt, Series, GREY, PALETTE};
use crate::posterior::{PosteriorSample, Prior};
use crate::predict::RunBands;
use crate::sampler::quantile;

/// At most this many observations are drawn as points per panel (the PNG
/// would show no more; the SVG stays small).
const MAX_POINTS: usize = 1500;

fn every(n: usize, max: usize) -> usize {
    n.div_ceil(max.max(1)).max(1)
}

/// Splits a band over a hysteresis loop into pieces along which `x` is
/// monotone, so each piece is a simple polygon (a loop drawn as one polygon
/// would fill its inside).
pub(crate) fn loop_band(label: &str, color: plot::RGBColor, x: &[f64], lo: &[f64], hi: &[f64], opacity: f64) -> Vec<Series> {
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

/// One figure per run: τ–γ and F–x with the 95 % predictive band, the 95 %
/// and 50 % model bands, the posterior median and the data.
pub fn bands(dir: &Path, bands: &[RunBands], area_m2: f64, gap_m: f64, figs: &mut Figures) -> Result<()> {
    for b in bands {
        let step = every(b.time.len(), MAX_POINTS);
        let pick = |v: &[f64], s: f64| v.iter().step_by(step).map(|x| x * s).collect::<Vec<f64>>();
        let panel = |title: String, xl: &str, yl: &str, x: &[f64], xobs: &[f64], yscale: f64| {
            let scaled = |v: &[f64]| v.iter().map(|y| y * yscale).collect::<Vec<f64>>();
            let mut c = Chart::new(title, xl, yl);
            c.series.extend(loop_band("95 % predictive", PALETTE[5], x, &scaled(&b.predictive[0]), &scaled(&b.predictive[1]), 0.25));
            c.series.extend(loop_band("95 % model", PALETTE[0], x, &scaled(&b.model[0]), &scaled(&b.model[4]), 0.35));
            c.series.extend(loop_band("50 % model", PALETTE[0], x, &scaled(&b.model[1]), &scaled(&b.model[3]), 0.6));
            c.series.push(Series::points(Some("measured".into()), plot::BLACK_, pick(xobs, 1.0), pick(&b.tau_obs, yscale)).with_width(1));
            c.series.push(Series::line(Some("posterior median".into()), PALETTE[1], x.to_vec(), scaled(&b.model[2])).with_width(1));
            c.legend_at = LegendAt::Middle;
            c
        };
        let x_model: Vec<f64> = crate::adequacy::model_displacement(b, gap_m).iter().map(|x| x * 1e3).collect();
        let x_obs: Vec<f64> = b.displacement.iter().map(|x| x * 1e3).collect();
        let tau_gamma = panel(format!("{}: stress against strain", b.run), "shear strain γ (-)", "shear stress τ (kPa)", &b.gamma_model, &b.gamma, 1e-3);
        let force_disp = panel(format!("{}: force against displacement", b.run), "displacement x (mm)", "force F = τA (N)", &x_model, &x_obs, area_m2);
        let zoom = zoom_first_loading(b);
        let stem = format!("bands_{}", b.run);
        plot::save(&Figure::grid(vec![tau_gamma, force_disp, zoom], 3), &dir.join(&stem))?;
        figs.push(
            &stem,
            &format!(
                "{} ({} A): posterior bands of the model stress and the 95 % band of a new measurement, with the record (every {}th sample shown).",
                b.run, b.current_a, step
            ),
        );
    }
    Ok(())
}

/// τ against time over the first loading up to yield, where the stress
/// changes fastest and the bands are wide enough to see.
fn zoom_first_loading(b: &RunBands) -> Chart {
    let n = b.tau_obs.len();
    let peak = b.model[2].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let knee = (0..n).find(|&k| b.model[2][k].abs() >= 0.9 * peak).unwrap_or(n / 4);
    let r = 0..(knee + knee / 2 + 10).min(n);
    let t: Vec<f64> = b.time[r.clone()].to_vec();
    let kpa = |v: &[f64]| v[r.clone()].iter().map(|x| x * 1e-3).collect::<Vec<f64>>();
    let mut c = Chart::new(format!("{}: first loading", b.run), "time t (s)", "shear stress τ (kPa)");
    c.series.push(Series::band(Some("95 % predictive".into()), PALETTE[5], t.clone(), kpa(&b.predictive[0]), kpa(&b.predictive[1])).with_opacity(0.25));
    c.series.push(Series::band(Some("95 % model".into()), PALETTE[0], t.clone(), kpa(&b.model[0]), kpa(&b.model[4])).with_opacity(0.45));
    c.series.push(Series::points(Some("measured".into()), plot::BLACK_, t.clone(), kpa(&b.tau_obs)).with_width(2));
    c.series.push(Series::line(Some("posterior median".into()), PALETTE[1], t, kpa(&b.model[2])).with_width(1));
    c.legend_at = LegendAt::LowerRight;
    c
}

/// Residuals τ_obs − median against time, one panel per run, with the 95 %
/// predictive band about the median.
pub fn residuals(dir: &Path, bands: &[RunBands], figs: &mut Figures) -> Result<()> {
    let panels: Vec<Chart> = bands
        .iter()
        .map(|b| {
            let step = every(b.time.len(), MAX_POINTS);
            let t: Vec<f64> = b.time.clone();
            let rel = |v: &[f64]| v.iter().zip(&b.model[2]).map(|(y, m)| (y - m) * 1e-3).collect::<Vec<f64>>();
            let res = rel(&b.tau_obs);
            let mut c = Chart::new(b.run.to_string(), "time t (s)", "τ_obs − median (kPa)");
            c.series.push(Series::band(Some("95 % predictive".into()), PALETTE[5], t.clone(), rel(&b.predictive[0]), rel(&b.predictive[1])));
            c.series.push(Series::points(Some("residual".into()), plot::BLACK_, t.iter().step_by(step).copied().collect(), res.iter().step_by(step).copied().collect()).with_width(1));
            c.series.push(Series::line(None, PALETTE[1], vec![t[0], t[t.len() - 1]], vec![0.0, 0.0]).with_width(1));
            c.legend_at = LegendAt::UpperRight;
            c
        })
        .collect();
    if panels.is_empty() {
        return Ok(());
    }
    plot::save(&Figure::grid(panels, 3.min(bands.len())), &dir.join("residuals"))?;
    figs.push("residuals", "Residuals against time: structure over a cycle shows where the B-P law misses the record; the band is the 95 % predictive band about the posterior median.");
    Ok(())
}

/// Trace plots of every parameter: eight chains spread over the ensembles,
/// and the end of the burn-in.
pub fn traces(dir: &Path, sample: &PosteriorSample, burn_in: usize, figs: &mut Figures) -> Result<()> {
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
            let mut c = Chart::new(name.clone(), "step", name.clone());
            for (k, &ch) in shown.iter().enumerate() {
                let trace = (0..chains.steps()).map(|s| chains.at(s, ch, i)).collect();
                c.series.push(Series::line(None, PALETTE[k % 7], steps.clone(), trace).with_width(1));
            }
            c.series.push(Series::vlines(Some("end of burn-in".into()), GREY, vec![burn_in as f64]).with_width(1));
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
pub fn corner(dir: &Path, sample: &PosteriorSample, positions: &[(usize, usize)], identification: &[f64], map: &[f64], figs: &mut Figures) -> Result<()> {
    let names = sample.layout.theta_names();
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
                c.series.push(Series::points(None, PALETTE[0].mix_rgb(), draws[col].clone(), draws[row].clone()).with_width(1));
                for (p, color) in [(identification, PALETTE[1]), (map, PALETTE[2])] {
                    if inside(p[col], ranges[col]) && inside(p[row], ranges[row]) {
                        c.series.push(Series::points(None, color, vec![p[col]], vec![p[row]]).with_width(5));
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
            "Corner plot of {} posterior draws (SI units): marginal histograms and pairs; orange marks the deterministic identification, green the MAP (each where it falls inside the plotted 0.2–99.8 % range).",
            positions.len()
        ),
    );
    Ok(())
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

/// Each B-P parameter's posterior against its prior on a log axis over the
/// prior's range: the prior density (scaled to peak 1), the posterior's 90 %
/// credible interval shaded and its median; the title gives how much the
/// records narrowed the prior (posterior sd / prior sd of ln θ).
pub fn marginals(dir: &Path, sample: &PosteriorSample, positions: &[(usize, usize)], priors: &[Prior], figs: &mut Figures) -> Result<()> {
    let mut panels = Vec::new();
    for (k, name) in sample.layout.theta_names().iter().enumerate() {
        let Some(values) = sample.values(name, positions) else { continue };
        let logs: Vec<f64> = values.iter().map(|v| v.ln()).collect();
        let (q05, q50, q95) = (quantile(&logs, 0.05), quantile(&logs, 0.5), quantile(&logs, 0.95));
        let mean = logs.iter().sum::<f64>() / logs.len().max(1) as f64;
        let sd = (logs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / logs.len().max(2) as f64).sqrt();
        let prior = priors[k];
        let (blo, bhi) = (prior.bounds().0.ln(), prior.bounds().1.ln());
        let (range, prior_sd) = match prior.centre() {
            Some((m, s)) => (((m - 2.5 * s).max(blo), (m + 2.5 * s).min(bhi)), s),
            None => ((blo, bhi), (bhi - blo) / 12f64.sqrt()),
        };
        let range = (range.0.min(q05 - 0.1), range.1.max(q95 + 0.1));
        let xs: Vec<f64> = (0..=300).map(|j| range.0 + (range.1 - range.0) * j as f64 / 300.0).collect();
        let dens: Vec<f64> = xs.iter().map(|x| prior.log_density(*x).exp()).collect();
        let peak = dens.iter().fold(0.0f64, |m, d| m.max(*d)).max(1e-300);
        let mut c = Chart::new(format!("{name}: posterior sd / prior sd = {}", plot::tick(plot::significant(sd / prior_sd, 2))), format!("{name} (log axis)"), "scaled density");
        c.log_x = true;
        c.y_range = Some((0.0, 1.15));
        c.series.push(Series::line(Some("prior".into()), PALETTE[1], xs.iter().map(|x| x.exp()).collect(), dens.iter().map(|d| d / peak).collect()));
        c.series.push(Series::band(Some("posterior 90 %".into()), PALETTE[0], vec![q05.exp(), q95.exp()], vec![0.0, 0.0], vec![1.0, 1.0]).with_opacity(0.5));
        c.series.push(Series::vlines(Some("posterior median".into()), PALETTE[0], vec![q50.exp()]).with_width(2));
        c.legend_at = LegendAt::UpperRight;
        panels.push(c);
    }
    plot::save(&Figure::grid(panels, 4), &dir.join("marginals"))?;
    figs.push("marginals", "Posterior against prior for each B-P parameter: the prior density (scaled to peak 1) over its ±2.5 sd range, the posterior's 90 % credible interval and median. A small sd ratio means the records, not the prior, determine the parameter; the corner plot shows the posterior's shape.");
    Ok(())
}
