//! Column tables written as Parquet, for pandas, polars, DuckDB and R.

use std::path::Path;

use polars::prelude::*;

use crate::atomic;
use crate::error::{Error, Result};

/// The key of a derived table's file-level metadata naming the calibration
/// it was derived from (`pyarrow.parquet.read_schema(path).metadata`).
pub const CALIBRATION_ID: &str = "mrbp.calibration_id";

/// A table built column by column; each column a name and its values; and
/// file-level key-value metadata.
#[derive(Default)]
pub struct Table {
    columns: Vec<Column>,
    metadata: Vec<(String, String)>,
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

    /// A key-value pair of the file's metadata.
    pub fn meta(mut self, key: &str, value: &str) -> Self {
        self.metadata.push((key.to_string(), value.to_string()));
        self
    }

    /// Names the calibration the table was derived from.
    pub fn derived_from(self, calibration_id: &str) -> Self {
        self.meta(CALIBRATION_ID, calibration_id)
    }

    pub fn into_frame(self) -> Result<DataFrame> {
        DataFrame::new_infer_height(self.columns)
            .map_err(|e| Error::Compute(format!("building a table: {e}")))
    }
}

/// Writes a table to `path` as Parquet (zstd-compressed), atomically.
pub fn write_parquet(path: &Path, table: Table) -> Result<()> {
    atomic::write_with(path, |file| encode(table, file).map_err(|e| Error::output(path, e)))
}

/// The bytes of the Parquet file [`write_parquet`] would write: the same
/// table in memory (the Python package reads them as a frame).
pub fn parquet_bytes(table: Table) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    encode(table, &mut bytes).map_err(|e| Error::Compute(format!("encoding a table: {e}")))?;
    Ok(bytes)
}

fn encode(
    table: Table,
    sink: impl std::io::Write,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    let metadata =
        (!table.metadata.is_empty()).then(|| KeyValueMetadata::from_static(table.metadata.clone()));
    let mut df = table.into_frame()?;
    ParquetWriter::new(sink)
        .with_compression(ParquetCompression::Zstd(None))
        .with_key_value_metadata(metadata)
        .finish(&mut df)?;
    Ok(())
}

/// Reads a Parquet file back (for tests and for later stages).
pub fn read_parquet(path: &Path) -> Result<DataFrame> {
    let file =
        std::fs::File::open(path).map_err(|e| Error::input(path, format!("cannot open: {e}")))?;
    crate::error::guard_foreign(|| ParquetReader::new(file).finish())
        .ok_or_else(|| {
            Error::input(path, "not a readable Parquet file (damaged: its decoder failed)")
        })?
        .map_err(|e| Error::input(path, format!("not a readable Parquet file: {e}")))
}

/// The value of `key` in the file-level metadata of the Parquet file at
/// `path`, if it has one.
pub fn parquet_meta(path: &Path, key: &str) -> Result<Option<String>> {
    let file =
        std::fs::File::open(path).map_err(|e| Error::input(path, format!("cannot open: {e}")))?;
    let mut reader = ParquetReader::new(file);
    let metadata = crate::error::guard_foreign(|| reader.get_metadata().cloned())
        .ok_or_else(|| {
            Error::input(path, "not a readable Parquet file (damaged: its decoder failed)")
        })?
        .map_err(|e| Error::input(path, format!("not a readable Parquet file: {e}")))?;
    let pairs = metadata.key_value_metadata.as_deref().unwrap_or_default();
    Ok(pairs.iter().find(|kv| kv.key == key).and_then(|kv| kv.value.clone()))
}

/// Checks that the table at `path` was derived from calibration `id`; a file
/// without the mark (written before mrbp marked its files) passes.
/// `rebuild` is the command that makes it afresh.
pub fn check_derived(path: &Path, id: &str, rebuild: &str) -> Result<()> {
    match parquet_meta(path, CALIBRATION_ID)? {
        Some(found) if found != id => Err(Error::input(path, stale(&found, id, rebuild))),
        _ => Ok(()),
    }
}

/// What a file derived from calibration `found` is, in a folder that holds
/// calibration `id`; `rebuild` makes it afresh.
pub fn stale(found: &str, id: &str, rebuild: &str) -> String {
    format!("stale: derived from calibration {found}, not from {id}, the one this folder holds; rebuild it with `{rebuild}`")
}

/// A float column of a table read back, with a clear error naming `path`.
pub fn f64_column(df: &DataFrame, name: &str, path: &Path) -> Result<Vec<f64>> {
    let col = df.column(name).map_err(|_| Error::input(path, format!("no column '{name}'")))?;
    let col = col
        .cast(&DataType::Float64)
        .map_err(|e| Error::input(path, format!("column '{name}': {e}")))?;
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
