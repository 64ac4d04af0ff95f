//! Reading one stand record (CSV or Parquet) into columns of numbers.
//!
//! Every problem is an [`Error::Input`] naming the file, and where it applies
//! the row (data rows counted from 1, the header not counted) and the column.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{one_line, Error, Result};

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

/// The largest magnitudes a stand record may hold, in SI units after the
/// column scales (`[limits]` in the manifest). The defaults are far beyond
/// any damper test (a meganewton, ten metres, ten days, a kiloampere), so a
/// value past them is a unit or export error, caught with its row.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    pub force_n: f64,
    pub displacement_m: f64,
    pub time_s: f64,
    pub current_a: f64,
}

impl Limits {
    pub fn is_default(&self) -> bool {
        *self == Limits::default()
    }
}

impl Default for Limits {
    fn default() -> Self {
        Limits { force_n: 1e6, displacement_m: 10.0, time_s: 1e6, current_a: 1e3 }
    }
}

/// One test record: time (s), displacement (m), force (N), and the coil
/// current (A) if the file has it. Units are SI after the manifest's scales.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Record {
    pub time: Vec<f64>,
    pub displacement: Vec<f64>,
    pub force: Vec<f64>,
    pub current: Option<Vec<f64>>,
}

/// The median sampling interval of `time`, and whether every interval is
/// that one to a millionth.
pub(super) fn sampling_step(time: &[f64]) -> (f64, bool) {
    let mut dt: Vec<f64> = time.windows(2).map(|w| w[1] - w[0]).collect();
    if dt.is_empty() {
        return (f64::NAN, false);
    }
    dt.sort_by(f64::total_cmp);
    let median = dt[dt.len() / 2];
    let uniform = dt[0] >= median * (1.0 - 1e-6) && dt[dt.len() - 1] <= median * (1.0 + 1e-6);
    (median, uniform)
}

