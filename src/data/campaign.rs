//! The campaign manifest (TOML) and loading a whole campaign.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::branches::{loading_branches, REVERSAL_SHARE};
use super::shear::{Geometry, Shear};
use super::table::{sampling_step, ColumnMap, Columns, Limits, Record};
use crate::error::{one_line, Error, Result};

/// The manifest file as written by the user (contract.md).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub name: String,
    pub geometry: Geometry,
    #[serde(default)]
    pub columns: Columns,
    /// Plausible magnitudes: a value beyond them is an input error.
    #[serde(default, skip_serializing_if = "Limits::is_default")]
    pub limits: Limits,
    #[serde(rename = "run", default)]
    pub runs: Vec<RunSpec>,
}

/// The file's current column may differ from the manifest's current_a by
/// this much (A) or this share of it, whichever is larger: sensor ripple.
const CURRENT_AGREEMENT: (f64, f64) = (0.05, 0.05);

/// One `[[run]]` entry of the manifest.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RunSpec {
    pub id: String,
    /// Relative to the manifest.
    pub file: PathBuf,
    pub current_a: f64,
    /// Nominal shear rate (1/s), for labels only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shear_rate: Option<f64>,
    /// Shear stress at the first sample (Pa); the fluid is at rest and
    /// unstressed (0) unless the run says otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_stress_pa: Option<f64>,
    /// The coil current changes within the record: the law follows the
    /// file's current column sample by sample, and `current_a` is the run's
    /// nominal current (a label). Only a law (current law, current curves)
    /// calibrates or predicts such a run.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub current_varies: bool,
}

impl RunSpec {
    /// A run of one current, with the defaults of the optional fields.
    pub fn new(id: String, file: PathBuf, current_a: f64) -> RunSpec {
        RunSpec {
            id,
            file,
            current_a,
            shear_rate: None,
            initial_stress_pa: None,
            current_varies: false,
        }
    }
}

/// How many times the median sampling interval an interval may be before
/// loading says samples seem missing ([`Run::gap`]).
pub const GAP_FACTOR: f64 = 5.0;

/// One loaded run: its manifest entry, its record and what follows from it.
#[derive(Clone, Debug)]
pub struct Run {
    pub spec: RunSpec,
    /// Absolute or manifest-relative path of the data file, as opened.
    pub path: PathBuf,
    pub record: Record,
    pub shear: Shear,
    /// Loading branches: sample ranges between displacement reversals.
    pub branches: Vec<std::ops::Range<usize>>,
    /// The damper's geometry (the campaign's).
    pub geometry: Geometry,
}

impl Run {
    pub fn id(&self) -> &str {
        &self.spec.id
    }

    /// The run of `spec` from its `record` (read from, or named as,
    /// `path`), checked against the manifest's limits and current.
    fn checked(
        spec: &RunSpec,
        path: PathBuf,
        record: Record,
        manifest: &Manifest,
        map: &ColumnMap,
    ) -> Result<Run> {
        record.check_limits(&path, map, &manifest.limits)?;
        match &record.current {
            Some(current) => check_current(&path, map, spec, current)?,
            None if spec.current_varies => {
                return Err(Error::input_at(
                    &path,
                    None,
                    Some(map.current),
                    format!("missing: run '{}' has current_varies = true, so its file needs the current column", spec.id),
                ))
            }
            None => {}
        }
        let shear = Shear::from_record(&record, &manifest.geometry, spec.initial_stress_pa);
        let branches = loading_branches(&record.displacement, REVERSAL_SHARE);
        Ok(Run { spec: spec.clone(), path, record, shear, branches, geometry: manifest.geometry })
    }

    /// Where the record's samples seem missing: its longest sampling
    /// interval if that is more than [`GAP_FACTOR`] times the median one (a
    /// logger that dropped a block). Not refused — a record may change its
    /// rate on purpose — but said, because the law is driven across such a
    /// gap by a straight line between the samples either side of it.
    pub fn gap(&self) -> Option<String> {
        let t = &self.record.time;
        let (median, _) = sampling_step(t);
        let limit = GAP_FACTOR * median;
        let dt = t.windows(2).map(|w| w[1] - w[0]);
        let wider = dt.clone().filter(|d| *d > limit).count();
        let (at, longest) = dt.enumerate().max_by(|a, b| a.1.total_cmp(&b.1))?;
        (wider > 0).then(|| {
            format!(
                "run '{}': {} of its sampling intervals {} more than {GAP_FACTOR} times the median one ({:.3e} s), the longest {:.4} s from t = {:.4} s: samples missing? The law is driven across such a gap by a straight line between the samples either side; cut the record there (two runs) if the damper moved meanwhile",
                self.id(),
                wider,
                if wider == 1 { "is" } else { "are" },
                median,
                longest,
                t[at],
            )
        })
    }

