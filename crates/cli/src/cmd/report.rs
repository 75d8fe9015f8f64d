//! `depthsense report`: every experiment output found under some run folders, gathered into
//! one self-contained HTML page (plus Markdown and JSON).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use depthsense_report::{build_report, ReportOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Folders searched, recursively, for experiment outputs: ablation.json, reduced_data.json,
    /// data_scale.json, failure.json, perturb.json, cost.json, explain.json, tables.json (eval)
    /// and MER reports (`mer report --json`), each with its .md/.csv/.png beside it.
    #[arg(long, required = true, num_args = 1.., value_name = "DIR")]
    pub runs: Vec<PathBuf>,
    /// Output folder: report.html (self-contained), report.md with img/, report.json. A report
    /// already there is refused unless --force.
    #[arg(long, value_name = "REPORT")]
    pub out: PathBuf,
    /// Replace a report already in --out (only report.html, report.md, report.json and img/;
    /// other files in the folder are left alone).
    #[arg(long)]
    pub force: bool,
    /// Title of the page.
    #[arg(long, default_value = "depthsense report")]
    pub title: String,
    /// How many folder levels below each --runs DIR are searched.
    #[arg(long, default_value_t = 4)]
    pub max_depth: usize,
    /// Plots and grids wider than this many pixels are downscaled before embedding.
    #[arg(long, default_value_t = 1600)]
    pub max_width: u32,
    /// Width in pixels of each tile of a figure grid (explain overlays).
    #[arg(long, default_value_t = 400)]
    pub tile_width: u32,
}

/// A page larger than this gets a warning (browsers and mail handle it, but slowly).
const LARGE_PAGE_BYTES: usize = 20_000_000;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let opts = ReportOptions {
        runs: a.runs,
        out: a.out,
        title: a.title,
        max_depth: a.max_depth,
        max_width: a.max_width.max(16),
        tile_width: a.tile_width.max(16),
        command_line: Some(crate::command_line()),
        force: a.force,
    };
    let s = build_report(&opts).with_context(|| format!("report → {}", opts.out.display()))?;
    for sec in &s.sections {
        // Pictures embedded in the page (not the images a table evaluated).
        let pictures = match sec.images.len() {
            0 => String::new(),
            1 => " (1 picture)".to_string(),
            n => format!(" ({n} pictures)"),
        };
        eprintln!(
            "{:<13} {}{pictures}",
            serde_json::to_value(sec.kind)?.as_str().unwrap_or("?"),
            if sec.source_dir.as_os_str().is_empty() {
                "every model found".to_string()
            } else {
                sec.source_dir.display().to_string()
            },
        );
    }
    eprintln!(
        "{} sections, {} files skipped (listed in the report); report.html {:.1} MB → {}",
        s.sections.len(),
        s.skipped.len(),
        s.html_bytes as f64 / 1e6,
        opts.out.display()
    );
    if s.html_bytes > LARGE_PAGE_BYTES {
        eprintln!(
            "warning: report.html is over {} MB; --max-width / --tile-width make it smaller",
            LARGE_PAGE_BYTES / 1_000_000
        );
    }
    Ok(ExitCode::SUCCESS)
}
