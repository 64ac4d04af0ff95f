//! Whether the results in a folder are whole: `mrbp status`. A folder is
//! *complete* when it has its record (`calibration.toml`, `prediction.toml`,
//! `comparison.toml`, `campaign.toml` — each written last and removed first)
//! and every file in it was derived from the calibration(s) that record
//! names; *incomplete* when a command stopped while writing it; *stale* when
//! a file comes from another calibration than the folder holds, or a
//! comparison from calibrations since redone; *busy* while another process
//! writes it. Each finding names the file and the command that rebuilds it.

use std::path::{Path, PathBuf};

use super::{
    comparison, consistency, coverage, folder, identification, laws, parquet_meta, prediction,
    record, simulation, CALIBRATION_ID,
};
use crate::error::Result;

/// The report of a folder (written by [`crate::report`]).
pub const REPORT: &str = "report.html";

/// The meta tag of a report naming a calibration it was made from.
pub const CALIBRATION_ID_META: &str = "mrbp-calibration-id";

/// The calibration ids a report names (none for a report made before
/// reports named them).
pub fn report_ids(html: &str) -> Vec<String> {
    let tag = format!("<meta name=\"{CALIBRATION_ID_META}\" content=\"");
    html.match_indices(&tag)
        .filter_map(|(at, _)| html[at + tag.len()..].split('"').next().map(str::to_string))
        .collect()
}

/// What a folder holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Calibration,
    Prediction,
    Comparison,
    Simulation,
    Campaign,
    /// The damper laws side by side (`run --law A,B,…`: `DIR/laws/`).
    Laws,
}

impl Kind {
    pub fn label(self) -> &'static str {
        match self {
            Kind::Calibration => "calibration",
            Kind::Prediction => "prediction",
            Kind::Comparison => "comparison",
            Kind::Simulation => "simulation",
            Kind::Campaign => "campaign",
            Kind::Laws => "damper laws",
        }
    }
}

/// The state of one results folder.
#[derive(Clone, Debug, PartialEq)]
pub struct FolderStatus {
    pub dir: PathBuf,
    pub kind: Kind,
    /// The process writing it now, if one is.
    pub writer: Option<String>,
    /// What is wrong, one line each (empty: complete).
    pub problems: Vec<String>,
}

impl FolderStatus {
    pub fn complete(&self) -> bool {
        self.writer.is_none() && self.problems.is_empty()
    }
}

/// The results folders in and under `dir`, each with its state, in path
/// order.
pub fn status(dir: &Path) -> Result<Vec<FolderStatus>> {
    let mut found = Vec::new();
    walk(dir, &mut found, 0);
    Ok(found)
}

fn walk(dir: &Path, found: &mut Vec<FolderStatus>, depth: usize) {
    if let Some(kind) = kind_of(dir) {
        let writer = crate::lock::writer(dir);
        let problems = if writer.is_some() { Vec::new() } else { check(dir, kind) };
        found.push(FolderStatus { dir: dir.to_path_buf(), kind, writer, problems });
    }
    if depth >= 6 {
        return;
    }
    let Ok(listed) = std::fs::read_dir(dir) else { return };
    let mut subs: Vec<PathBuf> = listed
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .filter(|p| {
            p.file_name().is_some_and(|n| {
                !n.to_string_lossy().starts_with('.') && !n.to_string_lossy().ends_with(".zarr")
            })
        })
        .collect();
    subs.sort();
    for sub in subs {
        walk(&sub, found, depth + 1);
    }
}

