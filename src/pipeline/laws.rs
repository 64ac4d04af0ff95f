//! Damper laws side by side: the whole job of each law on one campaign,
//! then their standings on the same records (`mrbp run --law A,B,…`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::{Pipeline, RunOptions};
use crate::data::current_tag;
use crate::error::{Error, Result};
use crate::laws::LawKind;
use crate::predict::RunBands;
use crate::store;
use crate::validate::laws::{measures, standings, Kind, LawEvidence, LawRow};

/// The study's folder in a run's `--out`.
pub const FOLDER: &str = "laws";

impl Pipeline<'_> {
    /// Each of the laws `options.sample.laws` through the whole job on the
    /// campaign of `manifest`, into `out/<law>/` (one calibration folder per
    /// current, with its bands, leave-one-out and report, as `run` makes
    /// for one law); then `out/laws/`: `laws.parquet` (every law, current,
    /// record, in sample and held out) and `report.html`, which ranks the
    /// laws current by current by what they predict of records they did
    /// not see. Returns the reports written.
    pub fn run_laws(
        &mut self,
        manifest: &Path,
        out: &Path,
        options: &RunOptions,
    ) -> Result<Vec<PathBuf>> {
        let campaign = self.check(manifest)?;
        let currents = match options.sample.current {
            Some(c) => vec![c],
            None => campaign.currents(),
        };
        // the ranking is by tests held out at each current: refused before
        // any calibration where a current has nothing to hold out
        if options.leave_one_out.is_some() {
            if let Some((c, only)) =
                currents.iter().find_map(|&c| match &campaign.at_current(c).runs[..] {
                    [only] => Some((c, only.spec.id.clone())),
                    _ => None,
                })
            {
                return Err(Error::Usage(format!(
                    "--law {} --leave-one-out ranks the laws by the tests held out at each current, and at {c} A there is a single run ({only}): nothing to hold out. Pick currents with two runs or more (--current), or drop --leave-one-out to compare the laws in sample and by their log evidence",
                    options.sample.laws.iter().map(|l| l.name()).collect::<Vec<_>>().join(",")
                )));
            }
        }
        let study = out.join(FOLDER);
        self.prepare(&study, "--out", &[&campaign], &[], true)?;
        let mut reports = Vec::new();
        let mut job_seconds = Vec::new();
        for &law in &options.sample.laws {
            let mut one = options.clone();
            one.sample.settings.set_law(law);
            one.sample.laws = vec![law];
            // the study ranks by held-out runs; each run alone only where asked
            one.sample.per_run_where_memory = false;
            // the current law is the B-P law's
            one.current_law = options.current_law && law.is_bodner_partom();
            self.note(&format!("the {} law:", law.name()));
            let clock = Instant::now();
            reports.extend(self.run(manifest, &out.join(law.name()), &one)?);
            job_seconds.push((law, clock.elapsed().as_secs_f64()));
        }
        let held_out = options.leave_one_out.is_some();
        let mut rows = Vec::new();
        let mut ids = Vec::new();
        let mut predictions: Vec<(LawKind, Vec<RunBands>)> = Vec::new();
        let mut evidence = Vec::new();
        for &law in &options.sample.laws {
            let mut shown = Vec::new();
            for &c in &currents {
                let dir = out.join(law.name()).join(current_tag(c));
                let cal = store::folder::read(&dir)?;
                let seconds = cal.record.seconds_start + cal.record.seconds_sampling;
                match crate::calibrate::evidence::estimate(&cal, &campaign) {
                    Ok(e) => evidence.push((law, c, LawEvidence::from(&e))),
                    Err(e) => self
                        .note(&format!("the {} law at {c} A has no log evidence: {e}", law.name())),
                }
                ids.push((
                    format!("{}/{}", law.name(), current_tag(c)),
                    cal.record.calibration_id.clone(),
                ));
                let area = campaign.geometry.area_m2;
                let prediction = store::prediction::read(&dir)?.ok_or_else(|| {
                    Error::Compute(format!("{}: no bands to judge the law by", dir.display()))
                })?;
                for (b, cov) in prediction.bands.iter().zip(&prediction.coverage) {
                    rows.push(row(law, c, b, Kind::InSample, cov.lppd, seconds, area));
                }
                if held_out {
                    let loo =
                        store::coverage::read_leave_one_out(&dir, &cal.record.calibration_id)?
                            .ok_or_else(|| {
                                Error::Compute(format!("{}: no leave-one-out study", dir.display()))
                            })?;
                    // bands only for the runs that could be held out
                    for b in &loo.bands {
                        let held = loo.rows.iter().find(|r| r.coverage.run == b.run);
                        let lppd = held.map_or(f64::NAN, |r| r.coverage.lppd);
                        let mut held_out = row(law, c, b, Kind::HeldOut, lppd, seconds, area);
                        held_out.held_out_rhat = held.map_or(f64::NAN, |r| r.max_rhat);
                        held_out.held_out_unconverged = held.and_then(|r| r.unconverged.clone());
                        rows.push(held_out);
                    }
                    shown.extend(loo.bands);
                } else {
                    shown.extend(prediction.bands);
                }
            }
            predictions.push((law, shown));
        }
        let evidence_at = |law: LawKind, c: f64| {
            evidence.iter().find(|(l, at, _)| *l == law && *at == c).map(|e| e.2)
        };
        for r in &mut rows {
            r.evidence = evidence_at(r.law, r.current_a);
        }
        let mut standings = if held_out { standings(&rows)? } else { Vec::new() };
        for s in &mut standings {
            s.evidence = evidence_at(s.law, s.current_a);
        }
        store::laws::write(&study.join(store::laws::FILE), &rows, &ids)?;
        for line in crate::validate::laws::verdict(&standings) {
            self.note(&line);
        }
        let laws: Vec<String> = options.sample.laws.iter().map(|l| l.name()).collect();
        let command = format!(
            "mrbp run {} --law {} --out {}{}",
            manifest.display(),
            laws.join(","),
            out.display(),
            if held_out { " --leave-one-out" } else { "" }
        );
        let report = crate::report::laws::write(&crate::report::laws::LawsReport {
            dir: &study,
            campaign: &campaign.name,
            rows: &rows,
            standings: &standings,
            predictions: &predictions,
            area_m2: campaign.geometry.area_m2,
            job_seconds: &job_seconds,
            command: &command,
            held_out,
            calibration_ids: &ids,
        })?;
        self.note(&format!(
            "wrote {} and {}",
            study.join(store::laws::FILE).display(),
            report.display()
        ));
        reports.push(report);
        Ok(reports)
    }
}

/// One record's row: its error measures from `bands`, its lppd.
fn row(
    law: LawKind,
    current_a: f64,
    bands: &RunBands,
    kind: Kind,
    lppd: f64,
    seconds: f64,
    area_m2: f64,
) -> LawRow {
    LawRow {
        law,
        current_a,
        run: bands.run.clone(),
        kind,
        measures: measures(bands, area_m2),
        lppd,
        seconds,
        evidence: None,
        held_out_rhat: f64::NAN,
        held_out_unconverged: None,
    }
}
