//! Comparing calibration folders.

use std::path::{Path, PathBuf};

use super::{Event, Pipeline};
use crate::calibrate::Calibration;
use crate::compare::{self, Comparison};
use crate::error::{Error, Result};
use crate::predict::Prediction;
use crate::report::comparison::Entry;
use crate::store;
use crate::store::comparison::{Compared, ComparisonRecord};

/// Posterior draws per calibration for differences and figures.
const DRAWS: usize = 4000;

/// A calibration as a comparison takes it, with its bands if it has them.
pub(super) fn entry(cal: Calibration, prediction: Option<Prediction>) -> Entry {
    Entry {
        label: cal.label(),
        positions: cal.draw_positions(DRAWS),
        cal,
        prediction,
        evidence: None,
    }
}

/// The between-run layer's centre in a calibration's folder, where it has
/// a whole one (`--per-run`) derived from it.
fn layer_centre(cal: &Calibration) -> Option<compare::LayerCentre> {
    if !cal.dir.join(store::between_runs::FILE).exists() {
        return None;
    }
    let names = cal.sample.layout.theta_names();
    let table = store::between_runs::read(&cal.dir, &cal.record.calibration_id, names).ok()?;
    Some(compare::LayerCentre {
        draw: table.draw,
        names: names.to_vec(),
        centre: table.centre,
        fit: table.fit,
    })
}

impl Pipeline<'_> {
    /// `comparison.parquet`, `differences.parquet`, the figures and
    /// `report.html` of the calibrations in `dirs`, into `out`. `rpm` picks
    /// the runs whose bands are overlaid. Returns the report's path.
    pub fn compare(&mut self, dirs: &[PathBuf], out: &Path, rpm: Option<f64>) -> Result<PathBuf> {
        if dirs.len() < 2 {
            return Err(Error::Usage("compare needs at least two calibration folders".into()));
        }
        let mut entries = Vec::new();
        for d in dirs {
            let _reading = crate::lock::read(d)?;
            let cal = store::folder::read(d)?;
            // bands made from other chains than the folder's are left out
            let prediction = store::prediction::read(d)?
                .filter(|p| p.record.calibration_id == cal.record.calibration_id);
            entries.push(entry(cal, prediction));
        }
        self.compare_entries(entries, out, rpm)
    }

    /// Each entry's log evidence: sequential Monte Carlo's where it was
    /// sampled so; by bridge sampling where another entry calibrates the
    /// same runs (evidences of different runs do not compare: they are
    /// not computed); where that fails, a note and none.
    fn estimate_evidences(&mut self, entries: &mut [Entry]) {
        let runs: Vec<Vec<String>> = entries.iter().map(|e| e.cal.record.runs.clone()).collect();
        for (i, e) in entries.iter_mut().enumerate() {
            if let Some(recorded) = crate::calibrate::evidence::by_smc(&e.cal) {
                e.evidence = Some(recorded);
                continue;
            }
            if !runs.iter().enumerate().any(|(j, r)| j != i && *r == runs[i]) {
                continue;
            }
            let estimated = e
                .cal
                .campaign()
                .and_then(|campaign| crate::calibrate::evidence::estimate(&e.cal, &campaign));
            match estimated {
                Ok(estimate) => e.evidence = Some(estimate),
                Err(why) => self.note(&format!("{}: no log evidence ({why})", e.label)),
            }
        }
    }

    /// [`Pipeline::compare`] of calibrations already at hand.
    pub(super) fn compare_entries(
        &mut self,
        mut entries: Vec<Entry>,
        out: &Path,
        rpm: Option<f64>,
    ) -> Result<PathBuf> {
        // folders of one name in different places: tell them apart by path
        let dirs: Vec<&Path> = entries.iter().map(|e| e.cal.dir.as_path()).collect();
        let labels = distinct_labels(&dirs);
        for (e, label) in entries.iter_mut().zip(labels) {
            e.label = label;
        }
        self.prepare(out, "--out", &[], &[], true)?;
        self.estimate_evidences(&mut entries);
        let record = ComparisonRecord {
            mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
            command: crate::calibrate::command_line(),
            compared: entries
                .iter()
                .map(|e| Compared::new(&e.label, &e.cal.dir, &e.cal.record.calibration_id, out))
                .collect(),
        };
        let tables: Vec<compare::Entry> = entries
            .iter()
            .map(|e| compare::Entry {
                label: e.label.clone(),
                current_a: e.cal.record.current_a,
                summary: &e.cal.summary,
                sample: &e.cal.sample,
                positions: e.positions.clone(),
                law_currents: if e.cal.is_current_law() {
                    e.cal.record.currents.clone()
                } else {
                    Vec::new()
                },
                layer: layer_centre(&e.cal),
            })
            .collect();
        let comparison = Comparison::of(&tables);
        store::comparison::retire(out)?;
        store::comparison::write(out, &comparison, &store::comparison::ids_text(&record))?;
        // the between-run layer's typical test against the current, from the
        // first folder that holds one
        let typical = entries.iter().find_map(|e| {
            store::between_runs::read_typical(&e.cal.dir, &e.cal.record.calibration_id)
                .ok()
                .flatten()
        });
        let path =
            crate::report::comparison::write(out, &entries, &comparison, rpm, typical.as_deref())?;
        store::comparison::write_record(out, &record)?;
        self.emit(Event::Wrote(&path));
        Ok(path)
    }
}

/// A label for each folder: its name, or where names repeat, as many of
/// its path's last components as tell it from the others ("bouc-wen/I0.7A"
/// beside "bp-viscous/I0.7A"), its whole path at most.
fn distinct_labels(dirs: &[&Path]) -> Vec<String> {
    let tail = |dir: &Path, k: usize| -> String {
        let parts: Vec<_> = dir.components().collect();
        match parts.len() > k {
            true => parts[parts.len() - k..].iter().collect::<PathBuf>().display().to_string(),
            false => dir.display().to_string(),
        }
    };
    let mut depth = vec![1; dirs.len()];
    loop {
        let labels: Vec<String> = dirs.iter().zip(&depth).map(|(d, &k)| tail(d, k)).collect();
        let repeated: Vec<usize> = (0..labels.len())
            .filter(|&i| labels.iter().filter(|l| **l == labels[i]).count() > 1)
            .filter(|&i| depth[i] < dirs[i].components().count())
            .collect();
        if repeated.is_empty() {
            return labels;
        }
        for i in repeated {
            depth[i] += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names that repeat take as much of their paths as tells them apart;
    /// a name alone stays as it is.
    #[test]
    fn repeated_folder_names_are_told_apart_by_their_paths() {
        let dirs = [
            Path::new("runs/bouc-wen/I0.7A"),
            Path::new("runs/bp-viscous/I0.7A"),
            Path::new("runs/bouc-wen/I1.0A"),
            Path::new("a/x/I0.5A"),
            Path::new("b/x/I0.5A"),
        ];
        assert_eq!(
            distinct_labels(&dirs),
            ["bouc-wen/I0.7A", "bp-viscous/I0.7A", "I1.0A", "a/x/I0.5A", "b/x/I0.5A"]
        );
        // the same folder twice: its whole path, no endless search
        let same = [Path::new("r/I1.0A"), Path::new("r/I1.0A")];
        assert_eq!(distinct_labels(&same), ["r/I1.0A", "r/I1.0A"]);
    }
}
