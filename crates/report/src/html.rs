//! The page: report.html (self-contained) and report.md (images by relative path).

use super::images::base64;
use super::markdown::{escape, to_html};
use super::{Kind, ReportSummary, Section};

/// The Files line of a section names at most this many (report.json has them all).
const MAX_FILES_SHOWN: usize = 8;

const CSS: &str = "\
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0 auto;\
max-width:1240px;padding:1em 2em 4em;color:#1d2329;background:#fff;line-height:1.45}\
h1{border-bottom:3px solid #2a6f97;padding-bottom:.2em}\
h2{border-bottom:1px solid #ccd;margin-top:2.2em;padding-bottom:.15em}\
section{margin-bottom:2.5em}\
code,pre{font-family:ui-monospace,'DejaVu Sans Mono',Menlo,monospace;font-size:.88em}\
code{background:#f1f3f5;padding:0 .25em;border-radius:3px}\
pre{background:#f6f8fa;border:1px solid #dde;padding:.6em .8em;white-space:pre-wrap;\
word-break:break-all;border-radius:4px}\
pre code{background:none;padding:0}\
.scroll{overflow-x:auto}\
table{border-collapse:collapse;margin:.8em 0;font-size:.86em}\
th,td{border:1px solid #ccd3da;padding:.22em .55em;vertical-align:top}\
thead th{background:#e8eef3}\
tbody tr:nth-child(even){background:#f8fafb}\
.r{text-align:right;font-variant-numeric:tabular-nums}.c{text-align:center}.l{text-align:left}\
dl.meta{display:grid;grid-template-columns:max-content 1fr;gap:.25em 1em;\
background:#f4f7f9;border-left:4px solid #2a6f97;padding:.6em 1em;margin:1em 0}\
dl.meta dt{font-weight:600}dl.meta dd{margin:0;min-width:0}dl.meta pre{margin:0}\
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #dde}\
figcaption{font-size:.85em;color:#555}\
table.grid td,table.grid th{padding:2px;font-size:.78em;background:#fff}\
table.grid img{display:block;width:100%;height:auto}\
nav ol{columns:2;column-gap:2em}nav li{margin:.15em 0}\
.top{font-size:.85em}.files code{margin-right:.4em;display:inline-block}";

/// The whole HTML page.
pub fn page(s: &ReportSummary) -> String {
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>{t}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<h1 id=\"top\">{t}</h1>\n",
        t = escape(&s.title)
    );
    h.push_str(&intro_html(s));
    h.push_str(&contents_html(s));
    for (i, sec) in s.sections.iter().enumerate() {
        h.push_str(&section_html(i, sec));
    }
    h.push_str(&skipped_html(s));
    h.push_str("</body>\n</html>\n");
    h
}

fn intro_html(s: &ReportSummary) -> String {
    let runs: Vec<String> = s
        .runs
        .iter()
        .map(|r| format!("<code>{}</code>", escape(&r.display().to_string())))
        .collect();
    let mut h = format!(
        "<p>{} experiment outputs found under {}; {} files skipped. Self-contained: every image \
         is embedded, nothing is loaded from elsewhere.</p>\n",
        s.sections.len(),
        runs.join(", "),
        s.skipped.len()
    );
    if let Some(c) = &s.command_line {
        h.push_str(&format!("<p>Made by:</p>\n<pre>{}</pre>\n", escape(c)));
    }
    h
}

fn contents_html(s: &ReportSummary) -> String {
    let mut h = String::from("<nav id=\"contents\">\n<h2>Contents</h2>\n<ol>\n");
    for (i, sec) in s.sections.iter().enumerate() {
        let dir = match sec.kind {
            Kind::Models => String::new(),
            _ => format!(
                " <code>{}</code>",
                escape(&sec.source_dir.display().to_string())
            ),
        };
        h.push_str(&format!(
            "<li><a href=\"#{}\">{}</a>{dir}</li>\n",
            sec.anchor,
            escape(&section_title(i, sec))
        ));
    }
    h.push_str(&format!(
        "<li><a href=\"#skipped\">Skipped files ({})</a></li>\n</ol>\n</nav>\n",
        s.skipped.len()
    ));
    h
}

fn section_title(i: usize, sec: &Section) -> String {
    format!("{}. {}", i + 1, sec.title)
}

