//! depthsense-report (layer 5, ARCHITECTURE.md) — `depthsense report`: one self-contained page of every experiment output found under some
//! run folders — ablation, reduced data, sensor failure, calibration perturbation, cost,
//! Grad-CAM++ (explain), evaluation tables (main, region and distance-cap tables), the MER
//! coverage report and the demo's report folder.
//!
//! Outputs are recognised by their file names (`ablation.json`, `reduced_data.json`,
//! `data_scale.json`,
//! `failure.json`, `perturb.json`, `cost.json`, `explain.json`, `tables.json`) or, for the MER
//! report (`mer report --json FILE`, any name), by its JSON fields; the demo's `OUT/report/` by
//! its `summary.json` (its README, tables, curves and every sample row). Each becomes one section:
//! its document (`metrics::doc::Doc`: built from the JSON and rendered by the page's template,
//! or the writer's Markdown file rendered by [`markdown`]), its plot or figure grid, and the
//! command and data that produced it (the JSON's `command_line` / options).
//!
//! REPORT/ gets `report.html` (images embedded as `data:` URIs, inline CSS, no script, no
//! external link), `report.md` (the same content, images copied to `img/`) and `report.json`
//! (what was found and skipped). Images wider than [`ReportOptions::max_width`] are
//! downscaled before embedding; figure-grid tiles to [`ReportOptions::tile_width`]. The
//! folder is written beside REPORT and renamed into place (never half-written).

mod discover;
mod found;
mod html;
mod images;
pub mod markdown;
mod runs;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use discover::{discover, Discovery, DEMO_SUMMARY};
pub use images::{base64, Embedded};

/// Errors of the report: each names the file or folder at fault.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {reason}", .path.display())]
    Invalid { path: PathBuf, reason: String },
    #[error("no experiment output found under {}", display_list(.0))]
    Nothing(Vec<PathBuf>),
    #[error(
        "{} already holds a report ({files}); nothing was changed: pass --force to replace \
         it (only report.html, report.md, report.json and img/ are replaced) or choose another --out",
        .dir.display()
    )]
    Exists { dir: PathBuf, files: String },
}

/// `a, b, c` of paths, for a message.
fn display_list(paths: &[PathBuf]) -> String {
    let shown: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    shown.join(", ")
}

impl ReportError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub fn invalid(path: &Path, reason: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }
}

/// The kinds of output the report knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kind {
    /// The comparison of every model found (built from the other sections).
    Models,
    Ablation,
    ReducedData,
    DataScale,
    Failure,
    Perturb,
    Cost,
    Explain,
    Eval,
    Mer,
    /// A training run (`train`, `mer train`): config.json + metrics.jsonl.
    Train,
    /// An exported model beside its sidecar (`export`).
    Export,
    Demo,
}

impl Kind {
    pub const ALL: [Kind; 13] = [
        Kind::Models,
        Kind::Demo,
        Kind::Ablation,
        Kind::ReducedData,
        Kind::DataScale,
        Kind::Failure,
        Kind::Perturb,
        Kind::Cost,
        Kind::Explain,
        Kind::Eval,
        Kind::Mer,
        Kind::Train,
        Kind::Export,
    ];

