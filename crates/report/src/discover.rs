//! Finding experiment outputs under the run folders, by file name (MER: by JSON fields).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use depthsense_metrics::doc::Doc;
use depthsense_records::tables::TablesRecord;
use depthsense_score::mer_coverage::{report_doc, CoverageRow, MerReport};
use serde::Deserialize;
use serde_json::Value;

use super::found::{file_name, read_json, string_at, Found, ImageSource, ModelRow};
use super::{FigureGrid, Kind, ReportError, Skipped};

/// JSON files larger than this are not opened to look for a MER report.
const MAX_PROBE_BYTES: u64 = 4 << 20;
/// At most this many rows of explain overlays (sample × radar state) go into the grid.
pub const MAX_GRID_ROWS: usize = 8;

/// Everything found under the run folders.
#[derive(Debug, Default)]
pub struct Discovery {
    pub sections: Vec<Found>,
    pub skipped: Vec<Skipped>,
}

/// Search each of `runs` (to `max_depth` levels below it; `out` and earlier reports are not
/// searched). A run folder that does not exist is an error; anything unreadable below it is
/// skipped with the reason.
pub fn discover(runs: &[PathBuf], out: &Path, max_depth: usize) -> Result<Discovery, ReportError> {
    let out_abs = std::fs::canonicalize(out).ok();
    let mut d = Discovery::default();
    let mut seen = BTreeSet::new();
    for root in runs {
        if !root.is_dir() {
            return Err(ReportError::invalid(root, "not a folder (--runs)"));
        }
        let mut stack = vec![(root.clone(), 0usize)];
        while let Some((dir, depth)) = stack.pop() {
            let canon = std::fs::canonicalize(&dir).unwrap_or_else(|_| dir.clone());
            if Some(&canon) == out_abs.as_ref() || !seen.insert(canon) {
                continue;
            }
            let subdirs = visit(&dir, depth == 0, &mut d);
            if depth < max_depth {
                stack.extend(subdirs.into_iter().rev().map(|s| (s, depth + 1)));
            }
        }
    }
    // The demo's section (in DEMO/report/) shows its two training runs (DEMO/rgb, DEMO/fusion)
    // itself: they are not sections of their own, but their validation rows stay in the
    // comparison (as the demo's).
    let demos: Vec<(usize, PathBuf)> = d
        .sections
        .iter()
        .enumerate()
        .filter(|(_, s)| s.kind == Kind::Demo)
        .filter_map(|(i, s)| Some((i, s.dir.parent()?.to_path_buf())))
        .collect();
    let of_demo = |s: &Found| {
        (s.kind == Kind::Train)
            .then(|| demos.iter().find(|(_, demo)| s.dir.starts_with(demo)))
            .flatten()
            .map(|(i, _)| *i)
    };
    let moved: Vec<(usize, Vec<ModelRow>)> = d
        .sections
        .iter()
        .filter_map(|s| Some((of_demo(s)?, s.models.clone())))
        .collect();
    for (i, rows) in moved {
        d.sections[i].models.extend(rows);
    }
    d.sections.retain(|s| of_demo(s).is_none());
    Ok(d)
}

/// Look at one folder: record its outputs; return the subfolders to search.
fn visit(dir: &Path, is_root: bool, d: &mut Discovery) -> Vec<PathBuf> {
    let (files, dirs) = match list(dir) {
        Ok(x) => x,
        Err(e) => {
            d.skipped.push(skip(dir, format!("cannot list: {e}")));
            return vec![];
        }
    };
    let names: BTreeSet<&str> = files.iter().filter_map(|p| file_name(p)).collect();
    if names.contains(DEMO_SUMMARY) {
        // The demo's report folder (it may hold its own report.html): one section, and its
        // samples/ subfolder is part of it.
        match read_json(&dir.join(DEMO_SUMMARY)).and_then(|v| demo(dir, &v, &files, &dirs)) {
            Ok(f) => {
                d.sections.push(f);
                return vec![];
            }
            Err(reason) => d.skipped.push(skip(&dir.join(DEMO_SUMMARY), reason)),
        }
    }
    if names.contains("report.html") || names.contains("index.json") {
        // An earlier report, or prepared data: nothing of ours inside.
        return vec![];
    }
    let mut claimed: BTreeSet<PathBuf> = BTreeSet::new();
    let before = d.sections.len();
    runs_and_exports(dir, &files, &names, &mut claimed, d);
    named_outputs(dir, &names, &mut claimed, d);
    probe_mer(dir, &files, &mut claimed, d);
    if is_root || d.sections.len() > before {
        for f in files.iter().filter(|f| !claimed.contains(*f)) {
            d.skipped
                .push(skip(f, "not an experiment output the report knows".into()));
        }
    }
    // An experiment of many training runs summarises them itself: its run folders are not
    // sections of their own.
    let summarises_runs = d.sections[before..]
        .iter()
        .any(|s| matches!(s.kind, Kind::Ablation | Kind::ReducedData | Kind::DataScale));
    if summarises_runs {
        return vec![];
    }
    dirs
}

