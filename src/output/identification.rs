//! Outputs of the identification: `identification.parquet`, the figures
//! that redo the paper's Figs. 1–5, and the terminal table.

use std::path::Path;

use super::plot::{self, Chart, Figure, LegendAt, Series, GREY, PALETTE};
use super::{write_parquet, Table};
use crate::data::Campaign;
use crate::error::Result;
use crate::identify::{yield_stress::eq6, CurrentIdentification};
use crate::model::PARAM_NAMES;

/// Label of a current level in file names, e.g. `I1.0A`.
pub fn current_tag(current_a: f64) -> String {
    format!("I{current_a:.1}A")
}

/// Writes `identification.parquet` with one row per run and quantity plus
/// the combined estimate (`run` = "all") per current.
pub fn write_table(path: &Path, results: &[CurrentIdentification]) -> Result<()> {
    let (mut run, mut current, mut parameter, mut value, mut raw) = (vec![], vec![], vec![], vec![], vec![]);
    let mut push = |r: &str, c: f64, p: &str, v: f64, rv: f64| {
        run.push(r.to_string());
        current.push(c);
        parameter.push(p.to_string());
        value.push(v);
        raw.push(rv);
    };
    for res in results {
        let c = res.current_a;
        for (i, r) in res.runs.iter().enumerate() {
            let (tau02, rate02) = r.yield_point.unwrap_or((f64::NAN, f64::NAN));
            for (name, v) in [("G", r.g), ("R1", r.r1), ("D1", r.d1), ("m1", r.m1), ("m2", r.m2)] {
                push(&r.run, c, name, v, v);
            }
            push(&r.run, c, "tau02_pa", tau02, tau02);
            push(&r.run, c, "gamma_i_rate_at_tau02", rate02, rate02);
            push(&r.run, c, "elastic_samples", r.elastic_points as f64, r.elastic_points as f64);
            if let Some(f) = &r.curve {
                for (name, v) in [("eq7_a", f.eq7.a), ("eq7_b", f.eq7.b), ("eq7_c", f.eq7.c), ("eq7_d", f.eq7.d), ("eq7_rms_pa", f.rms)] {
                    push(&r.run, c, name, v, v);
                }
                push(&r.run, c, "eq7_converged", f.converged as u8 as f64, f.converged as u8 as f64);
            }
            push(&r.run, c, "euler_rms_pa", res.euler_rms[i], res.euler_rms[i]);
        }
        for (k, name) in PARAM_NAMES.iter().enumerate() {
            push("all", c, name, res.params.to_array()[k], res.raw[k]);
        }
        push("all", c, "eq6_rms_log", res.yield_fit.rms_log, res.yield_fit.rms_log);
    }
    write_parquet(
        path,
        Table::new()
            .str("run", run)
            .f64("current_a", current)
            .str("parameter", parameter)
            .f64("value", value)
            .f64("raw_value", raw),
    )
}

/// The terminal table: one line per run and the combined estimate.
pub fn print_table(results: &[CurrentIdentification]) {
    for res in results {
        println!("\nidentification at {} A", res.current_a);
        println!(
            "{:<14} {:>9} {:>9} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>6} {:>9}",
            "run", "G", "tau02", "rate02", "R0", "R1", "D1", "m1", "m2", "n", "", "rms_pa"
        );
        for (i, r) in res.runs.iter().enumerate() {
            let (t, g) = r.yield_point.unwrap_or((f64::NAN, f64::NAN));
            println!(
                "{:<14} {:>9.3e} {:>9.3e} {:>8.1} {:>9} {:>9.3e} {:>9.3e} {:>9.3e} {:>9.3e} {:>9} {:>6} {:>9.1}",
                r.run, r.g, t, g, "", r.r1, r.d1, r.m1, r.m2, "", "", res.euler_rms[i]
            );
        }
        let p = res.params;
        println!(
            "{:<14} {:>9.3e} {:>9} {:>8} {:>9.3e} {:>9.3e} {:>9.3e} {:>9.3e} {:>9.3e} {:>9.3} {:>6}",
            "all", p.g, "", "", p.r0, p.r1, p.d1, p.m1, p.m2, p.n, "(SI)"
        );
        for w in &res.warnings {
            println!("  warning: {w}");
        }
        for r in &res.runs {
            for w in &r.warnings {
                println!("  warning: run {}: {w}", r.run);
            }
        }
    }
}

