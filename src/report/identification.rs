//! The figures of the identification, which redo the paper's Figs. 1–5.

use std::path::Path;

use crate::data::{current_tag, Campaign};
use crate::error::Result;
use crate::identify::{yield_stress::eq6, CurrentIdentification};
use crate::plot::{self, Chart, Figure, LegendAt, Series, GREY, PALETTE};

fn color(i: usize) -> plot::RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// The figures of the paper (Figs. 1–5) for every current level, as
/// `fig<k>_<name>_<current>.svg/.png` in `dir`.
pub fn write(dir: &Path, campaign: &Campaign, results: &[CurrentIdentification]) -> Result<()> {
    for res in results {
        let stem = |name: &str| dir.join(format!("{name}_{}", current_tag(res.current_a)));
        let group = campaign.at_current(res.current_a);
        fig1(&stem("fig1_tau_gamma"), &group, res)?;
        fig2(&stem("fig2_yield_rate"), res)?;
        fig3(&stem("fig3_tau_gamma_i"), res)?;
        fig4(&stem("fig4_euler"), &group, res)?;
        fig5(&stem("fig5_psi"), res)?;
    }
    Ok(())
}

/// Fig. 1: τ(γ) of the identified branch of each run
fn fig1(stem: &Path, group: &Campaign, res: &CurrentIdentification) -> Result<()> {
    let at = format!("{} A", res.current_a);
    let mut fig1 = Chart::new(
        format!("Fig. 1 — shear stress against strain, {at}"),
        "shear strain γ (-)",
        "shear stress τ (kPa)",
    );
    for (i, (run, r)) in group.runs.iter().zip(&res.runs).enumerate() {
        let b = r.branch.clone();
        fig1.series.push(
            Series::line(
                Some(run.id().to_string()),
                color(i),
                run.shear.gamma[b.clone()].to_vec(),
                run.shear.tau[b].iter().map(|t| t * 1e-3).collect(),
            )
            .with_width(1),
        );
    }
    fig1.legend_at = LegendAt::LowerRight;
    plot::save(&Figure::single(fig1), stem)
}

/// Fig. 2: τ02 against γ̇ᴵ with eq. 6
fn fig2(stem: &Path, res: &CurrentIdentification) -> Result<()> {
    let at = format!("{} A", res.current_a);
    let pts: Vec<(f64, f64)> =
        res.runs.iter().filter_map(|r| r.yield_point.map(|(t, g)| (g, t))).collect();
    let mut fig2 = Chart::new(
        format!("Fig. 2 — yield stress at γᴵ = 0.2 % against inelastic rate, {at}"),
        "inelastic shear rate dγᴵ/dt (1/s)",
        "τ02 (kPa)",
    );
    fig2.log_x = true;
    if !pts.is_empty() {
        let lo = pts.iter().map(|p| p.0).fold(f64::INFINITY, f64::min) / 2.0;
        let hi = pts.iter().map(|p| p.0).fold(0.0, f64::max) * 2.0;
        let xs: Vec<f64> = (0..100).map(|i| lo * (hi / lo).powf(i as f64 / 99.0)).collect();
        let ys = xs.iter().map(|g| eq6(res.yield_fit.r0, res.yield_fit.n, *g) * 1e-3).collect();
        fig2.series.push(Series::line(
            Some(format!("eq. 6: R0 = {:.3e} Pa, n = {:.3}", res.yield_fit.r0, res.yield_fit.n)),
            color(0),
            xs,
            ys,
        ));
        fig2.series.push(
            Series::points(
                Some("runs".into()),
                color(1),
                pts.iter().map(|p| p.0).collect(),
                pts.iter().map(|p| p.1 * 1e-3).collect(),
            )
            .with_width(5),
        );
    }
    plot::save(&Figure::single(fig2), stem)
}

