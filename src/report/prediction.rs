//! The report of a calibration predicting another campaign's runs
//! (`mrbp predict DIR --campaign MANIFEST`): how well the band holds records
//! the calibration never saw, and where the law misses them.

use std::path::{Path, PathBuf};

use super::adequacy;
use super::calibration::coverage_table;
use super::figures::{self, Figures};
use super::html::{esc, Page};
use crate::atomic;
use crate::calibrate::Calibration;
use crate::data::Campaign;
use crate::error::Result;
use crate::predict::Prediction;

/// What the report shows.
pub struct PredictionReport<'a> {
    pub cal: &'a Calibration,
    /// The runs predicted.
    pub campaign: &'a Campaign,
    /// Where the bands and the report go.
    pub dir: &'a Path,
    pub prediction: &'a Prediction,
}

/// Writes the figures and `report.html` into the prediction's folder.
pub fn write(r: &PredictionReport) -> Result<PathBuf> {
    let (cal, dir, p) = (r.cal, r.dir, r.prediction);
    let geometry = r.campaign.geometry;
    atomic::remove(&dir.join(super::html::REPORT))?;
    let mut figs = Figures::default();
    figures::bands(dir, &p.bands, geometry.area_m2, geometry.gap_m, &mut figs)?;
    figures::residuals(dir, &p.bands, &mut figs)?;
    let what = if cal.is_current_law() {
        format!("the current law calibrated on {:?} A", cal.record.currents)
    } else {
        format!("the calibration at {} A", cal.record.current_a)
    };
    let mut page = Page::new(&format!("mrbp prediction: {} by {}", r.campaign.name, what));
    page.derived_from(&cal.record.calibration_id);
    let unseen = p.coverage.iter().filter(|c| !c.calibrated).count();
    page.para(&format!(
        "{} run(s) of the campaign {} ({}) predicted by {what} in {} ({} posterior draws, {} noise replicates each); {unseen} of them \
         the calibration never saw. A run it never saw gets the typical noise level and force offset of the runs it did see.",
        p.coverage.len(),
        esc(&r.campaign.name),
        esc(&r.campaign.manifest_path.display().to_string()),
        esc(&cal.dir.display().to_string()),
        p.record.draws,
        p.record.noise_replicates
    ));
    page.section("coverage", "Coverage");
    coverage_table(&mut page, &p.coverage, false);
    adequacy::section(&mut page, dir, &p.bands, &p.adequacy, &geometry, &cal.settings.likelihood)?;
    page.section("figures", "Figures");
    for (stem, caption) in &figs.items {
        page.figure(&dir.join(format!("{stem}.png")), caption)?;
    }
    page.section("reproduce", "Reproduce");
    page.pre(&p.record.command);
    let path = dir.join(super::html::REPORT);
    atomic::write(&path, page.finish().as_bytes())?;
    Ok(path)
}
