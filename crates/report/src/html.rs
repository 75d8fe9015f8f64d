//! The page: report.html (self-contained; a maud template, which escapes every text where it is
//! placed) and report.md (images by relative path).

use maud::{html, Markup, PreEscaped, DOCTYPE};

use super::images::base64;
use depthsense_metrics::doc::{Block, Doc};
use depthsense_metrics::table::{Align, MdTable};

use super::markdown::{inline, to_html};
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

/// The whole HTML page, from a maud template: every text is escaped where it is placed; only
/// the CSS above, the sections' Markdown rendered by [`to_html`] (which escapes its text) and
/// the base64 images go in unescaped.
pub fn page(s: &ReportSummary) -> String {
    let nl = "\n";
    html! {
        (DOCTYPE) (nl)
        html lang="en" {
            (nl) head {
                (nl) meta charset="utf-8"; (nl)
                meta name="viewport" content="width=device-width, initial-scale=1"; (nl)
                title { (s.title) } (nl)
                style { (PreEscaped(CSS)) } (nl)
            } (nl)
            body {
                (nl) h1 id="top" { (s.title) } (nl)
                (intro(s))
                (contents(s))
                @for (i, sec) in s.sections.iter().enumerate() {
                    (section(i, sec))
                }
                (skipped(s))
            } (nl)
        } (nl)
    }
    .into_string()
}

fn intro(s: &ReportSummary) -> Markup {
    html! {
        p {
            (s.sections.len()) " experiment outputs found under "
            @for (k, r) in s.runs.iter().enumerate() {
                @if k > 0 { ", " }
                code { (r.display()) }
            }
            "; " (s.skipped.len()) " files skipped. Self-contained: every image is embedded, \
             nothing is loaded from elsewhere."
        } "\n"
        @if let Some(c) = &s.command_line {
            p { "Made by:" } "\n" pre { (c) } "\n"
        }
    }
}

fn contents(s: &ReportSummary) -> Markup {
    html! {
        nav id="contents" {
            "\n" h2 { "Contents" } "\n"
            ol {
                "\n"
                @for (i, sec) in s.sections.iter().enumerate() {
                    li {
                        a href={ "#" (sec.anchor) } { (section_title(i, sec)) }
                        // The comparison is built from the other sections: no folder of its own.
                        @if sec.kind != Kind::Models {
                            " " code { (sec.source_dir.display()) }
                        }
                    } "\n"
                }
                li { a href="#skipped" { "Skipped files (" (s.skipped.len()) ")" } } "\n"
            } "\n"
        } "\n"
    }
}

/// A section's document as HTML, its headings moved down `shift` levels: the blocks built from
/// the JSON through this template (text escaped, inline `code` / **bold** / *italic* marked up),
/// a writer's Markdown through [`to_html`].
pub fn doc_html(doc: &Doc, shift: u8) -> Markup {
    html! {
        @for b in &doc.blocks {
            @match b {
                Block::Heading { level, text } => (heading(level.saturating_add(shift), text)),
                Block::Paragraph { text } => { p { (PreEscaped(inline(text))) } "\n" }
                Block::Table { table } => (table_html(table)),
                Block::List { items } => {
                    ul { "\n" @for it in items { li { (PreEscaped(inline(it))) } "\n" } } "\n"
                }
                Block::Code { text } => { pre { code { (PreEscaped(code_text(text))) } } "\n" }
                Block::Markdown { text } => (PreEscaped(to_html(text, usize::from(shift)))),
            }
        }
    }
}

/// A code block's text as markdown.rs writes it: escaped, every line ending in a newline.
fn code_text(text: &str) -> String {
    let mut out = super::markdown::escape(text);
    if !out.ends_with('\n') {
        out.push('\n');
    }
    out
}

fn heading(level: u8, text: &str) -> Markup {
    let t = PreEscaped(inline(text));
    let h = match level {
        0 | 1 => html! { h1 { (t) } },
        2 => html! { h2 { (t) } },
        3 => html! { h3 { (t) } },
        4 => html! { h4 { (t) } },
        5 => html! { h5 { (t) } },
        _ => html! { h6 { (t) } },
    };
    html! { (h) "\n" }
}

/// The alignment class markdown.rs gives a column (`---:` → "r"; `---` → none).
fn align_class(a: Align) -> Option<&'static str> {
    match a {
        Align::Left => None,
        Align::Right => Some("r"),
    }
}

fn table_html(t: &MdTable) -> Markup {
    html! {
        table {
            "\n"
            thead { tr { @for (title, a) in &t.columns { th class=[align_class(*a)] { (PreEscaped(inline(title))) } } } }
            "\n"
            tbody {
                "\n"
                @for row in &t.rows {
                    tr {
                        @for (k, c) in row.iter().enumerate() {
                            td class=[t.columns.get(k).and_then(|(_, a)| align_class(*a))] { (PreEscaped(inline(c))) }
                        }
                    }
                    "\n"
                }
            }
            "\n"
        }
        "\n"
    }
}

fn section_title(i: usize, sec: &Section) -> String {
    format!("{}. {}", i + 1, sec.title)
}

fn section(i: usize, sec: &Section) -> Markup {
    html! {
        section id=(sec.anchor) {
            "\n" h2 { (section_title(i, sec)) } "\n"
            // The comparison is built from the other sections: no folder, files or command.
            @if sec.kind != Kind::Models { (meta(sec)) }
            div class="scroll" { "\n" (doc_html(&sec.doc, 2)) } "\n"
            @match &sec.grid {
                Some(g) => (grid(sec, g)),
                None => {
                    @for (k, info) in sec.images.iter().enumerate() {
                        figure {
                            (img(sec, k))
                            figcaption {
                                (info.caption) " (" (info.original_size.0) "x"
                                (info.original_size.1) ", shown at " (info.embedded_size.0) "x"
                                (info.embedded_size.1) ")"
                            }
                        } "\n"
                    }
                }
            }
            (to_contents())
        } "\n"
    }
}

