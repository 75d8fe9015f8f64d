//! The paper's tables (SPEC §10 items 1–3) as Markdown and CSV, from one or more [`Report`]s.

use serde::Serialize;

use crate::doc::Doc;
use crate::table::{csv_field, csv_row, Align, MdTable, MISSING};
use crate::{Report, Row, CONDITIONS};

/// A rendered table: a title, a header and string cells.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table {
    pub title: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// `### title`, a blank line, then the table: the first two columns (model, cap or
    /// condition) left-aligned, the numbers right-aligned.
    pub fn to_markdown(&self) -> String {
        format!("### {}\n\n{}", self.title, self.md_table().finish())
    }

    /// The table without its title (what [`Table::to_markdown`] writes below it).
    pub fn md_table(&self) -> MdTable {
        let columns: Vec<(&str, Align)> = self
            .header
            .iter()
            .enumerate()
            .map(|(i, h)| (h.as_str(), if i < 2 { Align::Left } else { Align::Right }))
            .collect();
        let mut t = MdTable::new(&columns);
        for r in &self.rows {
            t.row(r);
        }
        t
    }

    /// CSV with a header line; fields containing a comma, quote or newline are quoted.
    pub fn to_csv(&self) -> String {
        let line =
            |cells: &[String]| csv_row(&cells.iter().map(|c| csv_field(c)).collect::<Vec<_>>());
        let mut s = line(&self.header);
        for r in &self.rows {
            s.push_str(&line(r));
        }
        s
    }
}

fn f3(x: f64) -> String {
    format!("{x:.3}")
}

fn counts(r: &Row) -> [String; 2] {
    [r.n_images.to_string(), r.n_pixels.to_string()]
}

fn empty_or<F: Fn(&Row) -> Vec<String>>(r: Option<&Row>, n: usize, f: F) -> Vec<String> {
    match r {
        Some(r) if r.n_images > 0 => f(r),
        Some(r) => {
            let mut v = counts(r).to_vec();
            v.extend(std::iter::repeat_n(MISSING.to_string(), n));
            v
        }
        None => std::iter::repeat_n(MISSING.to_string(), n + 2).collect(),
    }
}

/// SPEC §10.1 main table: δ1, RMSE (m), AbsRel for combined / day / night / rain,
/// full image, at the largest cap.
pub fn main_table(models: &[(&str, &Report)]) -> Table {
    let mut rows = Vec::new();
    let mut cap_txt = String::new();
    for (name, rep) in models {
        let cap = rep.config.main_cap();
        cap_txt = format!("{cap:.0} m");
        for cond in CONDITIONS {
            let mut row = vec![name.to_string(), cond.to_string()];
            row.extend(empty_or(rep.row(cond, "full", cap), 3, |r| {
                let mut v = counts(r).to_vec();
                v.extend([
                    f3(r.metrics.delta1),
                    f3(r.metrics.rmse),
                    f3(r.metrics.abs_rel),
                ]);
                v
            }));
            rows.push(row);
        }
    }
    Table {
        title: format!("Main table (SPEC §10.1): full image, cap {cap_txt}"),
        header: [
            "model",
            "condition",
            "images",
            "pixels",
            "δ1",
            "RMSE (m)",
            "AbsRel",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }
}

/// SPEC §10.2 MER-style table: full image and low-height region, combined, largest cap:
/// δ1, δ2, δ3, RMSE (m), AbsRel, RMSE_log.
pub fn region_table(models: &[(&str, &Report)]) -> Table {
    let mut rows = Vec::new();
    let mut cap_txt = String::new();
    for (name, rep) in models {
        let cap = rep.config.main_cap();
        cap_txt = format!("{cap:.0} m");
        for region in crate::REGIONS {
            let mut row = vec![name.to_string(), crate::region_label(region).to_string()];
            row.extend(empty_or(rep.row("combined", region, cap), 6, |r| {
                let m = &r.metrics;
                let mut v = counts(r).to_vec();
                v.extend([
                    f3(m.delta1),
                    f3(m.delta2),
                    f3(m.delta3),
                    f3(m.rmse),
                    f3(m.abs_rel),
                    f3(m.rmse_log),
                ]);
                v
            }));
            rows.push(row);
        }
    }
    Table {
        title: format!("Region table (SPEC §10.2): combined, cap {cap_txt}"),
        header: [
            "model", "region", "images", "pixels", "δ1", "δ2", "δ3", "RMSE (m)", "AbsRel",
            "RMSE_log",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }
}

/// SPEC §10.3 distance table: MAE and RMSE in millimetres at every cap, combined, full image.
pub fn distance_table(models: &[(&str, &Report)]) -> Table {
    let mut rows = Vec::new();
    for (name, rep) in models {
        for &cap in &rep.config.caps_m {
            let mut row = vec![name.to_string(), format!("{cap:.0} m")];
            row.extend(empty_or(rep.row("combined", "full", cap), 2, |r| {
                let mut v = counts(r).to_vec();
                v.extend([
                    format!("{:.0}", r.metrics.mae * 1000.0),
                    format!("{:.0}", r.metrics.rmse * 1000.0),
                ]);
                v
            }));
            rows.push(row);
        }
    }
    Table {
        title: "Distance table (SPEC §10.3): combined, full image".to_string(),
        header: ["model", "cap", "images", "pixels", "MAE (mm)", "RMSE (mm)"]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The three tables in order.
pub fn all_tables(models: &[(&str, &Report)]) -> Vec<Table> {
    vec![
        main_table(models),
        region_table(models),
        distance_table(models),
    ]
}

/// All three tables as one Markdown document, with the protocol/aggregation noted (as printed
/// by `eval`: [`report_doc`] and a closing empty line).
pub fn markdown_report(models: &[(&str, &Report)]) -> String {
    report_doc(models).to_markdown() + "\n"
}

/// All three tables as a document: the protocol/aggregation line, then each table under its
/// `###` title.
pub fn report_doc(models: &[(&str, &Report)]) -> Doc {
    let mut doc = Doc::new();
    if let Some((_, rep)) = models.first() {
        doc.paragraph(format!(
            "Protocol `{}`, aggregation `{}`, predictions clipped to [{}, {}] m (SPEC §9).",
            serde_json::to_value(rep.config.protocol)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default(),
            serde_json::to_value(rep.config.aggregate)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default(),
            rep.config.clip_min_m,
            rep.config.clip_max_m
        ));
    }
    for t in all_tables(models) {
        doc.heading(3, t.title.clone()).table(t.md_table());
    }
    doc
}

/// The three tables as one CSV: a `table` column first, one header line per table.
pub fn csv_report(models: &[(&str, &Report)]) -> String {
    let mut s = String::new();
    for (i, t) in all_tables(models).iter().enumerate() {
        if i > 0 {
            s.push('\n');
        }
        s.push_str(&format!("# {}\n", t.title));
        s.push_str(&t.to_csv());
    }
    s
}
