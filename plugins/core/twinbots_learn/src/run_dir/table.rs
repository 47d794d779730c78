//! A CSV file of numbers read by column name: its header says which column is which, so a
//! reader never depends on the order the writer chose (and a column added later breaks
//! nothing). Cells hold no commas or quotes (they are numbers or empty).

use std::path::Path;
use std::str::FromStr;

/// The rows of a CSV file, with its header.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub header: Vec<String>,
    /// Each row as written, and its cells.
    rows: Vec<(String, Vec<String>)>,
}

/// One row, whose cells are looked up by column name.
#[derive(Clone, Copy, Debug)]
pub struct Row<'a> {
    header: &'a [String],
    /// The row's text as written.
    pub line: &'a str,
    cells: &'a [String],
}

impl Table {
    pub fn parse(text: &str) -> Self {
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let split = |l: &str| l.split(',').map(|c| c.trim().to_string()).collect::<Vec<_>>();
        let header = lines.next().map(split).unwrap_or_default();
        let rows = lines.map(|l| (l.to_string(), split(l))).collect();
        Self { header, rows }
    }

    /// The file at `path`; a missing file reads as an empty table.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        match std::fs::read_to_string(path) {
            Ok(text) => Ok(Self::parse(&text)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Self::default()),
            Err(e) => Err(anyhow::anyhow!("{}: {e}", path.display())),
        }
    }

    pub fn rows(&self) -> impl Iterator<Item = Row<'_>> {
        self.rows.iter().map(|(line, cells)| Row { header: &self.header, line, cells })
    }

    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

impl Row<'_> {
    /// The cell of column `name`, parsed; `None` if the column is missing, the cell empty or
    /// not a `T`.
    pub fn get<T: FromStr>(&self, name: &str) -> Option<T> {
        let i = self.header.iter().position(|h| h == name)?;
        self.cells.get(i).filter(|c| !c.is_empty())?.parse().ok()
    }

    /// A number of column `name`, NaN where there is none.
    pub fn number(&self, name: &str) -> f32 {
        self.get(name).unwrap_or(f32::NAN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_found_by_column_name_whatever_the_order() {
        let a = Table::parse("timesteps,mean_reward,success_rate\n64,9.5,\n128,12,0.5\n");
        let b = Table::parse("success_rate,timesteps,extra,mean_reward\n,64,x,9.5\n0.5,128,y,12\n");
        for t in [&a, &b] {
            let rows: Vec<Row> = t.rows().collect();
            assert_eq!(rows.len(), 2);
            assert_eq!(rows[0].get::<u64>("timesteps"), Some(64));
            assert_eq!(rows[1].number("mean_reward"), 12.0);
            assert!(rows[0].number("success_rate").is_nan(), "an empty cell is no number");
            assert_eq!(rows[1].get::<f32>("success_rate"), Some(0.5));
            assert_eq!(rows[0].get::<f32>("no_such_column"), None);
        }
    }
}