fn section_html(i: usize, sec: &Section) -> String {
    let mut h = format!(
        "<section id=\"{}\">\n<h2>{}</h2>\n",
        sec.anchor,
        escape(&section_title(i, sec))
    );
    // The comparison is built from the other sections: no folder, files or command of its own.
    if sec.kind != Kind::Models {
        h.push_str(&meta_html(sec));
    }
    h.push_str("<div class=\"scroll\">\n");
    h.push_str(&to_html(&sec.markdown, 2));
    h.push_str("</div>\n");
    match &sec.grid {
        Some(g) => h.push_str(&grid_html(sec, g)),
        None => {
            for (k, info) in sec.images.iter().enumerate() {
                h.push_str(&format!(
                    "<figure>{}<figcaption>{} ({}x{}, shown at {}x{})</figcaption></figure>\n",
                    img_tag(sec, k),
                    escape(&info.caption),
                    info.original_size.0,
                    info.original_size.1,
                    info.embedded_size.0,
                    info.embedded_size.1
                ));
            }
        }
    }
    h.push_str("<p class=\"top\"><a href=\"#contents\">↑ contents</a></p>\n</section>\n");
    h
}

fn img_tag(sec: &Section, k: usize) -> String {
    let (Some(info), Some(e)) = (sec.images.get(k), sec.embedded.get(k)) else {
        return String::new();
    };
    format!(
        "<img src=\"data:image/png;base64,{}\" width=\"{}\" height=\"{}\" alt=\"{}\">",
        base64(&e.png),
        e.width,
        e.height,
        escape(&info.caption)
    )
}

fn meta_html(sec: &Section) -> String {
    let mut h = String::from("<dl class=\"meta\">\n");
    let dir = sec.source_dir.display().to_string();
    h.push_str(&format!(
        "<dt>Source</dt><dd><code>{}</code> (written by <code>{}</code>)</dd>\n",
        escape(&dir),
        escape(sec.kind.writer())
    ));
    let cmd = match &sec.command_line {
        Some(c) => format!("<pre>{}</pre>", escape(c)),
        None => "not recorded in its JSON".to_string(),
    };
    h.push_str(&format!("<dt>Command</dt><dd>{cmd}</dd>\n"));
    for (k, v) in &sec.inputs {
        h.push_str(&format!(
            "<dt>{}</dt><dd><code>{}</code></dd>\n",
            escape(k),
            escape(v)
        ));
    }
    let files = file_list(sec, |f| format!("<code>{}</code>", escape(f)));
    h.push_str(&format!(
        "<dt>Files</dt><dd class=\"files\">{}</dd>\n</dl>\n",
        files.join(" ")
    ));
    h
}

/// The first [`MAX_FILES_SHOWN`] files of a section (relative to its folder), formatted.
fn file_list(sec: &Section, fmt: impl Fn(&str) -> String) -> Vec<String> {
    let mut v: Vec<String> = sec
        .files
        .iter()
        .take(MAX_FILES_SHOWN)
        .map(|f| fmt(&relative(f, &sec.source_dir)))
        .collect();
    if sec.files.len() > MAX_FILES_SHOWN {
        v.push(format!(
            "and {} more (listed in report.json)",
            sec.files.len() - MAX_FILES_SHOWN
        ));
    }
    v
}

fn relative(f: &std::path::Path, dir: &std::path::Path) -> String {
    f.strip_prefix(dir).unwrap_or(f).display().to_string()
}

fn grid_html(sec: &Section, g: &super::FigureGrid) -> String {
    let mut h = String::from("<div class=\"scroll\">\n<table class=\"grid\">\n<tr><th></th>");
    for c in &g.columns {
        h.push_str(&format!("<th>{}</th>", escape(c)));
    }
    h.push_str("</tr>\n");
    for (label, cells) in &g.rows {
        h.push_str(&format!("<tr><th>{}</th>", escape(label)));
        for k in 0..g.columns.len() {
            let img = cells.get(k).copied().flatten().map(|i| img_tag(sec, i));
            h.push_str(&format!("<td>{}</td>", img.unwrap_or_default()));
        }
        h.push_str("</tr>\n");
    }
    h.push_str("</table>\n</div>\n");
    h.push_str(&format!(
        "<p class=\"top\">Overlays named by <code>explain.json</code>, each downscaled to at most \
         {} px wide (rows: sample · radar state; columns: distance · layer); <code>grid.png</code> \
         holds the same tiles at full size.</p>\n",
        sec.embedded.iter().map(|e| e.width).max().unwrap_or(0)
    ));
    h
}

