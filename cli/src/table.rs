//! Reading run tables (CSV) for `repose analyze`: every problem becomes one line naming
//! the column, row or cell, because a lab user will fix the file by hand.

use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;

/// A numeric table read from CSV: named columns of finite values.
#[derive(Debug, Clone)]
pub struct RunTable {
    pub headers: Vec<String>,
    /// `rows[r][c]` is the value of column `c` in data row `r`.
    pub rows: Vec<Vec<Option<f64>>>,
}

impl RunTable {
    pub fn read(path: &Path) -> Result<RunTable> {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        Self::parse(&bytes).with_context(|| format!("in {}", path.display()))
    }

    /// Parses CSV with a header row. A cell that is not a
    /// number is only an error if its column is used (see [`RunTable::column`]), so a table may
    /// carry notes in columns nobody asked for.
    pub fn parse(bytes: &[u8]) -> Result<RunTable> {
        let mut reader = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .flexible(false)
            .from_reader(bytes);
        let headers: Vec<String> = reader
            .headers()
            .context("cannot read the header row")?
            .iter()
            .map(str::to_owned)
            .collect();
        if headers.iter().all(String::is_empty) {
            bail!("the header row is empty");
        }
        for (i, h) in headers.iter().enumerate() {
            if h.is_empty() {
                bail!("column {} has an empty name in the header row", i + 1);
            }
            if headers[..i].contains(h) {
                bail!("column name '{h}' appears twice in the header row");
            }
        }
        let mut rows = Vec::new();
        for (r, record) in reader.records().enumerate() {
            let record = record.map_err(|e| anyhow!("data row {}: {}", r + 1, csv_reason(&e)))?;
            rows.push(
                record
                    .iter()
                    .map(|cell| cell.parse::<f64>().ok())
                    .collect::<Vec<_>>(),
            );
        }
        if rows.is_empty() {
            bail!("the table has a header but no data rows");
        }
        Ok(RunTable { headers, rows })
    }

    pub fn index_of(&self, name: &str) -> Result<usize> {
        self.headers.iter().position(|h| h == name).ok_or_else(|| {
            anyhow!(
                "column '{name}' not found (columns: {})",
                self.headers.join(", ")
            )
        })
    }

    /// The finite values of one column, or an error naming the first bad cell.
    pub fn column(&self, name: &str) -> Result<Vec<f64>> {
        let c = self.index_of(name)?;
        self.rows
            .iter()
            .enumerate()
            .map(|(r, row)| match row[c] {
                Some(v) if v.is_finite() => Ok(v),
                Some(v) => Err(anyhow!(
                    "column '{name}', data row {}: value {v} is not a finite number",
                    r + 1
                )),
                None => Err(anyhow!(
                    "column '{name}', data row {}: cell is not a number",
                    r + 1
                )),
            })
            .collect()
    }
}

fn csv_reason(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => format!("has {len} cells but the header has {expected_len}"),
        csv::ErrorKind::Utf8 { .. } => "is not valid UTF-8".to_owned(),
        _ => e.to_string(),
    }
}
