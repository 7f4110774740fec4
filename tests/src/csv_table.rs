//! A recording written as CSV (`rt-loop run --record x.csv`), read back by column name: what
//! the system tests check the loop's rows with.

use std::collections::HashMap;
use std::path::Path;

/// The header's column indices and every row's cells, as text.
pub struct CsvTable {
    cols: HashMap<String, usize>,
    rows: Vec<Vec<String>>,
}

impl CsvTable {
    pub fn read(path: &Path) -> CsvTable {
        let text = std::fs::read_to_string(path).expect("read recording");
        let mut lines = text.lines();
        let header = lines.next().expect("header");
        let cols = header
            .split(',')
            .enumerate()
            .map(|(i, n)| (n.to_string(), i))
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect();
        CsvTable { cols, rows }
    }

    /// How many rows (steps) the recording holds.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// One column's cells, as written.
    pub fn col(&self, name: &str) -> Vec<&str> {
        let i = self.cols[name];
        self.rows.iter().map(|r| r[i].as_str()).collect()
    }

    /// One column as numbers (NaN and empty cells as NaN); panics on anything else.
    pub fn f64s(&self, name: &str) -> Vec<f64> {
        self.col(name)
            .iter()
            .map(|v| match *v {
                "NaN" | "nan" | "" => f64::NAN,
                _ => v.parse().unwrap_or_else(|e| panic!("{name}: {v:?}: {e}")),
            })
            .collect()
    }

    /// One column as booleans (`true`, `1`, `True`).
    pub fn bools(&self, name: &str) -> Vec<bool> {
        self.col(name)
            .iter()
            .map(|v| matches!(*v, "true" | "1" | "True"))
            .collect()
    }
}