/// The training run (`config.json` + `metrics.jsonl`) and the exported models of `dir`: their
/// sections, or the records that cannot be read with the reason; their files are `claimed`.
fn runs_and_exports(
    dir: &Path,
    files: &[PathBuf],
    names: &BTreeSet<&str>,
    claimed: &mut BTreeSet<PathBuf>,
    d: &mut Discovery,
) {
    match super::runs::training_run(dir, files, names) {
        Some(Ok(run)) => {
            claimed.extend(run.files.iter().cloned());
            d.sections.push(run);
        }
        Some(Err((path, reason))) => {
            // Its record is named with the reason; its other files are not listed again.
            claimed.extend(["config.json", "metrics.jsonl"].map(|n| dir.join(n)));
            d.skipped.push(skip(&path, reason));
        }
        None => {}
    }
    let mut unreadable = vec![];
    for export in super::runs::exports(dir, files, claimed, &mut unreadable) {
        d.sections.push(export);
    }
    d.skipped
        .extend(unreadable.into_iter().map(|(p, reason)| skip(&p, reason)));
}

/// The `<stem>.json` outputs of `dir`, one kind after another: their sections (their files
/// and images `claimed`), or the JSON that cannot be read with the reason.
fn named_outputs(
    dir: &Path,
    names: &BTreeSet<&str>,
    claimed: &mut BTreeSet<PathBuf>,
    d: &mut Discovery,
) {
    for kind in Kind::ALL {
        let Some(stem) = kind.stem() else { continue };
        let json = dir.join(format!("{stem}.json"));
        if names.contains(format!("{stem}.json").as_str()) {
            match read_json(&json).and_then(|v| found(kind, dir, &json, &v, names)) {
                Ok(f) => {
                    claimed.extend(f.files.iter().cloned());
                    claimed.extend(f.images.iter().map(|i| i.path.clone()));
                    d.sections.push(f);
                }
                Err(reason) => d.skipped.push(skip(&json, reason)),
            }
        }
    }
}

/// Files and subfolders of `dir` (sorted; hidden names left out).
fn list(dir: &Path) -> std::io::Result<(Vec<PathBuf>, Vec<PathBuf>)> {
    let mut files = vec![];
    let mut dirs = vec![];
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        let p = e.path();
        if file_name(&p).is_none_or(|n| n.starts_with('.')) {
            continue;
        }
        if e.file_type()?.is_dir() {
            dirs.push(p);
        } else {
            files.push(p);
        }
    }
    files.sort();
    dirs.sort();
    Ok((files, dirs))
}

fn skip(p: &Path, reason: String) -> Skipped {
    Skipped {
        path: p.to_path_buf(),
        reason,
    }
}

/// The document an output's JSON holds (`"document"`, written with it since issue 35), or
/// `None` for an output written before: its Markdown file is shown instead.
fn document(v: &Value) -> Option<Doc> {
    v.get(depthsense_metrics::doc::DOCUMENT_KEY)
        .and_then(|d| Doc::deserialize(d).ok())
}

/// The demo's summary file in `OUT/report/` (`depthsense demo`).
pub const DEMO_SUMMARY: &str = "summary.json";

