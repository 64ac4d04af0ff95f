//! What a study with known truths says about the calibration, per
//! coordinate: how often the central 50 % and 90 % credible intervals hold
//! the truth (with the binomial standard error at the nominal share), the
//! spread of z = (mean − truth)/sd, and whether the ranks of the truths
//! among posterior draws are uniform (simulation-based calibration: χ² over
//! 10 bins). `collected/coverage.parquet` and `collected/ranks.svg`/`.png`.

use std::collections::BTreeMap;
use std::path::Path;

use statrs::distribution::{ChiSquared, ContinuousCDF};

use crate::error::Result;
use crate::plot::{self, Chart, Figure, Series, GREY, PALETTE};
use crate::store::{f64_column, read_parquet, str_column, Table};

/// Bins of the rank histograms.
pub const BINS: usize = 10;

/// One coordinate over the tasks that know its truth.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CoverageRow {
    pub parameter: String,
    pub tasks: usize,
    pub inside_50: f64,
    pub inside_90: f64,
    pub z_mean: f64,
    pub z_sd: f64,
    /// Rank histogram: counts per bin, χ² and its p-value.
    pub rank_counts: Vec<usize>,
    pub rank_chi2: f64,
    pub rank_p: f64,
}

impl CoverageRow {
    /// The binomial standard error of a share over these tasks at the
    /// nominal share `p`: how far a correct calibration's share strays.
    pub fn se_at(&self, p: f64) -> f64 {
        (p * (1.0 - p) / self.tasks.max(1) as f64).sqrt()
    }
}

/// Per coordinate, what the truths of one task say.
#[derive(Default)]
pub struct Tally {
    rows: BTreeMap<String, (Vec<f64>, usize, usize, Vec<usize>)>,
}

impl Tally {
    /// Adds the rows of a task's `result.parquet`.
    pub fn add(&mut self, path: &Path) -> Result<()> {
        let df = read_parquet(path)?;
        let names = str_column(&df, "parameter", path)?;
        let truth = f64_column(&df, "truth", path)?;
        let z = f64_column(&df, "z", path)?;
        let i50 = f64_column(&df, "inside_50", path)?;
        let i90 = f64_column(&df, "inside_90", path)?;
        let rank = f64_column(&df, "rank", path)?;
        let draws = f64_column(&df, "rank_draws", path)?;
        for k in 0..names.len() {
            if !truth[k].is_finite() {
                continue;
            }
            let e =
                self.rows.entry(names[k].clone()).or_insert_with(|| (vec![], 0, 0, vec![0; BINS]));
            e.0.push(z[k]);
            e.1 += (i50[k] != 0.0) as usize;
            e.2 += (i90[k] != 0.0) as usize;
            let bin = ((rank[k] * BINS as f64 / (draws[k] + 1.0)) as usize).min(BINS - 1);
            e.3[bin] += 1;
        }
        Ok(())
    }

    pub fn rows(&self) -> Vec<CoverageRow> {
        let chi2 = ChiSquared::new((BINS - 1) as f64).expect("positive degrees of freedom");
        self.rows
            .iter()
            .map(|(name, (z, i50, i90, counts))| {
                let n = z.len() as f64;
                let mean = z.iter().sum::<f64>() / n;
                let sd =
                    (z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
                let expected = n / BINS as f64;
                let stat: f64 =
                    counts.iter().map(|c| (*c as f64 - expected).powi(2) / expected).sum();
                CoverageRow {
                    parameter: name.clone(),
                    tasks: z.len(),
                    inside_50: *i50 as f64 / n,
                    inside_90: *i90 as f64 / n,
                    z_mean: mean,
                    z_sd: sd,
                    rank_counts: counts.clone(),
                    rank_chi2: stat,
                    rank_p: 1.0 - chi2.cdf(stat),
                }
            })
            .collect()
    }
}

/// Writes `coverage.parquet` and the rank histograms into `out`.
pub fn write(out: &Path, rows: &[CoverageRow]) -> Result<()> {
    let col = |f: &dyn Fn(&CoverageRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    let table = Table::new()
        .str("parameter", rows.iter().map(|r| r.parameter.clone()).collect())
        .i64("tasks", rows.iter().map(|r| r.tasks as i64).collect())
        .f64("inside_50", col(&|r| r.inside_50))
        .f64("inside_90", col(&|r| r.inside_90))
        .f64("se_50", col(&|r| r.se_at(0.5)))
        .f64("se_90", col(&|r| r.se_at(0.9)))
        .f64("z_mean", col(&|r| r.z_mean))
        .f64("z_sd", col(&|r| r.z_sd))
        .f64("rank_chi2", col(&|r| r.rank_chi2))
        .f64("rank_p", col(&|r| r.rank_p));
    crate::store::write_parquet(&out.join("coverage.parquet"), table)?;
    let panels: Vec<Chart> = rows
        .iter()
        .map(|r| {
            let n = r.tasks as f64;
            let expected = n / BINS as f64;
            let edges: Vec<f64> = (0..=BINS).map(|b| b as f64 / BINS as f64).collect();
            let mut c = Chart::new(
                format!("{}: p = {:.2}", r.parameter, r.rank_p),
                "rank / (L + 1)",
                "tasks",
            );
            c.series.push(Series::bars(
                None,
                PALETTE[0],
                edges,
                r.rank_counts.iter().map(|c| *c as f64).collect(),
            ));
            // where a uniform histogram's bins stay 99 % of the time (binomial)
            let sd = (n * (1.0 / BINS as f64) * (1.0 - 1.0 / BINS as f64)).sqrt();
            for level in [expected - 2.58 * sd, expected, expected + 2.58 * sd] {
                c.series.push(Series::dashed(None, GREY, vec![0.0, 1.0], vec![level, level]));
            }
            c.legend = false;
            c
        })
        .collect();
    if !panels.is_empty() {
        plot::save(&Figure::grid(panels, 4), &out.join("ranks"))?;
    }
    Ok(())
}