/// Which columns to read and the factors that turn them into SI units.
#[derive(Clone, Debug)]
pub struct ColumnMap<'a> {
    pub time: (&'a str, f64),
    pub displacement: (&'a str, f64),
    pub force: (&'a str, f64),
    /// Optional: read if present.
    pub current: &'a str,
    /// Whether a file without the force column is refused; else its force
    /// is NaN (an excitation to simulate).
    pub force_required: bool,
}

impl<'a> ColumnMap<'a> {
    /// The columns named and scaled as `columns` says; `force_required`
    /// as the field.
    pub fn of(columns: &'a Columns, force_required: bool) -> Self {
        let c = columns;
        ColumnMap {
            time: (&c.time, c.time_scale),
            displacement: (&c.displacement, c.displacement_scale),
            force: (&c.force, c.force_scale),
            current: &c.current,
            force_required,
        }
    }
}

/// The record as CSV with the default column names ([`Columns`]);
/// numbers in Rust's shortest round-trip form, so the file is the same on
/// every machine.
pub fn csv_text(rec: &Record) -> String {
    let c = Columns::default();
    let mut s = String::with_capacity(rec.len() * 64);
    s.push_str(&format!("{},{},{}", c.time, c.displacement, c.force));
    if rec.current.is_some() {
        s.push_str(&format!(",{}", c.current));
    }
    s.push('\n');
    for k in 0..rec.len() {
        s.push_str(&format!("{},{},{}", rec.time[k], rec.displacement[k], rec.force[k]));
        if let Some(current) = &rec.current {
            s.push_str(&format!(",{}", current[k]));
        }
        s.push('\n');
    }
    s
}

/// The fewest samples a record may have: below it there is no loading and
/// unloading to fit, and the identification would only print NaN.
pub const MIN_ROWS: usize = 10;

impl Record {
    /// Refuses values beyond the plausible `limits` (SI), naming the row
    /// and column of the first.
    pub fn check_limits(&self, path: &Path, columns: &ColumnMap, limits: &Limits) -> Result<()> {
        let mut checks: Vec<(&[f64], &str, f64, &str)> = vec![
            (&self.time, columns.time.0, limits.time_s, "limits.time_s"),
            (
                &self.displacement, columns.displacement.0, limits.displacement_m,
                "limits.displacement_m",
            ),
            (&self.force, columns.force.0, limits.force_n, "limits.force_n"),
        ];
        if let Some(current) = &self.current {
            checks.push((current, columns.current, limits.current_a, "limits.current_a"));
        }
        for (values, name, limit, key) in checks {
            if let Some(k) = values.iter().position(|v| v.abs() > limit) {
                return Err(Error::input_at(
                    path,
                    Some(k + 1),
                    Some(name),
                    format!("{:e} (SI, after the column's scale) is beyond the plausible {limit:e}; a unit or export error? ({key} in the manifest raises the limit)", values[k]),
                ));
            }
        }
        Ok(())
    }

    /// Reads a `.csv` or `.parquet` file and checks it: at least MIN_ROWS rows,
    /// every value a finite number, time strictly increasing.
    pub fn read(path: &Path, columns: &ColumnMap) -> Result<Record> {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        let record = match ext.as_deref() {
            Some("csv") => read_csv(path, columns)?,
            Some("parquet") => read_parquet(path, columns)?,
            _ => {
                return Err(Error::input(
                    path,
                    "unknown data file type (expected .csv or .parquet)",
                ))
            }
        };
        record.check_rows(path, columns)?;
        Ok(record)
    }

    pub fn len(&self) -> usize {
        self.time.len()
    }

    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }

    /// Checks a record read or handed over: at least MIN_ROWS rows, every
    /// value finite, time strictly increasing; `path` names it in messages.
    pub fn check(&self, path: &Path, columns: &ColumnMap) -> Result<()> {
        let n = self.time.len();
        let series: [(&[f64], &str); 3] = [
            (&self.time, columns.time.0),
            (&self.displacement, columns.displacement.0),
            (&self.force, columns.force.0),
        ];
        for (i, (values, name)) in series.into_iter().enumerate() {
            if values.len() != n {
                return Err(Error::input_at(
                    path,
                    None,
                    Some(name),
                    format!("{} values where the time has {n}", values.len()),
                ));
            }
            // an excitation to simulate has no force to check
            let checked = i < 2 || columns.force_required;
            if let Some(k) = checked.then(|| values.iter().position(|v| !v.is_finite())).flatten() {
                finite(path, k + 1, name, values[k])?;
            }
        }
        if let Some(current) = &self.current {
            if current.len() != n {
                return Err(Error::input_at(
                    path,
                    None,
                    Some(columns.current),
                    format!("{} values where the time has {n}", current.len()),
                ));
            }
            if let Some(k) = current.iter().position(|v| !v.is_finite()) {
                finite(path, k + 1, columns.current, current[k])?;
            }
        }
        self.check_rows(path, columns)
    }

    fn check_rows(&self, path: &Path, columns: &ColumnMap) -> Result<()> {
        if self.time.len() < MIN_ROWS {
            return Err(Error::input(
                path,
                format!("record has {} data rows; at least {MIN_ROWS} are needed (a loading and an unloading)", self.time.len()),
            ));
        }
        for (k, w) in self.time.windows(2).enumerate() {
            if w[1] <= w[0] {
                return Err(Error::input_at(
                    path,
                    Some(k + 2),
                    Some(columns.time.0),
                    format!("time does not increase ({} after {})", w[1], w[0]),
                ));
            }
        }
        Ok(())
    }
}

fn parse_cell(path: &Path, row: usize, column: &str, text: &str) -> Result<f64> {
    let value: f64 = text.trim().parse().map_err(|_| {
        Error::input_at(
            path,
            Some(row),
            Some(column),
            format!("'{}' is text where a number belongs", shown(text)),
        )
    })?;
    finite(path, row, column, value)
}

/// A cell as an error message shows it: its first line, at most 40
/// characters (a stray quote can make a cell of many lines).
fn shown(text: &str) -> String {
    let line = text.lines().next().unwrap_or("");
    let cut: String = line.chars().take(40).collect();
    if cut.len() < text.len() {
        format!("{cut}…")
    } else {
        cut
    }
}

fn finite(path: &Path, row: usize, column: &str, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::input_at(
            path,
            Some(row),
            Some(column),
            format!("{value} is not a finite number"),
        ))
    }
}