/// The demo's report folder: its README (headline, stage times, commands, tables), the curves
/// and validation plot, and the picture row of every sample (one colour bar in metres each).
fn demo(dir: &Path, v: &Value, files: &[PathBuf], dirs: &[PathBuf]) -> Result<Found, String> {
    if v.get("summary").is_none() || v.get("plan").is_none() {
        return Err("not a demo summary (no `summary` / `plan`)".into());
    }
    let doc = match document(v) {
        Some(d) => d,
        None => Doc::from_markdown(
            std::fs::read_to_string(dir.join("README.md"))
                .map_err(|e| format!("README.md beside it: cannot read: {e}"))?,
        ),
    };
    let command_line = string_at(v, &["command_line"]);
    let models = demo_models(dir)?;
    Ok(Found {
        kind: Kind::Demo,
        dir: dir.to_path_buf(),
        files: files.to_vec(),
        inputs: inputs(v, command_line.as_deref()),
        command_line,
        doc,
        images: demo_images(dir, dirs),
        grid: None,
        models,
    })
}

/// The demo's two models on the test scenes (`tables.json` beside the summary), scored on
/// DEMO/prepared; none when there is no `tables.json`.
fn demo_models(dir: &Path) -> Result<Vec<ModelRow>, String> {
    let tables = dir.join("tables.json");
    if !tables.is_file() {
        return Ok(vec![]);
    }
    let t: TablesRecord = depthsense_records::read_json(&tables)
        .map_err(|e| format!("tables.json: {}", e.detail()))?;
    let data = dir
        .parent()
        .map(|p| p.join("prepared").display().to_string());
    Ok(super::runs::eval_models(dir, &t, data, "demo"))
}

/// The demo's pictures present: the validation plot and curves, then the picture row of every
/// sample under `samples/` (one colour bar in metres each).
fn demo_images(dir: &Path, dirs: &[PathBuf]) -> Vec<ImageSource> {
    let mut images = vec![];
    for name in ["val_rmse.png", "curves_rgb.png", "curves_fusion.png"] {
        let p = dir.join(name);
        if p.is_file() {
            images.push(ImageSource {
                caption: name.to_string(),
                path: p,
                tile: false,
            });
        }
    }
    for sample in dirs.iter().filter(|d| file_name(d) == Some("samples")) {
        let Ok((_, rows)) = list(sample) else {
            continue;
        };
        for r in rows {
            let p = r.join("row.png");
            if p.is_file() {
                images.push(ImageSource {
                    caption: format!(
                        "sample {}: image, radar, lidar GT, RGB only, fusion (m)",
                        file_name(&r).unwrap_or("?")
                    ),
                    path: p,
                    tile: false,
                });
            }
        }
    }
    images
}

/// JSON files of `dir` not claimed yet that hold a MER report (`mer report --json`).
fn probe_mer(dir: &Path, files: &[PathBuf], claimed: &mut BTreeSet<PathBuf>, d: &mut Discovery) {
    for f in files {
        let is_json = f.extension().is_some_and(|e| e == "json");
        let small = std::fs::metadata(f).is_ok_and(|m| m.len() <= MAX_PROBE_BYTES);
        if !is_json || !small || claimed.contains(f) {
            continue;
        }
        let Ok(v) = read_json(f) else { continue };
        let Some(r) = as_mer(&v) else { continue };
        let mut inputs = vec![("data".to_string(), r.data.display().to_string())];
        inputs.push(("split".into(), r.split.clone()));
        claimed.insert(f.clone());
        d.sections.push(Found {
            kind: Kind::Mer,
            dir: dir.to_path_buf(),
            files: vec![f.clone()],
            command_line: r.command_line.clone(),
            inputs,
            doc: report_doc(&r),
            images: vec![],
            grid: None,
            models: vec![],
        });
    }
}

