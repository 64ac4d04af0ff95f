//! Column tables written as Parquet, for pandas, polars, DuckDB and R.

use std::path::Path;

use polars::prelude::*;

use crate::atomic;
use crate::error::{Error, Result};

/// A table built column by column; each column a name and its values.
#[derive(Default)]
pub struct Table {
    columns: Vec<Column>,
}

impl Table {
    pub fn new() -> Self {
        Table::default()
    }

    pub fn f64(mut self, name: &str, values: Vec<f64>) -> Self {
        self.columns.push(Column::new(name.into(), values));
        self
    }

    pub fn i64(mut self, name: &str, values: Vec<i64>) -> Self {
        self.columns.push(Column::new(name.into(), values));
        self
    }

    pub fn bool(mut self, name: &str, values: Vec<bool>) -> Self {
        self.columns.push(Column::new(name.into(), values));
        self
    }

    pub fn str(mut self, name: &str, values: Vec<String>) -> Self {
        self.columns.push(Column::new(name.into(), values));
        self
    }

    pub fn into_frame(self) -> Result<DataFrame> {
        DataFrame::new_infer_height(self.columns).map_err(|e| Error::Compute(format!("building a table: {e}")))
    }
}

/// Writes a table to `path` as Parquet (zstd-compressed), atomically.
pub fn write_parquet(path: &Path, table: Table) -> Result<()> {
    let mut df = table.into_frame()?;
    atomic::write_with(path, |file| {
        ParquetWriter::new(file)
            .with_compression(ParquetCompression::Zstd(None))
            .finish(&mut df)
            .map(|_| ())
            .map_err(|e| Error::output(path, e))
    })
}

/// Reads a Parquet file back (for tests and for later stages).
pub fn read_parquet(path: &Path) -> Result<DataFrame> {
    let file = std::fs::File::open(path).map_err(|e| Error::input(path, format!("cannot open: {e}")))?;
    crate::error::guard_foreign(|| ParquetReader::new(file).finish())
        .ok_or_else(|| Error::input(path, "not a readable Parquet file (damaged: its decoder failed)"))?
        .map_err(|e| Error::input(path, format!("not a readable Parquet file: {e}")))
}

/// A float column of a table read back, with a clear error naming `path`.
pub fn f64_column(df: &DataFrame, name: &str, path: &Path) -> Result<Vec<f64>> {
    let col = df.column(name).map_err(|_| Error::input(path, format!("no column '{name}'")))?;
    let col = col.cast(&DataType::Float64).map_err(|e| Error::input(path, format!("column '{name}': {e}")))?;
    let ca = col.f64().map_err(|e| Error::input(path, format!("column '{name}': {e}")))?;
    Ok((0..ca.len()).map(|i| ca.get(i).unwrap_or(f64::NAN)).collect())
}

/// A string column of a table read back.
pub fn str_column(df: &DataFrame, name: &str, path: &Path) -> Result<Vec<String>> {
    let col = df.column(name).map_err(|_| Error::input(path, format!("no column '{name}'")))?;
    let ca = col.str().map_err(|e| Error::input(path, format!("column '{name}': {e}")))?;
    Ok((0..ca.len()).map(|i| ca.get(i).unwrap_or("").to_string()).collect())
}

/// The column names of a table read back.
pub fn column_names(df: &DataFrame) -> Vec<String> {
    df.get_column_names().iter().map(|s| s.to_string()).collect()
}