/// The separator of a CSV file, read off its header line: a comma, or
/// where the header has none a semicolon (a spreadsheet's export where the
/// decimal mark is a comma) or a tab.
fn separator(path: &Path) -> u8 {
    use std::io::BufRead;
    let mut header = String::new();
    if let Ok(file) = std::fs::File::open(path) {
        let _ = std::io::BufReader::new(file).read_line(&mut header);
    }
    match (header.contains(','), header.contains(';'), header.contains('\t')) {
        (false, true, _) => b';',
        (false, false, true) => b'\t',
        _ => b',',
    }
}

fn read_csv(path: &Path, columns: &ColumnMap) -> Result<Record> {
    let separator = separator(path);
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .delimiter(separator)
        .from_path(path)
        .map_err(|e| Error::input(path, format!("cannot open: {}", io_reason(&e))))?;
    let headers = reader
        .headers()
        .map_err(|e| Error::input(path, format!("cannot read the header: {e}")))?
        .clone();
    let names: Vec<&str> = headers.iter().collect();
    let missing_column = |path: &Path, name: &str| missing_column(path, name, &names);
    let find = |name: &str| headers.iter().position(|h| h == name);
    for (i, h) in headers.iter().enumerate() {
        if let Some(j) = headers.iter().skip(i + 1).position(|o| o == h) {
            return Err(Error::input_at(
                path,
                None,
                Some(h),
                format!(
                    "the header names this column twice (columns {} and {}): which one is meant?",
                    i + 1,
                    i + j + 2
                ),
            ));
        }
    }
    let required = [columns.time, columns.displacement];
    let mut index = [0usize; 2];
    for (slot, (name, _)) in index.iter_mut().zip(required) {
        *slot = find(name).ok_or_else(|| missing_column(path, name))?;
    }
    let force_index = match find(columns.force.0) {
        None if columns.force_required => return Err(missing_column(path, columns.force.0)),
        found => found,
    };
    let current_index = find(columns.current);

    let mut rec = Record { current: current_index.map(|_| Vec::new()), ..Record::default() };
    for (i, row) in reader.records().enumerate() {
        let row_no = i + 1;
        let row = row.map_err(|e| Error::input_at(path, Some(row_no), None, e.to_string()))?;
        let cell = |col: usize, name: &str| -> Result<f64> {
            let text = row
                .get(col)
                .ok_or_else(|| Error::input_at(path, Some(row_no), Some(name), "missing value"))?;
            match separator {
                // a semicolon's file writes the decimal mark as a comma
                b';' => parse_cell(path, row_no, name, &text.replace(',', ".")),
                _ => parse_cell(path, row_no, name, text),
            }
        };
        rec.time.push(cell(index[0], columns.time.0)? * columns.time.1);
        rec.displacement.push(cell(index[1], columns.displacement.0)? * columns.displacement.1);
        rec.force.push(match force_index {
            Some(fi) => cell(fi, columns.force.0)? * columns.force.1,
            None => f64::NAN,
        });
        if let (Some(ci), Some(cur)) = (current_index, rec.current.as_mut()) {
            cur.push(cell(ci, columns.current)?);
        }
    }
    Ok(rec)
}