/// A MER report (`rows` of `map` + `coverage`); numbers written as `null` (NaN: a map that
/// covers no GT pixel) read back as NaN.
fn as_mer(v: &Value) -> Option<MerReport> {
    let rows = v.get("rows")?.as_array()?;
    let first = rows.first()?;
    if first.get("map").is_none() || first.get("coverage").is_none() {
        return None;
    }
    let num = |r: &Value, k: &str| r.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let int = |r: &Value, k: &str| r.get(k).and_then(Value::as_u64).unwrap_or(0);
    let rows = rows
        .iter()
        .map(|r| CoverageRow {
            map: string_at(r, &["map"]).unwrap_or_default(),
            pixels_per_image: num(r, "pixels_per_image"),
            covered_gt_pixels: int(r, "covered_gt_pixels"),
            gt_pixels: int(r, "gt_pixels"),
            coverage: num(r, "coverage"),
            median_rel_error: num(r, "median_rel_error"),
            p90_rel_error: num(r, "p90_rel_error"),
        })
        .collect();
    Some(MerReport {
        data: string_at(v, &["data"]).unwrap_or_default().into(),
        split: string_at(v, &["split"]).unwrap_or_default(),
        images: v.get("images").and_then(Value::as_u64).unwrap_or(0) as usize,
        cap_m: num(v, "cap_m"),
        rows,
        command_line: string_at(v, &["command_line"]),
    })
}

/// The value of `--flag X` (or `--flag=X`) in a command line.
pub fn flag_value(cmd: &str, flag: &str) -> Option<String> {
    let mut words = cmd.split_whitespace();
    while let Some(w) = words.next() {
        if w == flag {
            return words.next().map(str::to_string);
        }
        if let Some(v) = w.strip_prefix(flag).and_then(|r| r.strip_prefix('=')) {
            return Some(v.to_string());
        }
    }
    None
}

/// Data, checkpoint, predictions and output folders: from the options (`options`, `eval`: the
/// evaluation options of failure / perturb, or the top level), else the command line.
fn inputs(v: &Value, cmd: Option<&str>) -> Vec<(String, String)> {
    let mut out = vec![];
    for key in ["data", "checkpoint", "predictions", "out"] {
        let val = string_at(v, &["options", key])
            .or_else(|| string_at(v, &["eval", key]))
            .or_else(|| string_at(v, &[key]))
            .or_else(|| cmd.and_then(|c| flag_value(c, &format!("--{key}"))));
        if let Some(x) = val {
            out.push((key.to_string(), x));
        }
    }
    out
}

/// The section of a `<stem>.json` output in `dir`.
fn found(
    kind: Kind,
    dir: &Path,
    json: &Path,
    v: &Value,
    names: &BTreeSet<&str>,
) -> Result<Found, String> {
    if !v.is_object() {
        return Err("not a JSON object".into());
    }
    let stem = kind.stem().unwrap_or_default();
    let command_line =
        string_at(v, &["options", "command_line"]).or_else(|| string_at(v, &["command_line"]));
    let mut f = Found {
        kind,
        dir: dir.to_path_buf(),
        files: vec![json.to_path_buf()],
        inputs: inputs(v, command_line.as_deref()),
        command_line,
        doc: Doc::new(),
        images: vec![],
        grid: None,
        models: vec![],
    };
    for ext in ["md", "csv"] {
        let name = format!("{stem}.{ext}");
        if names.contains(name.as_str()) {
            f.files.push(dir.join(name));
        }
    }
    f.doc = output_doc(dir, stem, v, names)?;
    f.models = output_models(kind, dir, json, v, &f.inputs)?;
    if kind == Kind::Explain {
        explain_images(&mut f, v, names);
    } else if names.contains(format!("{stem}.png").as_str()) {
        f.files.push(dir.join(format!("{stem}.png")));
        f.images.push(ImageSource {
            path: dir.join(format!("{stem}.png")),
            caption: format!("{stem}.png"),
            tile: false,
        });
    }
    Ok(f)
}

/// The document of a `<stem>.json` output: the one it holds, else its `<stem>.md` beside it,
/// else a paragraph saying there is none.
fn output_doc(dir: &Path, stem: &str, v: &Value, names: &BTreeSet<&str>) -> Result<Doc, String> {
    Ok(if let Some(doc) = document(v) {
        doc
    } else if names.contains(format!("{stem}.md").as_str()) {
        Doc::from_markdown(
            std::fs::read_to_string(dir.join(format!("{stem}.md")))
                .map_err(|e| format!("{stem}.md: cannot read: {e}"))?,
        )
    } else {
        let mut d = Doc::new();
        d.paragraph(format!("(no `{stem}.md` beside `{stem}.json`)"));
        d
    })
}

