//! The Markdown subset the experiment writers produce, rendered to HTML: ATX headings, pipe
//! tables (with `---:` / `:---:` alignment), `- ` lists, fenced code, paragraphs; inline
//! `code`, **bold** and *italic*. Everything else is text, HTML-escaped (links stay text, so
//! the page links nowhere).

/// `&`, `<`, `>`, `"` and `'` as entities.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            _ => o.push(c),
        }
    }
    o
}

/// Render `md`; headings move down `shift` levels (a writer's `#` becomes `h{1+shift}`).
pub fn to_html(md: &str, shift: usize) -> String {
    let lines: Vec<&str> = md.lines().collect();
    let mut out = String::new();
    let mut para: Vec<&str> = vec![];
    let mut i = 0;
    while i < lines.len() {
        let l = lines[i];
        let t = l.trim();
        let block = t.is_empty()
            || t.starts_with("```")
            || heading(t).is_some()
            || is_table_start(&lines, i)
            || list_item(l).is_some();
        if !block {
            para.push(t);
            i += 1;
            continue;
        }
        flush_paragraph(&mut para, &mut out);
        i = if t.is_empty() {
            i + 1
        } else if t.starts_with("```") {
            code_block(&lines, i, &mut out)
        } else if let Some((level, text)) = heading(t) {
            let h = (level + shift).min(6);
            out.push_str(&format!("<h{h}>{}</h{h}>\n", inline(text)));
            i + 1
        } else if is_table_start(&lines, i) {
            table(&lines, i, &mut out)
        } else {
            list(&lines, i, &mut out)
        };
    }
    flush_paragraph(&mut para, &mut out);
    out
}

fn flush_paragraph(para: &mut Vec<&str>, out: &mut String) {
    if !para.is_empty() {
        out.push_str(&format!("<p>{}</p>\n", inline(&para.join(" "))));
        para.clear();
    }
}

fn heading(t: &str) -> Option<(usize, &str)> {
    let level = t.chars().take_while(|&c| c == '#').count();
    let rest = &t[level..];
    ((1..=6).contains(&level) && rest.starts_with(' ')).then(|| (level, rest.trim()))
}

fn list_item(l: &str) -> Option<&str> {
    let t = l.trim_start();
    (l.len() - t.len() < 2)
        .then(|| t.strip_prefix("- ").or_else(|| t.strip_prefix("* ")))
        .flatten()
}

fn code_block(lines: &[&str], start: usize, out: &mut String) -> usize {
    let mut i = start + 1;
    out.push_str("<pre><code>");
    while i < lines.len() && !lines[i].trim().starts_with("```") {
        out.push_str(&escape(lines[i]));
        out.push('\n');
        i += 1;
    }
    out.push_str("</code></pre>\n");
    i + 1
}

fn list(lines: &[&str], start: usize, out: &mut String) -> usize {
    let mut items: Vec<String> = vec![];
    let mut i = start;
    while i < lines.len() {
        let l = lines[i];
        if let Some(item) = list_item(l) {
            items.push(item.trim().to_string());
        } else if !l.trim().is_empty() && l.starts_with("  ") && !items.is_empty() {
            let last = items.len() - 1;
            items[last] = format!("{} {}", items[last], l.trim());
        } else {
            break;
        }
        i += 1;
    }
    out.push_str("<ul>\n");
    for it in items {
        out.push_str(&format!("<li>{}</li>\n", inline(&it)));
    }
    out.push_str("</ul>\n");
    i
}

/// Cells of a pipe-table row: outer pipes dropped, `\|` kept as `|`, pipes inside `code`
/// spans kept.
pub fn split_row(line: &str) -> Vec<String> {
    let t = line.trim();
    let t = t.strip_prefix('|').unwrap_or(t);
    let t = t
        .strip_suffix('|')
        .filter(|_| !t.ends_with("\\|"))
        .unwrap_or(t);
    let mut cells = vec![];
    let mut cur = String::new();
    let mut in_code = false;
    let mut chars = t.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\\' if chars.peek() == Some(&'|') => {
                cur.push('|');
                chars.next();
            }
            '`' => {
                in_code = !in_code;
                cur.push(c);
            }
            '|' if !in_code => cells.push(std::mem::take(&mut cur).trim().to_string()),
            _ => cur.push(c),
        }
    }
    cells.push(cur.trim().to_string());
    cells
}