fn read_parquet(path: &Path, columns: &ColumnMap) -> Result<Record> {
    use polars::prelude::*;
    let file = std::fs::File::open(path)
        .map_err(|e| Error::input(path, format!("cannot open: {}", e.kind())))?;
    let df = crate::error::guard_foreign(|| ParquetReader::new(file).finish())
        .ok_or_else(|| {
            Error::input(path, "not a readable Parquet file (damaged: its decoder failed)")
        })?
        .map_err(|e| {
            Error::input(path, format!("not a readable Parquet file: {}", one_line(&e.to_string())))
        })?;
    let names: Vec<String> = df.get_column_names().iter().map(|n| n.to_string()).collect();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let missing_column = |path: &Path, name: &str| missing_column(path, name, &names);
    let column = |name: &str, scale: f64| -> Result<Vec<f64>> {
        let raw = df.column(name).map_err(|_| missing_column(path, name))?.as_materialized_series();
        if let Ok(text) = raw.str() {
            // text columns: every cell must read as a number
            return (0..text.len())
                .map(|i| match text.get(i) {
                    Some(t) => parse_cell(path, i + 1, name, t).map(|v| v * scale),
                    None => Err(Error::input_at(path, Some(i + 1), Some(name), "missing value")),
                })
                .collect();
        }
        let series = raw
            .cast(&DataType::Float64)
            .map_err(|_| Error::input_at(path, None, Some(name), "column is not numeric"))?;
        let values = series.f64().expect("cast to Float64");
        (0..values.len())
            .map(|i| (i, values.get(i)))
            .map(|(i, v)| match v {
                Some(v) => finite(path, i + 1, name, v).map(|v| v * scale),
                None => Err(Error::input_at(path, Some(i + 1), Some(name), "missing value")),
            })
            .collect()
    };
    let time = column(columns.time.0, columns.time.1)?;
    let force = match df.column(columns.force.0) {
        Err(_) if !columns.force_required => vec![f64::NAN; time.len()],
        _ => column(columns.force.0, columns.force.1)?,
    };
    Ok(Record {
        time,
        displacement: column(columns.displacement.0, columns.displacement.1)?,
        force,
        current: if df.column(columns.current).is_ok() {
            Some(column(columns.current, 1.0)?)
        } else {
            None
        },
    })
}

/// A column named by the manifest's `[columns]` (or the defaults) that the
/// file lacks: which columns it has.
fn missing_column(path: &Path, name: &str, has: &[&str]) -> Error {
    let shown: Vec<String> = has.iter().take(12).map(|h| format!("'{}'", shown(h))).collect();
    let more = if has.len() > 12 { ", …" } else { "" };
    Error::input_at(
        path,
        None,
        Some(name),
        format!(
            "no such column in the file (its columns: {}{more}); the manifest's [columns] names the file's columns (docs/contract.md)",
            shown.join(", ")
        ),
    )
}

fn io_reason(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::Io(io) if io.kind() == std::io::ErrorKind::NotFound => {
            "file not found".into()
        }
        csv::ErrorKind::Io(io) => io.to_string(),
        _ => e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `rows` (time, displacement, force) written with `separator` and
    /// the decimal mark `decimal` under `header`, read back.
    fn read_written(header: &str, separator: char, decimal: char) -> Result<Record> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.csv");
        let mut text = format!("{header}\n");
        for k in 0..12 {
            let row = [0.001 * k as f64, 1e-4 * (k as f64).sin(), 100.0 + k as f64];
            let cells: Vec<String> =
                row.iter().map(|v| v.to_string().replace('.', &decimal.to_string())).collect();
            text.push_str(&cells.join(&separator.to_string()));
            text.push('\n');
        }
        std::fs::write(&path, text).unwrap();
        Record::read(&path, &ColumnMap::of(&Columns::default(), true))
    }

    /// A spreadsheet's export with semicolons and decimal commas, or tabs,
    /// reads as the comma file does; a header without the manifest's
    /// columns is refused naming the columns it has.
    #[test]
    fn semicolon_and_tab_files_read_as_commas_do() {
        let header = |sep: &str| ["time_s", "displacement_m", "force_n"].join(sep);
        let comma = read_written(&header(","), ',', '.').unwrap();
        for (sep, decimal) in [(';', ','), (';', '.'), ('\t', '.')] {
            let other = read_written(&header(&sep.to_string()), sep, decimal).unwrap();
            assert_eq!(other.time, comma.time, "{sep:?}");
            assert_eq!(other.displacement, comma.displacement, "{sep:?}");
            assert_eq!(other.force, comma.force, "{sep:?}");
        }
        let e = read_written("Time (s),Disp (mm),Force (N)", ',', '.').unwrap_err().to_string();
        assert!(e.contains("its columns: 'Time (s)', 'Disp (mm)', 'Force (N)'"), "{e}");
    }
}
