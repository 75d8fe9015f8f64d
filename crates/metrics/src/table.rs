//! Tables as text: the one Markdown table writer and CSV row writer of every experiment, and the
//! renderings of a value that is absent.
//!
//! Missing values, as the outputs have always shown them: [`MISSING`] ("–") in Markdown cells
//! ([`md_num`], [`md_or_missing`]); an empty field in CSV ([`csv_num`], which also leaves
//! non-finite values empty). A Markdown column may use the CSV rendering where an empty cell is
//! its established look ([`csv_num`] in the ablation's "best val RMSE" column).

/// A Markdown cell with no value.
pub const MISSING: &str = "–";

/// Column alignment of a Markdown table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Align {
    Left,
    Right,
}

/// A Markdown table: column titles with their alignment, then rows of cells (inline Markdown:
/// `code`, **bold**). As text ([`MdTable::finish`]): a header row, the separator row, then one
/// line per row; every line is `| a | b |` and ends with a newline. The report renders the same
/// value as an HTML table (`doc`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MdTable {
    pub columns: Vec<(String, Align)>,
    pub rows: Vec<Vec<String>>,
}

impl MdTable {
    /// A table with these column titles and alignments (`Left` → `---`, `Right` → `---:`).
    pub fn new(columns: &[(&str, Align)]) -> Self {
        Self {
            columns: columns.iter().map(|(t, a)| (t.to_string(), *a)).collect(),
            rows: vec![],
        }
    }

    /// Append one row (as many cells as columns).
    pub fn row<S: AsRef<str>>(&mut self, cells: &[S]) -> &mut Self {
        debug_assert_eq!(cells.len(), self.columns.len(), "cells of a Markdown row");
        self.rows
            .push(cells.iter().map(|c| c.as_ref().to_string()).collect());
        self
    }

    /// The table's text.
    pub fn finish(self) -> String {
        self.to_markdown()
    }

    /// The table's text, the table kept.
    pub fn to_markdown(&self) -> String {
        let titles: Vec<&str> = self.columns.iter().map(|(t, _)| t.as_str()).collect();
        let mut text = format!("| {} |\n|", titles.join(" | "));
        for (_, a) in &self.columns {
            text.push_str(match a {
                Align::Left => "---|",
                Align::Right => "---:|",
            });
        }
        text.push('\n');
        for r in &self.rows {
            text.push_str(&format!("| {} |\n", r.join(" | ")));
        }
        text
    }
}

/// `x` with `prec` decimals, or [`MISSING`] when absent (a present non-finite value prints as
/// Rust formats it).
pub fn md_num(x: Option<f64>, prec: usize) -> String {
    md_or_missing(x.map(|v| format!("{v:.prec$}")))
}

/// The text, or [`MISSING`] when absent.
pub fn md_or_missing(s: Option<String>) -> String {
    s.unwrap_or_else(|| MISSING.to_string())
}

/// `x` with `prec` decimals, or an empty field when absent or not finite.
pub fn csv_num(x: Option<f64>, prec: usize) -> String {
    x.filter(|v| v.is_finite())
        .map_or(String::new(), |v| format!("{v:.prec$}"))
}

/// A CSV field in double quotes (names that may hold commas; the names written here hold no
/// double quotes, which are therefore not escaped).
pub fn csv_quoted(s: &str) -> String {
    format!("\"{s}\"")
}

/// A CSV field as RFC 4180 writes it: in double quotes (inner quotes doubled) when it holds a
/// comma, a double quote or a newline, else as is.
pub fn csv_field(s: &str) -> String {
    if s.contains(',') || s.contains('"') || s.contains('\n') {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A CSV line: the fields joined by commas, then a newline.
pub fn csv_row<S: AsRef<str>>(fields: &[S]) -> String {
    let f: Vec<&str> = fields.iter().map(|c| c.as_ref()).collect();
    format!("{}\n", f.join(","))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_table_layout() {
        let mut t = MdTable::new(&[("name", Align::Left), ("RMSE (m)", Align::Right)]);
        t.row(&["a", "1.000"])
            .row(&["b".to_string(), md_num(None, 3)]);
        assert_eq!(
            t.finish(),
            "| name | RMSE (m) |\n|---|---:|\n| a | 1.000 |\n| b | – |\n"
        );
    }

    #[test]
    fn missing_values_per_format() {
        assert_eq!(md_num(Some(1.23456), 3), "1.235");
        assert_eq!(md_num(Some(f64::NAN), 1), "NaN");
        assert_eq!(md_num(None, 3), "–");
        assert_eq!(csv_num(Some(2.5), 2), "2.50");
        assert_eq!(csv_num(Some(f64::INFINITY), 2), "");
        assert_eq!(csv_num(None, 2), "");
        assert_eq!(
            csv_row(&[csv_quoted("a,b"), "1".into(), String::new()]),
            "\"a,b\",1,\n"
        );
        assert_eq!(csv_field("plain"), "plain");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
    }
}