    /// The file stem of the writer's outputs (`<stem>.{md,csv,json,png}`); the MER report has
    /// none (recognised by content).
    pub fn stem(self) -> Option<&'static str> {
        Some(match self {
            Kind::Ablation => "ablation",
            Kind::ReducedData => "reduced_data",
            Kind::DataScale => "data_scale",
            Kind::Failure => "failure",
            Kind::Perturb => "perturb",
            Kind::Cost => "cost",
            Kind::Explain => "explain",
            Kind::Eval => "tables",
            Kind::Mer | Kind::Demo | Kind::Models | Kind::Train | Kind::Export => return None,
        })
    }

    /// Its name in report.json and in the section anchors.
    pub fn slug(self) -> &'static str {
        match self {
            Kind::Ablation => "ablation",
            Kind::ReducedData => "reduced-data",
            Kind::DataScale => "data-scale",
            Kind::Failure => "failure",
            Kind::Perturb => "perturb",
            Kind::Cost => "cost",
            Kind::Explain => "explain",
            Kind::Eval => "eval",
            Kind::Mer => "mer",
            Kind::Demo => "demo",
            Kind::Models => "models",
            Kind::Train => "train",
            Kind::Export => "export",
        }
    }

    /// Section heading.
    pub fn title(self) -> &'static str {
        match self {
            Kind::Ablation => "Ablation: fusion variants and loss (SPEC §10.1, §10.4)",
            Kind::ReducedData => "Reduced training data (SPEC §10.5)",
            Kind::DataScale => "Radar's margin against training-set size",
            Kind::Failure => "Sensor failure (SPEC §10.8)",
            Kind::Perturb => "Calibration perturbation (SPEC §10.7)",
            Kind::Cost => "Parameters, MACs, inference time (SPEC §10.9)",
            Kind::Explain => "Grad-CAM++ by distance class (SPEC §10.6)",
            Kind::Eval => "Evaluation: main, region and distance-cap tables (SPEC §10.1–10.3)",
            Kind::Mer => "MER: radar map coverage and error (SPEC §5)",
            Kind::Demo => "Demo: RGB-only vs radar fusion on a synthetic world",
            Kind::Models => "Models compared",
            Kind::Train => "Training run",
            Kind::Export => "Exported model",
        }
    }

    /// The command that writes it.
    pub fn writer(self) -> &'static str {
        match self {
            Kind::Ablation => "depthsense experiment ablation",
            Kind::ReducedData => "depthsense experiment reduced-data",
            Kind::DataScale => "depthsense experiment data-scale",
            Kind::Failure => "depthsense experiment failure",
            Kind::Perturb => "depthsense experiment perturb",
            Kind::Cost => "depthsense experiment cost",
            Kind::Explain => "depthsense explain",
            Kind::Eval => "depthsense eval",
            Kind::Mer => "depthsense mer report --json FILE",
            Kind::Demo => "depthsense demo",
            Kind::Models => "depthsense report",
            Kind::Train => "depthsense train / mer train",
            Kind::Export => "depthsense export",
        }
    }
}

/// One image of a section, as embedded.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ImageInfo {
    /// The source file.
    pub source: PathBuf,
    /// Where report.md references it (relative to REPORT/).
    pub copy: PathBuf,
    pub caption: String,
    pub original_size: (u32, u32),
    pub embedded_size: (u32, u32),
    pub embedded_bytes: usize,
}

/// One experiment output found.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Section {
    pub kind: Kind,
    /// In-page anchor (`id`) of the section.
    pub anchor: String,
    pub title: String,
    /// The folder holding the output.
    pub source_dir: PathBuf,
    /// The output's files (JSON, Markdown, CSV, images) found in `source_dir`.
    pub files: Vec<PathBuf>,
    /// The invocation that wrote it, as recorded in its JSON (`None`: not recorded).
    pub command_line: Option<String>,
    /// Data, checkpoint and output folders named by its JSON / command line.
    pub inputs: Vec<(String, String)>,
    /// What the section says (built from the JSON, or the writer's own Markdown).
    #[serde(skip)]
    pub doc: depthsense_metrics::doc::Doc,
    /// Figure grid (explain): column labels, then rows of (row label, image indices).
    #[serde(skip)]
    pub grid: Option<FigureGrid>,
    pub images: Vec<ImageInfo>,
    /// Embedded images, parallel to `images`.
    #[serde(skip)]
    pub embedded: Vec<Embedded>,
}

/// A table of images (rows × columns) with labels; cells index `Section::images`.
#[derive(Debug, Clone, Default)]
pub struct FigureGrid {
    pub columns: Vec<String>,
    pub rows: Vec<(String, Vec<Option<usize>>)>,
}

/// A file or folder not used, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Skipped {
    pub path: PathBuf,
    pub reason: String,
}

/// What `report` does.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Folders searched (recursively, to `max_depth` levels below each).
    pub runs: Vec<PathBuf>,
    /// REPORT folder (report.html, report.md, report.json, img/).
    pub out: PathBuf,
    pub title: String,
    pub max_depth: usize,
    /// Plots and grids wider than this are downscaled (aspect kept) before embedding.
    pub max_width: u32,
    /// Figure-grid tiles (explain overlays) are downscaled to this width.
    pub tile_width: u32,
    /// The invocation, shown at the top of the page.
    pub command_line: Option<String>,
    /// Replace a report already in `out` (its own files only; `depthsense_dataset::outputs`).
    pub force: bool,
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self {
            runs: vec![],
            out: PathBuf::from("runs/report"),
            title: "depthsense report".into(),
            max_depth: 4,
            max_width: 1600,
            tile_width: 400,
            command_line: None,
            force: false,
        }
    }
}

/// What was written (= report.json).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReportSummary {
    pub title: String,
    pub command_line: Option<String>,
    pub runs: Vec<PathBuf>,
    pub sections: Vec<Section>,
    pub skipped: Vec<Skipped>,
    /// Size of report.html in bytes.
    pub html_bytes: usize,
}