    /// What loading says of the run without refusing it: samples that seem
    /// missing, and why it cannot be identified or calibrated.
    pub fn notes(&self) -> impl Iterator<Item = String> {
        self.gap().into_iter().chain(self.unusable())
    }

    /// Why the run cannot be identified or calibrated, if it cannot: no
    /// motion (no loading branch) or no force signal.
    pub fn unusable(&self) -> Option<String> {
        let span = |v: &[f64]| {
            v.iter().fold(f64::NEG_INFINITY, |m, x| m.max(*x))
                - v.iter().fold(f64::INFINITY, |m, x| m.min(*x))
        };
        if span(&self.record.displacement) == 0.0 || self.branches.is_empty() {
            Some(format!("run '{}': the displacement never changes direction or never moves (no loading branch)", self.id()))
        } else if span(&self.record.force) == 0.0 {
            Some(format!("run '{}': the force is constant (no force signal)", self.id()))
        } else {
            None
        }
    }
}

/// A validated campaign with every record loaded.
#[derive(Clone, Debug)]
pub struct Campaign {
    pub name: String,
    pub manifest_path: PathBuf,
    pub geometry: Geometry,
    pub columns: Columns,
    /// The runs, shared: a campaign filtered to some runs holds the same
    /// records, not copies.
    pub runs: Vec<Arc<Run>>,
    /// What loading noticed but did not refuse (files outside the
    /// manifest's folder, runs without motion or force).
    pub notes: Vec<String>,
}

impl Manifest {
    /// Writes the manifest to `path`, after the comment lines `header`.
    pub fn write(&self, path: &Path, header: &str) -> Result<()> {
        let body = toml::to_string(self)
            .map_err(|e| Error::Compute(format!("writing {}: {e}", path.display())))?;
        crate::atomic::write(path, format!("{header}{body}").as_bytes())
    }