fn to_contents() -> Markup {
    html! { p class="top" { a href="#contents" { "↑ contents" } } "\n" }
}

fn img(sec: &Section, k: usize) -> Markup {
    let (Some(info), Some(e)) = (sec.images.get(k), sec.embedded.get(k)) else {
        return html! {};
    };
    html! {
        img src={ "data:image/png;base64," (PreEscaped(base64(&e.png))) } width=(e.width)
            height=(e.height) alt=(info.caption);
    }
}

fn meta(sec: &Section) -> Markup {
    html! {
        dl class="meta" {
            "\n"
            dt { "Source" }
            dd { code { (sec.source_dir.display()) } " (written by " code { (sec.kind.writer()) } ")" }
            "\n"
            dt { "Command" }
            dd {
                @match &sec.command_line {
                    Some(c) => pre { (c) },
                    None => (not_recorded(sec.kind)),
                }
            }
            "\n"
            @for (k, v) in &sec.inputs {
                dt { (k) } dd { code { (v) } } "\n"
            }
            dt { "Files" }
            dd class="files" {
                @for (n, f) in shown_files(sec).iter().enumerate() {
                    @if n > 0 { " " }
                    code { (f) }
                }
                @if let Some(more) = more_files(sec) { " " (more) }
            }
            "\n"
        } "\n"
    }
}

/// What the Command line says of an output that does not record its invocation.
fn not_recorded(kind: Kind) -> &'static str {
    match kind {
        Kind::Train => "not recorded in its config.json (written before runs recorded it)",
        _ => "not recorded in its JSON",
    }
}

/// The first [`MAX_FILES_SHOWN`] files of a section, relative to its folder.
fn shown_files(sec: &Section) -> Vec<String> {
    sec.files
        .iter()
        .take(MAX_FILES_SHOWN)
        .map(|f| relative(f, &sec.source_dir))
        .collect()
}

/// "and N more (listed in report.json)" when the files are more than [`MAX_FILES_SHOWN`].
fn more_files(sec: &Section) -> Option<String> {
    (sec.files.len() > MAX_FILES_SHOWN).then(|| {
        format!(
            "and {} more (listed in report.json)",
            sec.files.len() - MAX_FILES_SHOWN
        )
    })
}

/// The first [`MAX_FILES_SHOWN`] files of a section (relative to its folder), formatted, and
/// the count of the others.
fn file_list(sec: &Section, fmt: impl Fn(&str) -> String) -> Vec<String> {
    let mut v: Vec<String> = shown_files(sec).iter().map(|f| fmt(f)).collect();
    v.extend(more_files(sec));
    v
}

fn relative(f: &std::path::Path, dir: &std::path::Path) -> String {
    f.strip_prefix(dir).unwrap_or(f).display().to_string()
}

fn grid(sec: &Section, g: &super::FigureGrid) -> Markup {
    let widest = sec.embedded.iter().map(|e| e.width).max().unwrap_or(0);
    html! {
        div class="scroll" {
            "\n"
            table class="grid" {
                "\n"
                tr { th {} @for c in &g.columns { th { (c) } } } "\n"
                @for (label, cells) in &g.rows {
                    tr {
                        th { (label) }
                        @for k in 0..g.columns.len() {
                            td {
                                @if let Some(i) = cells.get(k).copied().flatten() { (img(sec, i)) }
                            }
                        }
                    } "\n"
                }
            } "\n"
        } "\n"
        p class="top" {
            "Overlays named by " code { "explain.json" } ", each downscaled to at most "
            (widest) " px wide (rows: sample · radar state; columns: distance · layer); "
            code { "grid.png" } " holds the same tiles at full size."
        } "\n"
    }
}

fn skipped(s: &ReportSummary) -> Markup {
    html! {
        section id="skipped" {
            "\n" h2 { "Skipped files (" (s.skipped.len()) ")" } "\n"
            @if s.skipped.is_empty() {
                p { "None." } "\n"
            } @else {
                div class="scroll" {
                    "\n"
                    table {
                        "\n" thead { tr { th { "file" } th { "reason" } } } "\n"
                        tbody {
                            "\n"
                            @for k in &s.skipped {
                                tr { td { code { (k.path.display()) } } td { (k.reason) } } "\n"
                            }
                        } "\n"
                    } "\n"
                } "\n"
            }
            (to_contents())
        } "\n"
    }
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
            shift_headings(&sec.doc.to_markdown(), 2)
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
        None => m.push_str(&format!("- Command: {}\n\n", not_recorded(sec.kind))),
    }
    m.push_str(&shift_headings(&sec.doc.to_markdown(), 2));
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A document built from data renders as its Markdown rendered by markdown.rs did: the page
    /// looks the same whichever way a section came.
    #[test]
    fn a_document_renders_as_its_markdown_did() {
        let mut t = MdTable::new(&[("model", Align::Left), ("RMSE (m)", Align::Right)]);
        t.row(&["`rgb` <b>", "8.385"])
            .row(&["fusion **best**", "–"]);
        let mut d = Doc::new();
        d.heading(1, "Run <x>")
            .paragraph("`tiny` & *it*, 4 epochs 'quoted'.")
            .table(t)
            .list(["one `a<b`", "two"])
            .code("let x = a < b && 'c';")
            .heading(3, "Next");
        assert_eq!(doc_html(&d, 2).into_string(), to_html(&d.to_markdown(), 2));
        let md = Doc::from_markdown("# T\n\ntext");
        assert_eq!(doc_html(&md, 1).into_string(), to_html("# T\n\ntext", 1));
    }
}