/// Alignment class of a separator cell (`---:` → "r", `:---:` → "c", `:---` → "l").
fn alignment(cell: &str) -> Option<&'static str> {
    let c = cell.trim();
    if c.is_empty() || !c.chars().all(|ch| ch == '-' || ch == ':') || !c.contains('-') {
        return None;
    }
    match (c.starts_with(':'), c.ends_with(':')) {
        (true, true) => Some("c"),
        (false, true) => Some("r"),
        (true, false) => Some("l"),
        (false, false) => Some(""),
    }
}

fn is_table_start(lines: &[&str], i: usize) -> bool {
    let (Some(head), Some(sep)) = (lines.get(i), lines.get(i + 1)) else {
        return false;
    };
    head.trim().starts_with('|')
        && sep.trim().starts_with('|')
        && split_row(sep).iter().all(|c| alignment(c).is_some())
}

fn table(lines: &[&str], start: usize, out: &mut String) -> usize {
    let aligns: Vec<&str> = split_row(lines[start + 1])
        .iter()
        .map(|c| alignment(c).unwrap_or(""))
        .collect();
    out.push_str("<table>\n<thead>");
    row_html(&split_row(lines[start]), &aligns, "th", out);
    out.push_str("</thead>\n<tbody>\n");
    let mut i = start + 2;
    while i < lines.len() && lines[i].trim().starts_with('|') {
        row_html(&split_row(lines[i]), &aligns, "td", out);
        out.push('\n');
        i += 1;
    }
    out.push_str("</tbody>\n</table>\n");
    i
}

fn row_html(cells: &[String], aligns: &[&str], tag: &str, out: &mut String) {
    out.push_str("<tr>");
    for (k, c) in cells.iter().enumerate() {
        match aligns.get(k).copied().unwrap_or("") {
            "" => out.push_str(&format!("<{tag}>")),
            a => out.push_str(&format!("<{tag} class=\"{a}\">")),
        }
        out.push_str(&inline(c));
        out.push_str(&format!("</{tag}>"));
    }
    out.push_str("</tr>");
}

/// Inline markup of one line: `code` spans (unmatched backticks stay text), then **bold**
/// and *italic* in the text between them; everything escaped.
pub fn inline(s: &str) -> String {
    let parts: Vec<&str> = s.split('`').collect();
    let mut out = String::new();
    for (k, p) in parts.iter().enumerate() {
        let closed = k + 1 < parts.len();
        if k % 2 == 1 && closed {
            out.push_str(&format!("<code>{}</code>", escape(p)));
        } else {
            if k % 2 == 1 {
                out.push('`');
            }
            out.push_str(&emphasis(&escape(p)));
        }
    }
    out
}

/// `**x**` → strong, then `*x*` → em (a marker must touch a non-space character).
fn emphasis(s: &str) -> String {
    let s = pairs(s, "**", "strong");
    pairs(&s, "*", "em")
}

fn pairs(s: &str, marker: &str, tag: &str) -> String {
    let mut out = String::new();
    let mut rest = s;
    while let Some(a) = rest.find(marker) {
        let after = &rest[a + marker.len()..];
        let close = after
            .find(marker)
            .filter(|&b| b > 0 && !after.starts_with(' ') && !after[..b].ends_with(' '));
        let Some(b) = close else {
            out.push_str(&rest[..a + marker.len()]);
            rest = after;
            continue;
        };
        out.push_str(&rest[..a]);
        out.push_str(&format!("<{tag}>{}</{tag}>", &after[..b]));
        rest = &after[b + marker.len()..];
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inline_code_bold_italic_and_escaping() {
        assert_eq!(
            inline("a `x<y` **b** *c* 2 * 3 <i>"),
            "a <code>x&lt;y</code> <strong>b</strong> <em>c</em> 2 * 3 &lt;i&gt;"
        );
        assert_eq!(inline("odd ` tick"), "odd ` tick");
        assert_eq!(
            split_row("| a | `b|c` | d\\|e |"),
            vec!["a", "`b|c`", "d|e"]
        );
    }

    #[test]
    fn headings_lists_and_code() {
        let h = to_html(
            "# T\n\n- one\n  more\n- two\n\n```\n<x>\n```\ntext\nnext",
            1,
        );
        assert_eq!(
            h,
            "<h2>T</h2>\n<ul>\n<li>one more</li>\n<li>two</li>\n</ul>\n\
             <pre><code>&lt;x&gt;\n</code></pre>\n<p>text next</p>\n"
        );
    }
}