fn kind_of(dir: &Path) -> Option<Kind> {
    let has = |f: &str| dir.join(f).exists();
    let calibration = [folder::RECORD, folder::CHAINS, folder::SUMMARY, folder::CONFIG];
    if calibration.iter().any(|f| has(f)) || folder::checkpoint_in(dir).is_some() {
        Some(Kind::Calibration)
    } else if [comparison::RECORD, comparison::SUMMARIES, comparison::DIFFERENCES]
        .iter()
        .any(|f| has(f))
    {
        Some(Kind::Comparison)
    } else if [prediction::RECORD, prediction::BANDS, prediction::COVERAGE, prediction::ADEQUACY]
        .iter()
        .any(|f| has(f))
    {
        Some(Kind::Prediction)
    } else if [simulation::RECORD, simulation::FILE].iter().any(|f| has(f)) {
        Some(Kind::Simulation)
    } else if has(laws::FILE) {
        Some(Kind::Laws)
    } else if has("synth.toml") {
        Some(Kind::Campaign)
    } else {
        None
    }
}

fn check(dir: &Path, kind: Kind) -> Vec<String> {
    let mut problems = Vec::new();
    match kind {
        Kind::Calibration => check_calibration(dir, &mut problems),
        Kind::Prediction => check_prediction(
            dir,
            enclosing(dir).as_deref(),
            "mrbp predict CALIBRATION --campaign MANIFEST --out DIR",
            &mut problems,
        ),
        Kind::Simulation => check_simulation(dir, &mut problems),
        Kind::Comparison => check_comparison(dir, &mut problems),
        Kind::Laws => check_laws(dir, &mut problems),
        Kind::Campaign => {
            if !dir.join("campaign.toml").exists() {
                problems.push("campaign.toml missing: `mrbp synth` stopped while writing this campaign; make it again with `mrbp synth --out DIR`".into());
            }
        }
    }
    problems
}

/// The calibration of the folder that holds `dir`, if `dir` lies in a
/// calibration folder (a prediction or simulation made into it).
fn enclosing(dir: &Path) -> Option<String> {
    let parent = dir.parent()?;
    record::read(&parent.join(folder::RECORD)).ok().map(|r| r.calibration_id)
}

fn check_simulation(dir: &Path, problems: &mut Vec<String>) {
    let rebuild = "mrbp simulate CALIBRATION --input FILE --out DIR";
    if !dir.join(simulation::RECORD).exists() {
        return problems.push(format!("{}: missing, the simulation is incomplete (stopped while written); rebuild it with `{rebuild}`", simulation::RECORD));
    }
    let (made_from, layer_runs) = match simulation::read_record(dir) {
        Ok(r) => (r.calibration_id, r.layer_runs),
        Err(e) => return problems.push(e.to_string()),
    };
    check_table(&dir.join(simulation::FILE), &made_from, rebuild, problems);
    if let Some(id) = enclosing(dir).filter(|id| *id != made_from) {
        problems.push(stale(&dir.join(simulation::FILE), &made_from, &id, rebuild));
    }
    // new tests of the damper: from the between-run layer now in the folder
    if let (false, Some(parent)) =
        (layer_runs.is_empty(), dir.parent().filter(|_| enclosing(dir).is_some()))
    {
        let now =
            parquet_meta(&parent.join(super::between_runs::FILE), super::between_runs::LAYER_RUNS)
                .ok()
                .flatten();
        if now.as_deref() != Some(layer_runs.as_str()) {
            problems.push(format!(
                "{}: stale, its new tests came from a between-run layer since fitted again or removed; rebuild it with `mrbp simulate CALIBRATION --input FILE --new-test --out DIR`",
                simulation::FILE
            ));
        }
    }
}

/// The id a derived table names, if it names one.
fn table_id(path: &Path, key: &str) -> Result<Option<String>, String> {
    parquet_meta(path, key).map_err(|e| e.to_string())
}

fn check_table(path: &Path, id: &str, rebuild: &str, problems: &mut Vec<String>) {
    if !path.exists() {
        return;
    }
    match table_id(path, CALIBRATION_ID) {
        Err(e) => problems.push(e),
        Ok(Some(found)) if found != id => problems.push(stale(path, &found, id, rebuild)),
        Ok(_) => {}
    }
}

