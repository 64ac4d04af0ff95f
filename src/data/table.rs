//! Reading one stand record (CSV or Parquet) into columns of numbers.
//!
//! Every problem is an [`Error::Input`] naming the file, and where it applies
//! the row (data rows counted from 1, the header not counted) and the column.

use std::path::Path;

use crate::error::{Error, Result};

/// One test record: time (s), displacement (m), force (N), and the coil
/// current (A) if the file has it. Units are SI after the manifest's scales.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Record {
    pub time: Vec<f64>,
    pub displacement: Vec<f64>,
    pub force: Vec<f64>,
    pub current: Option<Vec<f64>>,
}

/// Which columns to read and the factors that turn them into SI units.
#[derive(Clone, Debug)]
pub struct ColumnMap<'a> {
    pub time: (&'a str, f64),
    pub displacement: (&'a str, f64),
    pub force: (&'a str, f64),
    /// Optional: read if present.
    pub current: &'a str,
}

impl Record {
    /// Reads a `.csv` or `.parquet` file and checks it: at least two rows,
    /// every value a finite number, time strictly increasing.
    pub fn read(path: &Path, columns: &ColumnMap) -> Result<Record> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
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
        record.check(path, columns)?;
        Ok(record)
    }

    pub fn len(&self) -> usize {
        self.time.len()
    }

    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }

    fn check(&self, path: &Path, columns: &ColumnMap) -> Result<()> {
        if self.time.len() < 2 {
            return Err(Error::input(
                path,
                format!("record has {} data rows; at least 2 are needed", self.time.len()),
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
        Error::input_at(path, Some(row), Some(column), format!("'{text}' is not a number"))
    })?;
    finite(path, row, column, value)
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

fn read_csv(path: &Path, columns: &ColumnMap) -> Result<Record> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .map_err(|e| Error::input(path, format!("cannot open: {}", io_reason(&e))))?;
    let headers = reader
        .headers()
        .map_err(|e| Error::input(path, format!("cannot read the header: {e}")))?
        .clone();
    let find = |name: &str| headers.iter().position(|h| h == name);
    let required = [columns.time, columns.displacement, columns.force];
    let mut index = [0usize; 3];
    for (slot, (name, _)) in index.iter_mut().zip(required) {
        *slot = find(name).ok_or_else(|| missing_column(path, name))?;
    }
    let current_index = find(columns.current);

    let mut rec = Record {
        current: current_index.map(|_| Vec::new()),
        ..Record::default()
    };
    for (i, row) in reader.records().enumerate() {
        let row_no = i + 1;
        let row = row.map_err(|e| Error::input_at(path, Some(row_no), None, e.to_string()))?;
        let cell = |col: usize, name: &str| -> Result<f64> {
            let text = row.get(col).ok_or_else(|| {
                Error::input_at(path, Some(row_no), Some(name), "missing value")
            })?;
            parse_cell(path, row_no, name, text)
        };
        rec.time.push(cell(index[0], columns.time.0)? * columns.time.1);
        rec.displacement
            .push(cell(index[1], columns.displacement.0)? * columns.displacement.1);
        rec.force.push(cell(index[2], columns.force.0)? * columns.force.1);
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
    let df = ParquetReader::new(file)
        .finish()
        .map_err(|e| Error::input(path, format!("not a readable Parquet file: {e}")))?;
    let column = |name: &str, scale: f64| -> Result<Vec<f64>> {
        let series = df
            .column(name)
            .map_err(|_| missing_column(path, name))?
            .as_materialized_series()
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
    Ok(Record {
        time: column(columns.time.0, columns.time.1)?,
        displacement: column(columns.displacement.0, columns.displacement.1)?,
        force: column(columns.force.0, columns.force.1)?,
        current: if df.column(columns.current).is_ok() {
            Some(column(columns.current, 1.0)?)
        } else {
            None
        },
    })
}

fn missing_column(path: &Path, name: &str) -> Error {
    Error::input_at(path, None, Some(name), "no such column in the file")
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
