//! The figure of a simulation (`mrbp simulate`): the force of the
//! calibrated damper along the user's excitation, against time and against
//! displacement, with its bands, and the coil current where it changes.

use std::path::Path;

use super::figures::{coil_current, every, loop_band, MAX_VERTICES};
use crate::error::Result;
use crate::plot::{self, Chart, Figure, LegendAt, Series, PALETTE};
use crate::store::simulation::Simulation;

/// The figure's file stem in the simulation's folder.
pub const FIGURE: &str = "simulation";

/// Draws `simulation.svg` and `.png` into `dir`; `calibration` names the
/// posterior in the title.
pub fn write(dir: &Path, s: &Simulation, calibration: &str) -> Result<()> {
    let r = &s.record;
    let thin = every(s.time.len(), MAX_VERTICES);
    let pick =
        |v: &[f64], scale: f64| v.iter().step_by(thin).map(|y| y * scale).collect::<Vec<f64>>();
    let force = |v: &[f64]| pick(v, r.area_m2);
    let panel = |title: &str, x_label: &str, x: Vec<f64>, looped: bool, legend_at: LegendAt| {
        let mut c = Chart::new(title, x_label, "force F = τA (N)");
        let band = |label: &str, color, lo: &[f64], hi: &[f64], opacity: f64| -> Vec<Series> {
            if looped {
                loop_band(label, color, &x, &force(lo), &force(hi), opacity)
            } else {
                vec![Series::band(Some(label.to_string()), color, x.clone(), force(lo), force(hi))
                    .with_opacity(opacity)]
            }
        };
        c.series
            .extend(band("95 % predictive", PALETTE[5], &s.predictive[0], &s.predictive[1], 0.25));
        c.series.extend(band("95 % model", PALETTE[0], &s.model[0], &s.model[4], 0.35));
        c.series.extend(band("50 % model", PALETTE[0], &s.model[1], &s.model[3], 0.6));
        c.series.push(
            Series::line(
                Some("posterior median".into()),
                PALETTE[1],
                x.clone(),
                force(&s.model[2]),
            )
            .with_width(1),
        );
        c.legend_at = legend_at;
        c
    };
    // the posterior named over time, the current over displacement: each
    // title fits its panel
    let mut extrapolated = if r.extrapolated { ", extrapolated" } else { "" }.to_string();
    if !r.beyond_records.is_empty() {
        extrapolated += &format!(", beyond records: {}", r.beyond_records.join(", "));
    }
    let current = if r.current_varies {
        let (lo, hi) = s
            .current
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &c| (a.min(c), b.max(c)));
        format!("{lo}–{hi} A{extrapolated}")
    } else {
        format!("{} A{extrapolated}", r.current_a)
    };
    let in_time = panel(
        &format!("{calibration}: force against time"),
        "time t (s)",
        pick(&s.time, 1.0),
        false,
        LegendAt::UpperRight,
    );
    let in_x = panel(
        &format!("force against displacement ({current})"),
        "displacement x (mm)",
        pick(&s.displacement, 1e3),
        true,
        LegendAt::Middle,
    );
    let mut panels = vec![in_time, in_x];
    // the current it was driven along, where it changes, under the force
    // against time
    if r.current_varies {
        panels.push(coil_current("the coil current commanded", &s.time, &s.current));
    }
    plot::save(&Figure::grid(panels, 2), &dir.join(FIGURE))
}