    /// Reads and checks a manifest without opening the data files.
    pub fn read(path: &Path) -> Result<Manifest> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            Error::input(
                path,
                match e.kind() {
                    std::io::ErrorKind::NotFound => "manifest not found".to_string(),
                    _ => format!("cannot read the manifest: {e}"),
                },
            )
        })?;
        let manifest: Manifest = toml::from_str(&text).map_err(|e| {
            Error::input(path, format!("invalid manifest: {}", one_line(&e.to_string())))
        })?;
        manifest.check(path)?;
        Ok(manifest)
    }

    /// Checks a manifest; `path` names it in messages.
    pub fn check(&self, path: &Path) -> Result<()> {
        let positive = |value: f64, what: &str| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(Error::input(path, format!("{what} must be positive, got {value}")))
            }
        };
        positive(self.geometry.area_m2, "geometry.area_m2")?;
        positive(self.geometry.gap_m, "geometry.gap_m")?;
        positive(self.columns.time_scale, "columns.time_scale")?;
        positive(self.columns.displacement_scale, "columns.displacement_scale")?;
        positive(self.columns.force_scale, "columns.force_scale")?;
        positive(self.limits.force_n, "limits.force_n")?;
        positive(self.limits.displacement_m, "limits.displacement_m")?;
        positive(self.limits.time_s, "limits.time_s")?;
        positive(self.limits.current_a, "limits.current_a")?;
        if self.name.trim().is_empty() {
            return Err(Error::input(path, "name must not be empty"));
        }
        if self.runs.is_empty() {
            return Err(Error::input(path, "the manifest lists no [[run]]"));
        }
        let mut seen = HashSet::new();
        for run in &self.runs {
            if run.id.trim().is_empty() {
                return Err(Error::input(path, "a run has an empty id"));
            }
            if !seen.insert(run.id.as_str()) {
                return Err(Error::input(path, format!("duplicate run id '{}'", run.id)));
            }
            if !(run.current_a.is_finite() && run.current_a >= 0.0) {
                return Err(Error::input(
                    path,
                    format!("run '{}': current_a must be a non-negative number", run.id),
                ));
            }
            if let Some(rate) = run.shear_rate {
                positive(rate, &format!("run '{}': shear_rate", run.id))?;
            }
            if let Some(s) = run.initial_stress_pa {
                if !s.is_finite() {
                    return Err(Error::input(
                        path,
                        format!("run '{}': initial_stress_pa must be finite", run.id),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Whether `file` lies outside the folder `dir` (by its path, after
/// resolving both where they exist).
fn outside(dir: &Path, file: &Path) -> bool {
    let resolve = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let dir = resolve(if dir.as_os_str().is_empty() { Path::new(".") } else { dir });
    !resolve(file).starts_with(&dir)
}

/// A current that changes along a record (its `column` in `path`) must be
/// a coil current: 0 A or more at every sample.
pub fn check_coil_current(path: &Path, column: &str, current: &[f64]) -> Result<()> {
    match current.iter().position(|v| !(*v >= 0.0)) {
        Some(k) => Err(Error::input_at(
            path,
            Some(k + 1),
            Some(column),
            format!("{} A: the law takes a coil current of 0 A or more", current[k]),
        )),
        None => Ok(()),
    }
}

/// The file's current column must agree with the manifest's current_a,
/// or, where the current varies, be a coil current (0 A or more).
fn check_current(path: &Path, map: &ColumnMap, spec: &RunSpec, current: &[f64]) -> Result<()> {
    if spec.current_varies {
        return check_coil_current(path, map.current, current);
    }
    let mut sorted = current.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let tolerance = CURRENT_AGREEMENT.0.max(CURRENT_AGREEMENT.1 * spec.current_a.abs());
    if (median - spec.current_a).abs() > tolerance {
        return Err(Error::input_at(
            path,
            None,
            Some(map.current),
            format!(
                "the file's coil current is {median} A (median), the manifest's current_a for run '{}' is {} A (if the current changes within the record, set current_varies = true for this run)",
                spec.id, spec.current_a
            ),
        ));
    }
    Ok(())
}

impl Campaign {
    /// Reads the manifest and every data file it names; the first problem
    /// found is the error.
    pub fn load(manifest_path: &Path) -> Result<Campaign> {
        let manifest = Manifest::read(manifest_path)?;
        let dir = manifest_path.parent().unwrap_or(Path::new("."));
        let map = ColumnMap::of(&manifest.columns, true);
        let mut runs = Vec::with_capacity(manifest.runs.len());
        let mut notes = Vec::new();
        for spec in &manifest.runs {
            let path = dir.join(&spec.file);
            if outside(dir, &path) {
                notes.push(format!(
                    "run '{}': its file {} is outside the manifest's folder {} (read anyway; keep a campaign's files below its manifest so it travels whole)",
                    spec.id,
                    path.display(),
                    dir.display()
                ));
            }
            let record = Record::read(&path, &map)?;
            runs.push(Arc::new(Run::checked(spec, path, record, &manifest, &map)?));
        }
        notes.extend(runs.iter().flat_map(|r| r.notes()));
        Ok(Campaign {
            name: manifest.name,
            manifest_path: manifest_path.to_path_buf(),
            geometry: manifest.geometry,
            columns: manifest.columns,
            runs,
            notes,
        })
    }

    /// Writes the campaign into `dir`: one CSV per run (SI units, the
    /// default column names, numbers that read back to the same doubles)
    /// and the manifest `campaign.toml`, after the comment lines `header`.
    /// What [`Campaign::load`] reads back as this campaign; its path.
    pub fn write(&self, dir: &Path, header: &str) -> Result<PathBuf> {
        std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
        let mut runs = Vec::with_capacity(self.runs.len());
        let mut taken = std::collections::HashSet::new();
        for (i, run) in self.runs.iter().enumerate() {
            let stem: String = run
                .id()
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' })
                .collect();
            let file = match taken.insert(stem.clone()) {
                true => format!("{stem}.csv"),
                false => format!("{stem}-{i}.csv"),
            };
            crate::atomic::write(&dir.join(&file), super::table::csv_text(&run.record).as_bytes())?;
            runs.push(RunSpec { file: PathBuf::from(file), ..run.spec.clone() });
        }
        let manifest = Manifest {
            name: self.name.clone(),
            geometry: self.geometry,
            columns: Columns::default(),
            limits: Default::default(),
            runs,
        };
        let path = dir.join("campaign.toml");
        manifest.write(&path, header)?;
        Ok(path)
    }

    /// A campaign from records in memory (SI units; a notebook's frames):
    /// the manifest's and the records' checks of [`Campaign::load`], with
    /// each run named `<manifest name>/<run id>` in messages.
    pub fn from_records(manifest: Manifest, records: Vec<Record>) -> Result<Campaign> {
        let here = PathBuf::from(format!("campaign '{}'", manifest.name));
        manifest.check(&here)?;
        if records.len() != manifest.runs.len() {
            return Err(Error::input(
                &here,
                format!("{} runs but {} records", manifest.runs.len(), records.len()),
            ));
        }
        let c = Columns::default();
        let map = ColumnMap::of(&c, true);
        let mut runs = Vec::with_capacity(records.len());
        for (spec, record) in manifest.runs.iter().zip(records) {
            let path = PathBuf::from(format!("run '{}'", spec.id));
            record.check(&path, &map)?;
            runs.push(Arc::new(Run::checked(spec, path, record, &manifest, &map)?));
        }
        let notes = runs.iter().flat_map(|r| r.notes()).collect();
        Ok(Campaign {
            name: manifest.name.clone(),
            manifest_path: here,
            geometry: manifest.geometry,
            columns: c,
            runs,
            notes,
        })
    }

    /// Refuses a campaign whose runs cannot be identified or calibrated (no
    /// motion, no force signal): `what` names the command.
    pub fn require_usable(&self, what: &str) -> Result<()> {
        for run in &self.runs {
            if let Some(problem) = run.unusable() {
                return Err(Error::input(
                    &run.path,
                    format!("{problem}: nothing for {what} to fit"),
                ));
            }
        }
        Ok(())
    }

    /// The distinct coil currents of the campaign's runs of one current
    /// (not those whose current varies), ascending.
    pub fn currents(&self) -> Vec<f64> {
        let mut c: Vec<f64> =
            self.runs.iter().filter(|r| !r.spec.current_varies).map(|r| r.spec.current_a).collect();
        c.sort_by(f64::total_cmp);
        c.dedup();
        c
    }

    /// The same campaign restricted to the runs that `keep` accepts.
    pub fn filtered(&self, keep: impl Fn(&Run) -> bool) -> Campaign {
        Campaign {
            name: self.name.clone(),
            manifest_path: self.manifest_path.clone(),
            geometry: self.geometry,
            columns: self.columns.clone(),
            runs: self.runs.iter().filter(|r| keep(r)).cloned().collect(),
            notes: self.notes.clone(),
        }
    }

    /// The runs held at one coil current (not those whose current varies).
    pub fn at_current(&self, current_a: f64) -> Campaign {
        self.filtered(|r| !r.spec.current_varies && same_current(r.spec.current_a, current_a))
    }

    /// Whether any run is held at `current_a`.
    pub fn has_current(&self, current_a: f64) -> bool {
        self.runs
            .iter()
            .any(|r| !r.spec.current_varies && same_current(r.spec.current_a, current_a))
    }

    /// The ids of the runs whose current varies within the record.
    pub fn varying_runs(&self) -> Vec<&str> {
        self.runs.iter().filter(|r| r.spec.current_varies).map(|r| r.id()).collect()
    }
}

/// Coil currents that differ by less than this (A) are one current level.
pub const CURRENT_TOLERANCE_A: f64 = 1e-3;

/// Whether two coil currents are the same level.
pub fn same_current(a: f64, b: f64) -> bool {
    (a - b).abs() < CURRENT_TOLERANCE_A
}

/// Label of a current level in folder and file names: `I1.0A`, `I0.25A`
/// (the shortest decimal that names it, with at least one decimal).
pub fn current_tag(current_a: f64) -> String {
    let digits = format!("{current_a}");
    if digits.contains('.') {
        format!("I{digits}A")
    } else {
        format!("I{digits}.0A")
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn current_tags_name_each_level() {
        assert_eq!(super::current_tag(1.0), "I1.0A");
        assert_eq!(super::current_tag(0.25), "I0.25A");
        assert_eq!(super::current_tag(1.5), "I1.5A");
    }

    /// A record whose logger dropped 0.2 s of a 1 kHz stroke is loaded with
    /// a note naming the gap; the same record whole has none.
    #[test]
    fn missing_samples_are_noted() {
        use super::*;
        let record = |drop: std::ops::Range<usize>| {
            let t: Vec<f64> =
                (0..4000).filter(|k| !drop.contains(k)).map(|k| k as f64 * 1e-3).collect();
            let x: Vec<f64> = t.iter().map(|t| 0.01 * (std::f64::consts::TAU * t).sin()).collect();
            let f: Vec<f64> = t.iter().map(|t| 1e3 * (std::f64::consts::TAU * t).cos()).collect();
            Record { time: t, displacement: x, force: f, current: None }
        };
        let manifest = || Manifest {
            name: "gaps".into(),
            geometry: Geometry { area_m2: 0.05, gap_m: 1e-3 },
            columns: Columns::default(),
            limits: Default::default(),
            runs: vec![RunSpec::new("r".into(), "r.csv".into(), 1.0)],
        };
        let whole = Campaign::from_records(manifest(), vec![record(0..0)]).unwrap();
        assert!(whole.notes.is_empty(), "{:?}", whole.notes);
        let cut = Campaign::from_records(manifest(), vec![record(1800..2000)]).unwrap();
        assert_eq!(cut.notes.len(), 1, "{:?}", cut.notes);
        let note = &cut.notes[0];
        // the interval from the 1 799th sample (t = 1.799 s) to the 2 000th
        assert!(
            note.contains("1 of its sampling intervals is")
                && note.contains("0.2010 s from t = 1.7990 s"),
            "{note}"
        );
    }
}
