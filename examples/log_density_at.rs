//! A calibration's posterior log-density at points of your own: the input
//! of an independent check of its chains (importance sampling,
//! `benches/reference/importance_sampling.py`).
//!
//! `cargo run --release --example log_density_at -- DIR MODE < points.csv`
//! with DIR a calibration folder and MODE
//! - `names`: prints the coordinates' names in order (SI units);
//! - `si`: reads points in SI (one per line, comma-separated, in that
//!   order), prints each in the sampler's coordinates followed by its
//!   log-density there (Jacobian included);
//! - `x`: reads points in the sampler's coordinates, prints them and their
//!   log-density;
//! - `to-si`: reads points in the sampler's coordinates, prints them in SI.
//!
//! The posterior is the calibration's own: its settings, its runs, its step
//! rule's sub-steps.
use std::io::BufRead;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, dir, mode] = &args[..] else {
        eprintln!("usage: log_density_at DIR names|si|x|to-si < points");
        std::process::exit(2);
    };
    let cal = mrbp::store::folder::read(std::path::Path::new(dir))
        .unwrap_or_else(|e| fail(&e.to_string()));
    let campaign = cal.campaign().unwrap_or_else(|e| fail(&e.to_string()));
    let posterior =
        cal.settings.posterior(&cal.used_runs(&campaign), cal.predict_settings(1, 1).integrator);
    let layout = &posterior.layout;
    let line = |v: &[f64]| v.iter().map(|x| format!("{x:.17e}")).collect::<Vec<_>>().join(",");
    if mode == "names" {
        println!("{}", layout.names.join(","));
        return;
    }
    let points: Vec<Vec<f64>> = std::io::stdin()
        .lock()
        .lines()
        .map(|l| {
            l.unwrap_or_else(|e| fail(&e.to_string()))
                .split(',')
                .map(|v| {
                    v.trim().parse::<f64>().unwrap_or_else(|_| fail(&format!("not a number: {v}")))
                })
                .collect()
        })
        .collect();
    if let Some(p) = points.iter().find(|p| p.len() != layout.names.len()) {
        fail(&format!(
            "a point of {} values; the posterior has {} coordinates",
            p.len(),
            layout.names.len()
        ));
    }
    match mode.as_str() {
        "to-si" => points.iter().for_each(|p| println!("{}", line(&layout.to_si(p)))),
        "si" | "x" => {
            let xs: Vec<Vec<f64>> = points
                .iter()
                .map(|p| if mode == "si" { layout.from_si(p) } else { p.clone() })
                .collect();
            let flat: Vec<f64> = xs.iter().flatten().copied().collect();
            for (x, lp) in xs.iter().zip(mrbp::sampler::density::log_densities(&posterior, &flat)) {
                println!("{},{lp:.17e}", line(x));
            }
        }
        _ => fail(&format!("unknown mode {mode}: names, si, x or to-si")),
    }
}

fn fail(message: &str) -> ! {
    eprintln!("log_density_at: {message}");
    std::process::exit(2)
}
