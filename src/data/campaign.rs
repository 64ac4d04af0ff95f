//! The campaign manifest (TOML) and loading a whole campaign.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::branches::loading_branches;
use super::shear::{Geometry, Shear};
use super::table::{ColumnMap, Record};
use crate::error::{Error, Result};

/// The manifest file as written by the user (contract.md).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub name: String,
    pub geometry: Geometry,
    #[serde(default)]
    pub columns: Columns,
    #[serde(rename = "run", default)]
    pub runs: Vec<RunSpec>,
}

/// Column names in the data files and the factors to SI units.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Columns {
    pub time: String,
    pub displacement: String,
    pub force: String,
    pub current: String,
    pub time_scale: f64,
    pub displacement_scale: f64,
    pub force_scale: f64,
}

impl Default for Columns {
    fn default() -> Self {
        Columns {
            time: "time_s".into(),
            displacement: "displacement_m".into(),
            force: "force_n".into(),
            current: "current_a".into(),
            time_scale: 1.0,
            displacement_scale: 1.0,
            force_scale: 1.0,
        }
    }
}

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
}

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
}

/// A validated campaign with every record loaded.
#[derive(Clone, Debug)]
pub struct Campaign {
    pub name: String,
    pub manifest_path: PathBuf,
    pub geometry: Geometry,
    pub columns: Columns,
    pub runs: Vec<Run>,
}

impl Manifest {
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
        let manifest: Manifest = toml::from_str(&text)
            .map_err(|e| Error::input(path, format!("invalid manifest: {}", one_line(&e.to_string()))))?;
        manifest.check(path)?;
        Ok(manifest)
    }

    fn check(&self, path: &Path) -> Result<()> {
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
                    return Err(Error::input(path, format!("run '{}': initial_stress_pa must be finite", run.id)));
                }
            }
        }
        Ok(())
    }
}

impl Campaign {
    /// Reads the manifest and every data file it names; the first problem
    /// found is the error.
    pub fn load(manifest_path: &Path) -> Result<Campaign> {
        let manifest = Manifest::read(manifest_path)?;
        let dir = manifest_path.parent().unwrap_or(Path::new("."));
        let c = &manifest.columns;
        let map = ColumnMap {
            time: (&c.time, c.time_scale),
            displacement: (&c.displacement, c.displacement_scale),
            force: (&c.force, c.force_scale),
            current: &c.current,
        };
        let mut runs = Vec::with_capacity(manifest.runs.len());
        for spec in &manifest.runs {
            let path = dir.join(&spec.file);
            let record = Record::read(&path, &map)?;
            let shear = Shear::from_record(&record, &manifest.geometry, spec.initial_stress_pa);
            let branches = loading_branches(&record.displacement, 0.1);
            runs.push(Run {
                spec: spec.clone(),
                path,
                record,
                shear,
                branches,
                geometry: manifest.geometry,
            });
        }
        Ok(Campaign {
            name: manifest.name,
            manifest_path: manifest_path.to_path_buf(),
            geometry: manifest.geometry,
            columns: manifest.columns,
            runs,
        })
    }

    /// The distinct coil currents of the campaign, ascending.
    pub fn currents(&self) -> Vec<f64> {
        let mut c: Vec<f64> = self.runs.iter().map(|r| r.spec.current_a).collect();
        c.sort_by(f64::total_cmp);
        c.dedup();
        c
    }

    /// The same campaign restricted to the runs that `keep` accepts.
    pub fn filtered(&self, keep: impl Fn(&Run) -> bool) -> Campaign {
        Campaign {
            runs: self.runs.iter().filter(|r| keep(r)).cloned().collect(),
            ..self.clone()
        }
    }

    /// The runs at one coil current.
    pub fn at_current(&self, current_a: f64) -> Campaign {
        self.filtered(|r| same_current(r.spec.current_a, current_a))
    }

    /// Whether any run is at `current_a`.
    pub fn has_current(&self, current_a: f64) -> bool {
        self.runs.iter().any(|r| same_current(r.spec.current_a, current_a))
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

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    #[test]
    fn current_tags_name_each_level() {
        assert_eq!(super::current_tag(1.0), "I1.0A");
        assert_eq!(super::current_tag(0.25), "I0.25A");
        assert_eq!(super::current_tag(1.5), "I1.5A");
    }
}