fn stale(path: &Path, found: &str, id: &str, rebuild: &str) -> String {
    format!("{}: {}", name(path), super::parquet::stale(found, id, rebuild))
}

fn name(path: &Path) -> String {
    path.file_name()
        .map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

fn check_calibration(dir: &Path, problems: &mut Vec<String>) {
    let record_path = dir.join(folder::RECORD);
    // a calibration stopped while sampling: its chains so far, kept
    if let Some(found) = folder::checkpoint_in(dir) {
        problems.push(format!(
            "{found}: the chains of an interrupted calibration, kept; rebuild it with `{}`",
            folder::REBUILD
        ));
        return;
    }
    if !record_path.exists() {
        problems.push(format!("{}: missing, the calibration is incomplete (stopped while written); rebuild it with `{}`", folder::RECORD, folder::REBUILD));
        return;
    }
    let id = match record::read(&record_path) {
        Ok(r) => r.calibration_id,
        Err(e) => return problems.push(e.to_string()),
    };
    for file in [folder::CHAINS, folder::SUMMARY, folder::CONFIG] {
        if !dir.join(file).exists() {
            problems.push(format!("{file}: missing; rebuild it with `{}`", folder::REBUILD));
        }
    }
    for file in
        [folder::CHAINS, folder::SUMMARY, identification::FILE, super::against_current::FILE]
    {
        check_table(&dir.join(file), &id, folder::REBUILD, problems);
    }
    check_prediction(dir, Some(&id), "mrbp predict DIR", problems);
    let zarr = dir.join(super::inference::FILE);
    if zarr.exists() {
        match super::inference::calibration_id(&zarr) {
            Ok(found) if found != id => {
                problems.push(stale(&zarr, &found, &id, "mrbp predict DIR"))
            }
            Ok(_) => {}
            Err(e) => problems.push(e.to_string()),
        }
    }
    let (loo, loo_bands) = (dir.join(coverage::LOO), dir.join(coverage::LOO_BANDS));
    if loo_bands.exists() && !loo.exists() {
        problems.push(format!("{}: missing, the leave-one-out study is incomplete; rebuild it with `mrbp report DIR --leave-one-out`", coverage::LOO));
    }
    if loo.exists() {
        for file in [loo, loo_bands] {
            check_table(&file, &id, coverage::REBUILD_LOO, problems);
        }
    }
    if dir.join(consistency::FILE).exists() {
        if let Err(e) = consistency::check(dir, &id) {
            problems.push(e.to_string());
        }
    }
    for file in [super::between_runs::FILE, super::between_runs::LOO, super::between_runs::TYPICAL]
    {
        let path = dir.join(file);
        if path.exists() {
            if let Err(e) = super::between_runs::check(&path, dir, &id) {
                problems.push(e.to_string());
            }
        }
    }
    check_report(dir, std::slice::from_ref(&id), "mrbp report DIR", problems);
}

fn check_prediction(
    dir: &Path,
    calibration: Option<&str>,
    rebuild: &str,
    problems: &mut Vec<String>,
) {
    let files = [prediction::BANDS, prediction::COVERAGE, prediction::ADEQUACY];
    let record_path = dir.join(prediction::RECORD);
    if !record_path.exists() {
        if files.iter().any(|f| dir.join(f).exists()) {
            problems.push(format!("{}: missing, the bands are incomplete (stopped while written); rebuild it with `{rebuild}`", prediction::RECORD));
        }
        return;
    }
    let made_from = match prediction::read_record(&record_path) {
        Ok(r) => r.calibration_id,
        Err(e) => return problems.push(e.to_string()),
    };
    if let Some(id) = calibration {
        if made_from != id {
            return problems.push(stale(&record_path, &made_from, id, rebuild));
        }
    }
    for file in files {
        if !dir.join(file).exists() {
            problems.push(format!("{file}: missing; rebuild it with `{rebuild}`"));
        }
        check_table(&dir.join(file), &made_from, rebuild, problems);
    }
    if calibration.is_none() {
        check_report(dir, std::slice::from_ref(&made_from), rebuild, problems);
    }
}

/// A report naming other calibrations than `ids` is stale.
fn check_report(dir: &Path, ids: &[String], rebuild: &str, problems: &mut Vec<String>) {
    let path = dir.join(REPORT);
    let Ok(html) = std::fs::read_to_string(&path) else { return };
    let named = report_ids(&html);
    if !named.is_empty() && named != ids {
        problems.push(format!("{}: stale (made from calibration(s) {}, the folder holds {}); rebuild it with `{rebuild}`", name(&path), named.join(", "), ids.join(", ")));
    }
}

fn check_comparison(dir: &Path, problems: &mut Vec<String>) {
    let rebuild = "mrbp compare DIR DIR … --out OUT";
    if !dir.join(comparison::RECORD).exists() {
        return problems.push(format!("{}: missing, the comparison is incomplete (stopped while written, or made before comparisons were recorded); rebuild it with `{rebuild}`", comparison::RECORD));
    }
    let record = match comparison::read_record(dir) {
        Ok(r) => r,
        Err(e) => return problems.push(e.to_string()),
    };
    for c in &record.compared {
        check_source(&c.folder_from(dir), &c.calibration_id, "comparison", rebuild, problems);
    }
    let ids = comparison::ids_text(&record);
    for file in [comparison::SUMMARIES, comparison::DIFFERENCES] {
        let path = dir.join(file);
        match table_id(&path, comparison::CALIBRATION_IDS) {
            Err(e) => problems.push(e),
            Ok(Some(found)) if found != ids => problems.push(format!(
                "{file}: stale (compares {found}, the record {ids}); rebuild it with `{rebuild}`"
            )),
            Ok(_) => {}
        }
    }
    let ids: Vec<String> = record.compared.iter().map(|c| c.calibration_id.clone()).collect();
    check_report(dir, &ids, rebuild, problems);
}

/// A laws folder (`OUT/laws/`) judges the calibrations `OUT/<law>/I<c>A/`
/// its table names: each must still hold the calibration it was made
/// from, and its report name the same ones.
fn check_laws(dir: &Path, problems: &mut Vec<String>) {
    let rebuild = "mrbp run MANIFEST --law A,B,… --out OUT";
    let path = dir.join(laws::FILE);
    let named = match table_id(&path, laws::CALIBRATIONS) {
        Err(e) => return problems.push(e),
        Ok(None) => return problems.push(format!("{}: names no calibrations (made before laws tables named them); rebuild it with `{rebuild}`", laws::FILE)),
        Ok(Some(named)) => named,
    };
    let Some(out) = dir.parent() else { return };
    let mut ids = Vec::new();
    for entry in named.split(',') {
        let Some((label, id)) = entry.split_once('=') else {
            return problems.push(format!(
                "{}: unreadable calibration list '{named}'; rebuild it with `{rebuild}`",
                laws::FILE
            ));
        };
        ids.push(id.to_string());
        check_source(&out.join(label), id, "study", rebuild, problems);
    }
    check_report(dir, &ids, rebuild, problems);
}

/// A calibration folder `cal` that a derived folder (a `what`) was made
/// from must still hold calibration `id`.
fn check_source(cal: &Path, id: &str, what: &str, rebuild: &str, problems: &mut Vec<String>) {
    match record::read(&cal.join(folder::RECORD)).map(|r| r.calibration_id) {
        Ok(now) if now == id => {}
        Ok(now) => problems.push(format!("{}: calibrated again since this {what} (calibration {id} then, {now} now); rebuild it with `{rebuild}`", cal.display())),
        Err(_) => problems.push(format!("{}: no complete calibration there any more (it held {id}); rebuild it with `{rebuild}`", cal.display())),
    }
}