/// Fig. 3: τ(γᴵ) with the eq. 7 fit
fn fig3(stem: &Path, res: &CurrentIdentification) -> Result<()> {
    let at = format!("{} A", res.current_a);
    let mut fig3 = Chart::new(
        format!("Fig. 3 — stress against inelastic strain with eq. 7, {at}"),
        "inelastic shear strain γᴵ (-)",
        "shear stress τ (kPa)",
    );
    fig3.log_x = true;
    fig3.legend_at = LegendAt::UpperLeft;
    for (i, r) in res.runs.iter().enumerate() {
        let (xs, ys) = &r.curve_data;
        fig3.series.push(Series::points(
            Some(format!("{} data", r.run)),
            color(i),
            xs.clone(),
            ys.iter().map(|y| y * 1e-3).collect(),
        ));
        if let Some(f) = &r.curve {
            fig3.series.push(Series::line(
                None,
                color(i),
                xs.clone(),
                xs.iter().map(|x| f.eq7.value(*x) * 1e-3).collect(),
            ));
        }
    }
    plot::save(&Figure::single(fig3), stem)
}

/// Fig. 4: Euler solution against the data, one panel per run
fn fig4(stem: &Path, group: &Campaign, res: &CurrentIdentification) -> Result<()> {
    let panels: Vec<Chart> = group
        .runs
        .iter()
        .zip(&res.euler_tau)
        .zip(&res.euler_rms)
        .map(|((run, model), rms)| {
            let mut c = Chart::new(
                format!("Fig. 4 — {} (RMS {:.2} kPa)", run.id(), rms * 1e-3),
                "shear strain γ (-)",
                "shear stress τ (kPa)",
            );
            c.legend_at = LegendAt::Middle;
            c.series.push(
                Series::line(
                    Some("data".into()),
                    GREY,
                    run.shear.gamma.clone(),
                    run.shear.tau.iter().map(|t| t * 1e-3).collect(),
                )
                .with_width(1),
            );
            if !model.is_empty() {
                c.series.push(Series::line(
                    Some("B-P, Euler".into()),
                    color(1),
                    run.shear.gamma.clone(),
                    model.iter().map(|t| t * 1e-3).collect(),
                ));
            }
            c
        })
        .collect();
    plot::save(&Figure::grid(panels, 3), stem)
}

/// Fig. 5: ψ(τ) with both asymptotes, one panel per run
fn fig5(stem: &Path, res: &CurrentIdentification) -> Result<()> {
    let panels: Vec<Chart> = res
        .runs
        .iter()
        .map(|r| {
            let mut c = Chart::new(
                format!("Fig. 5 — ψ(τ), {}", r.run),
                "shear stress τ (kPa)",
                "hardening rate ψ = dτ/dWᴵ (-)",
            );
            c.legend_at = LegendAt::UpperRight;
            let (t, p) = &r.psi;
            c.series.push(Series::line(
                Some("ψ from eq. 7".into()),
                color(0),
                t.iter().map(|v| v * 1e-3).collect(),
                p.clone(),
            ));
            if let Some((small, large)) = r.ends {
                let (lo, hi) = (t[0], t[t.len() - 1]);
                let line = |a: &crate::identify::hardening::Asymptote| {
                    (
                        vec![lo * 1e-3, hi * 1e-3],
                        vec![a.intercept - a.m * lo, a.intercept - a.m * hi],
                    )
                };
                let (x, y) = line(&small);
                c.series.push(Series::dashed(
                    Some(format!("small γᴵ: slope −m2, m2 = {:.2e}", small.m)),
                    color(1),
                    x,
                    y,
                ));
                let (x, y) = line(&large);
                c.series.push(Series::dashed(
                    Some(format!("large γᴵ: slope −m1, m1 = {:.2e}", large.m)),
                    color(2),
                    x,
                    y,
                ));
                let lo_y = p.iter().copied().fold(f64::INFINITY, f64::min);
                let hi_y = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let pad = 0.05 * (hi_y - lo_y).max(1e-12);
                c.y_range = Some((lo_y - pad, hi_y + pad));
            }
            c
        })
        .collect();
    plot::save(&Figure::grid(panels, 3), stem)
}