fn color(i: usize) -> plot::RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// The figures of the paper (Figs. 1–5) for every current level, as
/// `fig<k>_<name>_<current>.svg/.png` in `dir`.
pub fn write_figures(dir: &Path, campaign: &Campaign, results: &[CurrentIdentification]) -> Result<()> {
    for res in results {
        let tag = current_tag(res.current_a);
        let group = campaign.at_current(res.current_a);
        let at = format!("{} A", res.current_a);

        // Fig. 1: τ(γ) of the identified branch of each run
        let mut fig1 = Chart::new(format!("Fig. 1 — shear stress against strain, {at}"), "shear strain γ (-)", "shear stress τ (kPa)");
        for (i, (run, r)) in group.runs.iter().zip(&res.runs).enumerate() {
            let b = r.branch.clone();
            fig1.series.push(Series::line(
                Some(run.id().to_string()),
                color(i),
                run.shear.gamma[b.clone()].to_vec(),
                run.shear.tau[b].iter().map(|t| t * 1e-3).collect(),
            ).with_width(1));
        }
        fig1.legend_at = LegendAt::LowerRight;
        plot::save(&Figure::single(fig1), &dir.join(format!("fig1_tau_gamma_{tag}")))?;

        // Fig. 2: τ02 against γ̇ᴵ with eq. 6
        let pts: Vec<(f64, f64)> = res.runs.iter().filter_map(|r| r.yield_point.map(|(t, g)| (g, t))).collect();
        let mut fig2 = Chart::new(format!("Fig. 2 — yield stress at γᴵ = 0.2 % against inelastic rate, {at}"), "inelastic shear rate dγᴵ/dt (1/s)", "τ02 (kPa)");
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
            fig2.series.push(Series::points(Some("runs".into()), color(1), pts.iter().map(|p| p.0).collect(), pts.iter().map(|p| p.1 * 1e-3).collect()).with_width(5));
        }
        plot::save(&Figure::single(fig2), &dir.join(format!("fig2_yield_rate_{tag}")))?;

        // Fig. 3: τ(γᴵ) with the eq. 7 fit
        let mut fig3 = Chart::new(format!("Fig. 3 — stress against inelastic strain with eq. 7, {at}"), "inelastic shear strain γᴵ (-)", "shear stress τ (kPa)");
        fig3.log_x = true;
        fig3.legend_at = LegendAt::UpperLeft;
        for (i, r) in res.runs.iter().enumerate() {
            let (xs, ys) = &r.curve_data;
            fig3.series.push(Series::points(Some(format!("{} data", r.run)), color(i), xs.clone(), ys.iter().map(|y| y * 1e-3).collect()));
            if let Some(f) = &r.curve {
                fig3.series.push(Series::line(None, color(i), xs.clone(), xs.iter().map(|x| f.eq7.value(*x) * 1e-3).collect()));
            }
        }
        plot::save(&Figure::single(fig3), &dir.join(format!("fig3_tau_gamma_i_{tag}")))?;

        // Fig. 4: Euler solution against the data, one panel per run
        let panels: Vec<Chart> = group
            .runs
            .iter()
            .zip(&res.euler_tau)
            .zip(&res.euler_rms)
            .map(|((run, model), rms)| {
                let mut c = Chart::new(format!("Fig. 4 — {} (RMS {:.2} kPa)", run.id(), rms * 1e-3), "shear strain γ (-)", "shear stress τ (kPa)");
                c.legend_at = LegendAt::Middle;
                c.series.push(Series::line(Some("data".into()), GREY, run.shear.gamma.clone(), run.shear.tau.iter().map(|t| t * 1e-3).collect()).with_width(1));
                if !model.is_empty() {
                    c.series.push(Series::line(Some("B-P, Euler".into()), color(1), run.shear.gamma.clone(), model.iter().map(|t| t * 1e-3).collect()));
                }
                c
            })
            .collect();
        plot::save(&Figure::grid(panels, 3), &dir.join(format!("fig4_euler_{tag}")))?;

        // Fig. 5: ψ(τ) with both asymptotes, one panel per run
        let panels: Vec<Chart> = res
            .runs
            .iter()
            .map(|r| {
                let mut c = Chart::new(format!("Fig. 5 — ψ(τ), {}", r.run), "shear stress τ (kPa)", "hardening rate ψ = dτ/dWᴵ (-)");
                c.legend_at = LegendAt::UpperRight;
                let (t, p) = &r.psi;
                c.series.push(Series::line(Some("ψ from eq. 7".into()), color(0), t.iter().map(|v| v * 1e-3).collect(), p.clone()));
                if let Some((small, large)) = r.ends {
                    let (lo, hi) = (t[0], t[t.len() - 1]);
                    let line = |a: &crate::identify::hardening::Asymptote| {
                        (vec![lo * 1e-3, hi * 1e-3], vec![a.intercept - a.m * lo, a.intercept - a.m * hi])
                    };
                    let (x, y) = line(&small);
                    c.series.push(Series::dashed(Some(format!("small γᴵ: slope −m2, m2 = {:.2e}", small.m)), color(1), x, y));
                    let (x, y) = line(&large);
                    c.series.push(Series::dashed(Some(format!("large γᴵ: slope −m1, m1 = {:.2e}", large.m)), color(2), x, y));
                    let lo_y = p.iter().copied().fold(f64::INFINITY, f64::min);
                    let hi_y = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    let pad = 0.05 * (hi_y - lo_y).max(1e-12);
                    c.y_range = Some((lo_y - pad, hi_y + pad));
                }
                c
            })
            .collect();
        plot::save(&Figure::grid(panels, 3), &dir.join(format!("fig5_psi_{tag}")))?;
    }
    Ok(())
}