fn skipped_html(s: &ReportSummary) -> String {
    let mut h = format!(
        "<section id=\"skipped\">\n<h2>Skipped files ({})</h2>\n",
        s.skipped.len()
    );
    if s.skipped.is_empty() {
        h.push_str("<p>None.</p>\n");
    } else {
        h.push_str("<div class=\"scroll\">\n<table>\n<thead><tr><th>file</th><th>reason</th></tr></thead>\n<tbody>\n");
        for k in &s.skipped {
            h.push_str(&format!(
                "<tr><td><code>{}</code></td><td>{}</td></tr>\n",
                escape(&k.path.display().to_string()),
                escape(&k.reason)
            ));
        }
        h.push_str("</tbody>\n</table>\n</div>\n");
    }
    h.push_str("<p class=\"top\"><a href=\"#contents\">↑ contents</a></p>\n</section>\n");
    h
}

/// report.md: the same content; images referenced by their copies under img/.
pub fn markdown_page(s: &ReportSummary) -> String {
    let mut m = format!("# {}\n\n", s.title);
    if let Some(c) = &s.command_line {
        m.push_str(&format!("Made by:\n\n```\n{c}\n```\n\n"));
    }
    m.push_str("## Contents\n\n");
    for (i, sec) in s.sections.iter().enumerate() {
        let dir = match sec.kind {
            Kind::Models => String::new(),
            _ => format!(" `{}`", sec.source_dir.display()),
        };
        m.push_str(&format!(
            "{}. [{}](#{}){dir}\n",
            i + 1,
            sec.title,
            sec.anchor
        ));
    }
    m.push_str(&format!(
        "{}. [Skipped files](#skipped)\n\n",
        s.sections.len() + 1
    ));
    for (i, sec) in s.sections.iter().enumerate() {
        m.push_str(&section_markdown(i, sec));
    }
    m.push_str(&format!(
        "<a id=\"skipped\"></a>\n\n## Skipped files ({})\n\n",
        s.skipped.len()
    ));
    if !s.skipped.is_empty() {
        m.push_str("| file | reason |\n|---|---|\n");
        for k in &s.skipped {
            m.push_str(&format!(
                "| `{}` | {} |\n",
                k.path.display(),
                k.reason.replace('|', "\\|")
            ));
        }
    }
    m
}

fn section_markdown(i: usize, sec: &Section) -> String {
    if sec.kind == Kind::Models {
        return format!(
            "<a id=\"{}\"></a>\n\n## {}\n\n{}\n",
            sec.anchor,
            section_title(i, sec),
            shift_headings(&sec.markdown, 2)
        );
    }
    let mut m = format!(
        "<a id=\"{}\"></a>\n\n## {}\n\n- Source: `{}` (written by `{}`)\n",
        sec.anchor,
        section_title(i, sec),
        sec.source_dir.display(),
        sec.kind.writer()
    );
    for (k, v) in &sec.inputs {
        m.push_str(&format!("- {k}: `{v}`\n"));
    }
    let files = file_list(sec, |f| format!("`{f}`"));
    m.push_str(&format!("- Files: {}\n", files.join(", ")));
    match &sec.command_line {
        Some(c) => m.push_str(&format!("- Command:\n\n```\n{c}\n```\n\n")),
        None => m.push_str("- Command: not recorded in its JSON\n\n"),
    }
    m.push_str(&shift_headings(&sec.markdown, 2));
    m.push('\n');
    match &sec.grid {
        Some(g) => m.push_str(&grid_markdown(sec, g)),
        None => {
            for info in &sec.images {
                m.push_str(&format!("![{}]({})\n\n", info.caption, info.copy.display()));
            }
        }
    }
    m
}

/// `#` headings (outside code fences) moved down `by` levels.
fn shift_headings(md: &str, by: usize) -> String {
    let mut fence = false;
    let mut out = String::new();
    for l in md.lines() {
        if l.trim_start().starts_with("```") {
            fence = !fence;
        }
        if !fence && l.starts_with('#') {
            out.push_str(&"#".repeat(by));
        }
        out.push_str(l);
        out.push('\n');
    }
    out
}

fn grid_markdown(sec: &Section, g: &super::FigureGrid) -> String {
    let mut m = String::from("| |");
    for c in &g.columns {
        m.push_str(&format!(" {c} |"));
    }
    m.push_str(&format!("\n|---|{}\n", "---|".repeat(g.columns.len())));
    for (label, cells) in &g.rows {
        m.push_str(&format!("| {label} |"));
        for k in 0..g.columns.len() {
            let cell = cells
                .get(k)
                .copied()
                .flatten()
                .and_then(|i| sec.images.get(i))
                .map(|info| format!("![{}]({})", info.caption, info.copy.display()));
            m.push_str(&format!(" {} |", cell.unwrap_or_default()));
        }
        m.push('\n');
    }
    m.push('\n');
    m
}