/// What REPORT/ holds of the report's own (the only entries a rewrite replaces).
pub const REPORT_ENTRIES: [&str; 4] = ["img", "report.json", "report.md", "report.html"];

/// Discover and render: the summary and the HTML page (nothing is written).
pub fn render(opts: &ReportOptions) -> Result<(ReportSummary, String), ReportError> {
    let mut found = discover(&opts.runs, &opts.out, opts.max_depth)?;
    found
        .sections
        .sort_by(|a, b| (a.kind, &a.dir).cmp(&(b.kind, &b.dir)));
    if let Some(models) = runs::comparison(&found.sections) {
        found.sections.insert(0, models);
    }
    if found.sections.is_empty() {
        return Err(ReportError::Nothing(opts.runs.clone()));
    }
    let mut skipped = found.skipped;
    let mut sections = vec![];
    for (i, s) in found.sections.into_iter().enumerate() {
        sections.push(images::load_section(s, i, opts, &mut skipped));
    }
    let mut summary = ReportSummary {
        title: opts.title.clone(),
        command_line: opts.command_line.clone(),
        runs: opts.runs.clone(),
        sections,
        skipped,
        html_bytes: 0,
    };
    let page = html::page(&summary);
    summary.html_bytes = page.len();
    Ok((summary, page))
}

/// Discover, render and write REPORT/ (a sibling temp folder, then renamed into place; into an
/// existing REPORT entry by entry). A report already there is refused without `opts.force`.
pub fn build_report(opts: &ReportOptions) -> Result<ReportSummary, ReportError> {
    let existing: Vec<&str> = REPORT_ENTRIES
        .into_iter()
        .filter(|e| opts.out.join(e).exists())
        .collect();
    if !existing.is_empty() && !opts.force {
        return Err(ReportError::Exists {
            dir: opts.out.clone(),
            files: existing.join(", "),
        });
    }
    let (summary, page) = render(opts)?;
    write_folder(&opts.out, &summary, &page)?;
    Ok(summary)
}

/// Write REPORT/ into a temp sibling, then move it (or its entries) into place.
fn write_folder(out: &Path, s: &ReportSummary, page: &str) -> Result<(), ReportError> {
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(|e| ReportError::io(&parent, e))?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| ReportError::invalid(out, "--out needs a folder name"))?;
    let tmp = parent.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = fill_folder(&tmp, s, page).and_then(|()| swap_in(&tmp, out));
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result
}

fn fill_folder(dir: &Path, s: &ReportSummary, page: &str) -> Result<(), ReportError> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(|e| ReportError::io(dir, e))?;
    }
    let img = dir.join("img");
    std::fs::create_dir_all(&img).map_err(|e| ReportError::io(&img, e))?;
    for sec in &s.sections {
        for (info, emb) in sec.images.iter().zip(&sec.embedded) {
            let p = dir.join(&info.copy);
            std::fs::write(&p, &emb.png).map_err(|e| ReportError::io(&p, e))?;
        }
    }
    let json = serde_json::to_string_pretty(s)
        .map_err(|e| ReportError::invalid(&dir.join("report.json"), e.to_string()))?;
    for (file, text) in [
        ("report.html", page.to_string()),
        ("report.md", html::markdown_page(s)),
        ("report.json", json),
    ] {
        let p = dir.join(file);
        std::fs::write(&p, text).map_err(|e| ReportError::io(&p, e))?;
    }
    Ok(())
}

/// Rename `tmp` to `out`; into an existing `out`, move each of the report's own entries
/// ([`REPORT_ENTRIES`]; each rename is atomic, `img/` is swapped as a folder) and leave every
/// other file there alone.
fn swap_in(tmp: &Path, out: &Path) -> Result<(), ReportError> {
    if !out.exists() {
        return std::fs::rename(tmp, out).map_err(|e| ReportError::io(out, e));
    }
    for entry in REPORT_ENTRIES {
        let (src, dst) = (tmp.join(entry), out.join(entry));
        if dst.is_dir() {
            let old = out.join(format!(".{entry}.{}.old", std::process::id()));
            std::fs::rename(&dst, &old).map_err(|e| ReportError::io(&dst, e))?;
            std::fs::rename(&src, &dst).map_err(|e| ReportError::io(&dst, e))?;
            std::fs::remove_dir_all(&old).map_err(|e| ReportError::io(&old, e))?;
        } else {
            std::fs::rename(&src, &dst).map_err(|e| ReportError::io(&dst, e))?;
        }
    }
    std::fs::remove_dir_all(tmp).map_err(|e| ReportError::io(tmp, e))
}