/// The comparison's rows of a `<stem>.json` output: an evaluation's tables (on the `data` of
/// its `inputs`) or an experiment's arms; none for the other kinds.
fn output_models(
    kind: Kind,
    dir: &Path,
    json: &Path,
    v: &Value,
    inputs: &[(String, String)],
) -> Result<Vec<ModelRow>, String> {
    Ok(match kind {
        Kind::Eval => {
            let data = inputs
                .iter()
                .find(|(k, _)| k == "data")
                .map(|(_, d)| d.clone());
            let t: TablesRecord =
                depthsense_records::checked(v.clone(), json, None).map_err(|e| e.detail())?;
            super::runs::eval_models(dir, &t, data, "eval")
        }
        Kind::Ablation | Kind::ReducedData | Kind::DataScale => {
            super::runs::experiment_models(kind, dir, v)
        }
        _ => vec![],
    })
}

/// Explain: a grid of its overlays (rows: sample × radar state; columns: distance × layer);
/// `grid.png` when the records name no overlay present.
fn explain_images(f: &mut Found, v: &Value, names: &BTreeSet<&str>) {
    let records = v.get("records").and_then(Value::as_array);
    let mut grid = FigureGrid::default();
    let mut more_rows = 0usize;
    for r in records.into_iter().flatten() {
        let Some(overlay) = string_at(r, &["overlay"]).filter(|o| names.contains(o.as_str()))
        else {
            continue;
        };
        let d = r
            .get("distance_m")
            .and_then(Value::as_f64)
            .unwrap_or(f64::NAN);
        let layer = string_at(r, &["layer"]).unwrap_or_default();
        let sample = string_at(r, &["sample"]).unwrap_or_default();
        let radar = r.get("radar").and_then(Value::as_bool).unwrap_or(true);
        let col = format!("{d} m · {layer}");
        let row = format!(
            "{} · {}",
            short(&sample),
            if radar { "radar" } else { "radar zeroed" }
        );
        f.files.push(f.dir.join(&overlay));
        let Some(ri) = row_index(&mut grid, row, &mut more_rows) else {
            continue;
        };
        let ci = index_of(&mut grid.columns, col);
        f.images.push(ImageSource {
            path: f.dir.join(&overlay),
            caption: overlay,
            tile: true,
        });
        let cells = &mut grid.rows[ri].1;
        cells.resize(cells.len().max(ci + 1), None);
        cells[ci] = Some(f.images.len() - 1);
    }
    if more_rows > 0 {
        f.doc.paragraph(format!(
            "The report's grid shows the first {MAX_GRID_ROWS} rows; {more_rows} more \
             overlays are in `{}`.",
            f.dir.display()
        ));
    }
    if !grid.rows.is_empty() {
        f.grid = Some(grid);
    } else if names.contains("grid.png") {
        f.images.push(ImageSource {
            path: f.dir.join("grid.png"),
            caption: "grid.png".into(),
            tile: false,
        });
    }
    if names.contains("grid.png") {
        f.files.push(f.dir.join("grid.png"));
    }
}

fn short(s: &str) -> String {
    match s.char_indices().nth(8) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

fn index_of(v: &mut Vec<String>, x: String) -> usize {
    match v.iter().position(|y| *y == x) {
        Some(i) => i,
        None => {
            v.push(x);
            v.len() - 1
        }
    }
}

/// Row of `label` in the grid, added when there is room (else counted in `more`).
fn row_index(g: &mut FigureGrid, label: String, more: &mut usize) -> Option<usize> {
    if let Some(i) = g.rows.iter().position(|(l, _)| *l == label) {
        return Some(i);
    }
    if g.rows.len() >= MAX_GRID_ROWS {
        *more += 1;
        return None;
    }
    g.rows.push((label, vec![]));
    Some(g.rows.len() - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flag_values_from_a_command_line() {
        let c = "depthsense eval --data runs/p --out=runs/e --checkpoint x.safetensors";
        assert_eq!(flag_value(c, "--data").as_deref(), Some("runs/p"));
        assert_eq!(flag_value(c, "--out").as_deref(), Some("runs/e"));
        assert_eq!(flag_value(c, "--predictions"), None);
        assert_eq!(short("ffb929e6fcfc7b05"), "ffb929e6…");
        assert_eq!(short("abc"), "abc");
    }
}
