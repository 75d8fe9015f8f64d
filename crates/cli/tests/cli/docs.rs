//! Docs that stay true (README "Documentation"): every `depthsense …` command in README.md and
//! docs/guide/*.md parses with the real command line; every number in a results table of
//! RESULTS.md and README.md equals its source JSON; every relative link in every Markdown file
//! resolves; docs/guide/cli.md is what `depthsense help-markdown` prints. Each checker is also
//! shown to catch a broken doc (a renamed flag, an edited number, a broken link).

use std::path::{Path, PathBuf};

use clap::{CommandFactory, Parser};
use depthsense_cli::Cli;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

// ---------------------------------------------------------------------------------------------
// Commands

/// A `depthsense …` command found in a Markdown file.
#[derive(Debug)]
struct DocCommand {
    line: usize,
    /// The words after `depthsense`.
    args: Vec<String>,
    /// From a fenced code block (parsed in full) or an inline code span (subcommand and flags).
    fenced: bool,
}

/// Shell-like words: whitespace-separated, '…' and "…" quoting.
fn words(s: &str) -> Vec<String> {
    let (mut out, mut cur, mut quote, mut any) = (vec![], String::new(), None, false);
    for c in s.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => cur.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                any = true;
            }
            (None, c) if c.is_whitespace() => {
                if any || !cur.is_empty() {
                    out.push(std::mem::take(&mut cur));
                }
                any = false;
            }
            (None, c) => cur.push(c),
        }
    }
    if any || !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// The words after the program when `w` runs depthsense (`depthsense`, `depthsense-net`,
/// `target/release/depthsense`, …, after `$ `, `VAR=value` and `time`).
fn depthsense_args(w: &[String]) -> Option<Vec<String>> {
    let mut i = 0;
    while i < w.len() && (w[i] == "$" || w[i] == "time" || is_assignment(&w[i])) {
        i += 1;
    }
    let prog = w.get(i)?;
    let name = prog.rsplit('/').next().unwrap_or(prog);
    // The command ends at a shell redirection or the next command (`> log 2>&1`, `| tee`,
    // `&&`, `;`).
    let end = w[i + 1..]
        .iter()
        .position(|x| {
            matches!(
                x.as_str(),
                ">" | ">>" | "2>" | "2>&1" | "|" | "&&" | "||" | ";" | "&"
            )
        })
        .map_or(w.len(), |p| i + 1 + p);
    (name == "depthsense" || name == "depthsense-net").then(|| w[i + 1..end].to_vec())
}

fn is_assignment(w: &str) -> bool {
    w.split_once('=').is_some_and(|(k, _)| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_uppercase() || c == '_' || c.is_ascii_digit())
    })
}

/// Strips a shell comment (` # …`) outside quotes.
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    let mut prev_space = true;
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (None, '\'' | '"') => quote = Some(c),
            (None, '#') if prev_space => return &line[..i],
            _ => {}
        }
        prev_space = c.is_whitespace();
    }
    line
}

fn commands_in(md: &str) -> Vec<DocCommand> {
    let mut out = vec![];
    let mut fence: Option<String> = None;
    let mut pending: Option<(usize, String)> = None;
    for (n, raw) in md.lines().enumerate() {
        let line_no = n + 1;
        let t = raw.trim_start();
        if let Some(f) = &fence {
            if t.starts_with(f.as_str()) {
                fence = None;
                pending = None;
                continue;
            }
            let code = strip_comment(raw).trim_end();
            let (start, mut text) = pending.take().unwrap_or((line_no, String::new()));
            match code.strip_suffix('\\') {
                Some(head) => {
                    text.push_str(head);
                    text.push(' ');
                    pending = Some((start, text));
                }
                None => {
                    text.push_str(code);
                    if let Some(args) = depthsense_args(&words(&text)) {
                        out.push(DocCommand {
                            line: start,
                            args,
                            fenced: true,
                        });
                    }
                }
            }
            continue;
        }
        if t.starts_with("```") || t.starts_with("~~~") {
            fence = Some(t.chars().take_while(|c| *c == '`' || *c == '~').collect());
            continue;
        }
        // inline code spans
        let mut rest = raw;
        while let Some(a) = rest.find('`') {
            let after = &rest[a + 1..];
            let Some(b) = after.find('`') else { break };
            if let Some(args) = depthsense_args(&words(&after[..b])) {
                out.push(DocCommand {
                    line: line_no,
                    args,
                    fenced: false,
                });
            }
            rest = &after[b + 1..];
        }
    }
    out
}

/// The subcommand path of `args` in `root`, and the command it ends at; `|`-alternatives
/// (`bench data|synth`) must all be subcommands. Errors name the word at fault.
fn subcommand_of<'a>(
    root: &'a clap::Command,
    args: &[String],
) -> Result<(&'a clap::Command, usize), String> {
    let mut cmd = root;
    let mut i = 0;
    while let Some(w) = args.get(i) {
        if w.starts_with('-') || !cmd.has_subcommands() {
            break;
        }
        if w.contains('|') {
            for alt in w.split('|') {
                if cmd.find_subcommand(alt).is_none() {
                    return Err(format!("no subcommand `{alt}` of `{}`", cmd.get_name()));
                }
            }
            return Ok((cmd, i + 1));
        }
        match cmd.find_subcommand(w) {
            Some(sub) => cmd = sub,
            None => return Err(format!("no subcommand `{w}` of `{}`", cmd.get_name())),
        }
        i += 1;
    }
    if cmd.has_subcommands() && !args.iter().any(|a| a == "--help" || a == "-h") {
        let names: Vec<&str> = cmd.get_subcommands().map(|s| s.get_name()).collect();
        // `depthsense bench` alone in prose names the family; a fenced command must be complete
        return Err(format!(
            "`{}` needs a subcommand ({})",
            cmd.get_name(),
            names.join(", ")
        ));
    }
    Ok((cmd, i))
}

/// Whether `flag` (`--name`, `--name=v`, `-x`) is an argument of `cmd`.
fn has_flag(cmd: &clap::Command, flag: &str) -> bool {
    let f = flag.split('=').next().unwrap_or(flag);
    if matches!(f, "--help" | "-h" | "--version" | "-V") {
        return true;
    }
    cmd.get_arguments().any(|a| {
        if let Some(long) = f.strip_prefix("--") {
            a.get_long() == Some(long) || a.get_all_aliases().is_some_and(|al| al.contains(&long))
        } else if let Some(short) = f.strip_prefix('-') {
            short.len() == 1 && a.get_short() == short.chars().next()
        } else {
            false
        }
    })
}

/// Problems of one command against the real command line.
fn check_command(root: &clap::Command, c: &DocCommand) -> Result<(), String> {
    if c.args.is_empty() {
        return Ok(());
    }
    // A synopsis (`[--opt]`, `…`, `<value>`) is checked like an inline span: flags only.
    let synopsis = c.args.iter().any(|a| {
        a.starts_with('[')
            || a.starts_with('<')
            || a.contains('…')
            || a == "..."
            || a.ends_with("...")
    });
    if c.fenced && !synopsis {
        let argv = std::iter::once("depthsense".to_string()).chain(c.args.iter().cloned());
        return match Cli::try_parse_from(argv) {
            Ok(_) => Ok(()),
            Err(e) => match e.kind() {
                clap::error::ErrorKind::DisplayHelp
                | clap::error::ErrorKind::DisplayVersion
                | clap::error::ErrorKind::MissingRequiredArgument => Ok(()),
                _ => Err(e
                    .render()
                    .to_string()
                    .lines()
                    .next()
                    .unwrap_or("")
                    .to_string()),
            },
        };
    }
    // An inline span: the subcommand exists and every flag is one of its flags.
    if c.args.len() == 1 && c.args[0].starts_with('-') && has_flag(root, &c.args[0]) {
        return Ok(());
    }
    let (cmd, start) = subcommand_of(root, &c.args).or_else(|e| {
        // `depthsense bench` / `depthsense mer` naming a family in prose
        if c.args.len() == 1 && root.find_subcommand(&c.args[0]).is_some() {
            Ok((root, 1))
        } else {
            Err(e)
        }
    })?;
    for w in &c.args[start..] {
        let w = w.trim_matches(|ch| matches!(ch, '[' | ']' | '(' | ')' | ',' | '.' | ';'));
        for alt in w.split('|') {
            if alt.starts_with('-')
                && alt.len() > 1
                && !alt.starts_with("---")
                && !has_flag(cmd, alt)
            {
                return Err(format!("`{}` has no flag `{alt}`", cmd.get_name()));
            }
        }
    }
    Ok(())
}

/// Every command of `md` checked; the problems as `file:line: …`.
fn command_problems(name: &str, md: &str) -> Vec<String> {
    let root = Cli::command();
    commands_in(md)
        .iter()
        .filter_map(|c| {
            check_command(&root, c)
                .err()
                .map(|e| format!("{name}:{}: depthsense {}: {e}", c.line, c.args.join(" ")))
        })
        .collect()
}

fn guide_files() -> Vec<PathBuf> {
    let mut v = vec![repo().join("README.md")];
    let dir = repo().join("docs/guide");
    let mut guides: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    guides.retain(|p| p.extension().is_some_and(|e| e == "md"));
    guides.sort();
    v.extend(guides);
    v
}

#[test]
fn every_documented_command_parses() {
    let mut problems = vec![];
    let mut n = 0;
    for f in guide_files() {
        let md = std::fs::read_to_string(&f).unwrap();
        n += commands_in(&md).len();
        let name = f.strip_prefix(repo()).unwrap_or(&f).display().to_string();
        problems.extend(command_problems(&name, &md));
    }
    assert!(n > 50, "only {n} depthsense commands found in the docs");
    assert!(
        problems.is_empty(),
        "{} stale command(s):\n{}",
        problems.len(),
        problems.join("\n")
    );
}

#[test]
fn the_command_check_catches_a_renamed_flag() {
    let good = "```sh\ndepthsense eval --data runs/d --predictions p --allow-missing\n```\n\
                Then `depthsense export --format onnx|torchscript --out m.onnx`.\n";
    assert!(
        command_problems("good.md", good).is_empty(),
        "{:?}",
        command_problems("good.md", good)
    );
    // a flag renamed in a fenced block, in an inline span; an unknown subcommand
    for bad in [
        "```sh\ndepthsense eval --data runs/d --predictions p --allow-missings\n```\n",
        "```bash\ndepthsense train --data d \\\n  --epochz 3\n```\n",
        "Use `depthsense export --formats onnx`.\n",
        "Use `depthsense evaluate --data d`.\n",
        "```sh\ndepthsense bench modle --config tiny\n```\n",
        "```sh\ndepthsense report --runs DIR... --out R [--titel T]\n```\n",
    ] {
        let p = command_problems("bad.md", bad);
        assert_eq!(p.len(), 1, "{bad}: {p:?}");
        assert!(p[0].starts_with("bad.md:"), "{p:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// Results: numbers in Markdown tables against their source JSON

/// A table cell that is a number: `12.3`, `−0.4 %`, `1,134 s`, `0.92 M`, `**9.95**`, `3 ± 0.1`.
fn cell_numbers(cell: &str) -> Option<Vec<(f64, usize)>> {
    let c = cell
        .replace(['*', '`'], "")
        .replace('−', "-")
        .replace(',', "");
    let c = c.trim();
    if c.is_empty() {
        return None;
    }
    let mut nums = vec![];
    for (i, part) in c.split('±').enumerate() {
        let part = part.trim();
        let num: String = part
            .chars()
            .take_while(|ch| ch.is_ascii_digit() || *ch == '.' || (*ch == '-' || *ch == '+'))
            .collect();
        let unit = part[num.len()..].trim();
        let units = [
            "", "%", "m", "ms", "s", "MB", "GB", "M", "k", "×", "x", "min", "h",
        ];
        if num.is_empty() || !units.contains(&unit) || (i == 0 && c.split('±').count() > 2) {
            return None;
        }
        let value: f64 = num.parse().ok()?;
        let decimals = num.split_once('.').map_or(0, |(_, d)| d.len());
        nums.push((value, decimals));
    }
    Some(nums)
}

fn json_numbers(v: &serde_json::Value, out: &mut Vec<f64>) {
    match v {
        serde_json::Value::Number(n) => out.extend(n.as_f64()),
        serde_json::Value::Array(a) => a.iter().for_each(|x| json_numbers(x, out)),
        serde_json::Value::Object(m) => m.values().for_each(|x| json_numbers(x, out)),
        _ => {}
    }
}

/// Whether `value` (printed with `decimals`) is one of `source`'s numbers, directly or as a
/// percentage, in thousands, thousandths or millions.
fn printed_from(value: f64, decimals: usize, source: &[f64]) -> bool {
    let half_ulp = 0.5 * 10f64.powi(-(decimals as i32)) + 1e-9;
    source.iter().any(|&n| {
        [1.0, 100.0, 1e3, 1e-3, 1e-6]
            .iter()
            .any(|s| (n * s - value).abs() <= half_ulp)
    })
}

/// Every numeric cell of every table in `md` against the JSON its section names
/// (`Source: [docs/results/x.json](…)`); a table with numbers and no source is a problem too.
fn result_problems(name: &str, md: &str, root: &Path) -> Vec<String> {
    let mut problems = vec![];
    let mut source: Option<(PathBuf, Vec<f64>)> = None;
    let mut row = 0usize;
    for (n, line) in md.lines().enumerate() {
        let t = line.trim();
        if t.starts_with('#') {
            source = None;
        }
        if let Some(rest) = t.strip_prefix("Source:") {
            let Some(path) = rest.split('(').nth(1).and_then(|s| s.split(')').next()) else {
                problems.push(format!("{name}:{}: a Source line without a link", n + 1));
                continue;
            };
            let p = root.join(path);
            match std::fs::read(&p).map(|b| serde_json::from_slice::<serde_json::Value>(&b)) {
                Ok(Ok(v)) => {
                    let mut nums = vec![];
                    json_numbers(&v, &mut nums);
                    source = Some((p, nums));
                }
                _ => problems.push(format!("{name}:{}: {path}: no such JSON", n + 1)),
            }
            continue;
        }
        if !t.starts_with('|') {
            row = 0;
            continue;
        }
        row += 1;
        if row <= 2 {
            continue; // header and separator
        }
        for cell in t.trim_matches('|').split('|') {
            let Some(nums) = cell_numbers(cell) else {
                continue;
            };
            let Some((p, src)) = &source else {
                problems.push(format!(
                    "{name}:{}: a number ({}) with no Source JSON",
                    n + 1,
                    cell.trim()
                ));
                break;
            };
            for (v, d) in nums {
                if !printed_from(v, d, src) {
                    problems.push(format!(
                        "{name}:{}: {} is not in {}",
                        n + 1,
                        cell.trim(),
                        p.strip_prefix(root).unwrap_or(p).display()
                    ));
                }
            }
        }
    }
    problems
}

#[test]
fn every_result_number_comes_from_its_json() {
    let mut problems = vec![];
    for f in ["RESULTS.md", "README.md"] {
        let path = repo().join(f);
        let md = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{f}: {e}"));
        problems.extend(result_problems(f, &md, &repo()));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_result_check_catches_an_edited_number() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("docs/results")).unwrap();
    std::fs::write(
        dir.path().join("docs/results/demo.json"),
        r#"{"rgb": {"rmse": 10.4031, "abs_rel": 0.1234}, "images": 96, "delta1": 0.8812}"#,
    )
    .unwrap();
    let table = |rmse: &str| {
        format!(
            "## Demo\n\nSource: [docs/results/demo.json](docs/results/demo.json)\n\n\
             | model | images | RMSE (m) | AbsRel | δ1 |\n|---|---|---|---|---|\n\
             | RGB | 96 | {rmse} | 0.123 | 88.1 % |\n"
        )
    };
    assert!(result_problems("ok.md", &table("10.40"), dir.path()).is_empty());
    assert!(result_problems("ok.md", &table("**10.403 m**"), dir.path()).is_empty());
    let p = result_problems("bad.md", &table("10.45"), dir.path());
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(
        p[0].contains("10.45") && p[0].contains("demo.json"),
        "{p:?}"
    );
    // a table with numbers and no source
    let p = result_problems("bad.md", "| a | b |\n|---|---|\n| x | 3.5 |\n", dir.path());
    assert_eq!(p.len(), 1, "{p:?}");
}

// ---------------------------------------------------------------------------------------------
// Links

/// Every relative link target of `md` (Markdown links and images, `#anchors` dropped).
fn link_targets(md: &str) -> Vec<(usize, String)> {
    let mut out = vec![];
    let mut fenced = false;
    for (n, line) in md.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // inline code spans are examples, not links
        let text: String = line
            .split('`')
            .enumerate()
            .filter(|(i, _)| i % 2 == 0)
            .map(|(_, t)| t)
            .collect::<Vec<_>>()
            .join(" ");
        let mut rest = text.as_str();
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            let end = after.find(')').unwrap_or(after.len());
            let target = after[..end]
                .split_whitespace()
                .next()
                .unwrap_or("")
                .to_string();
            rest = &after[end..];
            let external = target.contains("://") || target.starts_with("mailto:");
            let path = target.split('#').next().unwrap_or("").to_string();
            if !external && !path.is_empty() {
                out.push((n + 1, path));
            }
        }
    }
    out
}

fn link_problems(file: &Path, md: &str) -> Vec<String> {
    let dir = file.parent().unwrap_or(Path::new("."));
    link_targets(md)
        .into_iter()
        .filter(|(_, t)| !dir.join(t).exists())
        .map(|(n, t)| format!("{}:{n}: {t} does not exist", file.display()))
        .collect()
}

fn markdown_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        let name = e.file_name().to_string_lossy().into_owned();
        if p.is_dir() {
            if !name.starts_with('.') && !matches!(name.as_str(), "target" | "runs" | "data") {
                markdown_files(&p, out);
            }
        } else if name.ends_with(".md") {
            out.push(p);
        }
    }
}

#[test]
fn every_relative_link_resolves() {
    let mut files = vec![];
    markdown_files(&repo(), &mut files);
    assert!(files.len() >= 5, "{files:?}");
    let mut problems = vec![];
    for f in &files {
        problems.extend(link_problems(f, &std::fs::read_to_string(f).unwrap()));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_link_check_catches_a_broken_link() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("docs/guide")).unwrap();
    std::fs::write(dir.path().join("RESULTS.md"), "").unwrap();
    let f = dir.path().join("docs/guide/x.md");
    let ok = "See [results](../../RESULTS.md#demo), [web](https://example.org) and [here](#top).\n";
    assert!(link_problems(&f, ok).is_empty());
    let p = link_problems(
        &f,
        "See [results](../RESULTS.md).\n```\n[not a link](nowhere)\n```\n",
    );
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(p[0].contains("../RESULTS.md"), "{p:?}");
}

// ---------------------------------------------------------------------------------------------
// The generated reference

#[test]
fn the_cli_reference_is_up_to_date() {
    let path = repo().join("docs/guide/cli.md");
    let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
    let generated = depthsense_cli::cmd::help_markdown::reference(&Cli::command());
    assert!(
        on_disk == generated,
        "docs/guide/cli.md is stale: run `target/debug/depthsense help-markdown > docs/guide/cli.md`"
    );
}

// ---------------------------------------------------------------------------------------------
// ARCHITECTURE.md's layer table and its rule ("a crate depends only on crates of lower layers;
// inside a crate no two modules import each other in a circle")

/// (crate directory, layer) of every row of ARCHITECTURE.md's layer table.
fn layer_table(md: &str) -> Vec<(String, u32)> {
    md.lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            let layer = cells.get(1)?.parse().ok()?;
            let name = cells.get(2)?.strip_prefix('`')?.strip_suffix('`')?;
            Some((name.to_string(), layer))
        })
        .collect()
}

/// The `depthsense-*` crates of a Cargo.toml's `[dependencies]`, `[dev-dependencies]` and
/// `[build-dependencies]` (without the prefix), each with whether it is a normal dependency.
/// A normal dependency is on a lower layer; a test's or build script's on a lower layer or the
/// same one (a crate of the same layer never depends on it): one on a higher layer would build
/// the crate's tests against the crates built on it, a circle.
fn deps(toml: &str) -> Vec<(String, bool)> {
    let mut section: Option<bool> = None;
    let mut out = vec![];
    for l in toml.lines() {
        let l = l.trim();
        if l.starts_with('[') {
            section = match l {
                "[dependencies]" => Some(true),
                "[dev-dependencies]" | "[build-dependencies]" => Some(false),
                _ => None,
            };
        } else if let Some(normal) = section {
            if let Some(rest) = l.strip_prefix("depthsense-") {
                let name: String = rest
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '-')
                    .collect();
                out.push((name, normal));
            }
        }
    }
    out
}

fn layer_problems(table: &[(String, u32)], root: &Path) -> Vec<String> {
    let layer = |n: &str| table.iter().find(|(c, _)| c == n).map(|(_, l)| *l);
    let mut out = vec![];
    for e in std::fs::read_dir(root.join("crates")).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Ok(toml) = std::fs::read_to_string(e.path().join("Cargo.toml")) else {
            continue;
        };
        let Some(own) = layer(&name) else {
            out.push(format!(
                "crates/{name} is not in ARCHITECTURE.md's layer table"
            ));
            continue;
        };
        for (dep, normal) in deps(&toml) {
            match layer(&dep) {
                Some(l) if l < own || (!normal && l == own) => {}
                l => out.push(format!(
                    "{name} (layer {own}) {} {dep} (layer {l:?}): not a lower layer",
                    if normal {
                        "depends on"
                    } else {
                        "dev-depends on"
                    }
                )),
            }
        }
    }
    out
}

/// The top-level modules of a crate's `src` and the ones each refers to through `crate::`
/// (items re-exported by lib.rs count as their module; comments and `mod tests` ignored).
fn module_graph(
    src: &Path,
) -> std::collections::BTreeMap<String, std::collections::BTreeSet<String>> {
    fn files(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                files(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let code = |p: &Path| {
        let s = std::fs::read_to_string(p).unwrap_or_default();
        let s = s
            .split("#[cfg(test)]\nmod tests")
            .next()
            .unwrap_or("")
            .to_string();
        s.lines()
            .filter(|l| !l.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    // lib.rs `pub use module::{Item, …};` / `pub use module::Item;`
    let mut alias = std::collections::BTreeMap::new();
    for stmt in code(&src.join("lib.rs")).split(';') {
        if let Some(rest) = stmt.trim().strip_prefix("pub use ") {
            if let Some((module, items)) = rest.split_once("::") {
                for it in items.trim_matches(|c| c == '{' || c == '}').split(',') {
                    let it = it.split(" as ").last().unwrap_or("").trim();
                    alias.insert(it.to_string(), module.to_string());
                }
            }
        }
    }
    let mut all = vec![];
    files(src, &mut all);
    let mut graph: std::collections::BTreeMap<String, std::collections::BTreeSet<String>> =
        Default::default();
    for f in &all {
        let rel = f.strip_prefix(src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        if matches!(top.as_str(), "lib" | "main" | "bin") {
            continue;
        }
        let text = code(f);
        // In a top-level module (src/x.rs, src/x/mod.rs) `super::` is the crate root.
        let depth = rel.components().count();
        let top_level = depth == 1 || (depth == 2 && rel.ends_with("mod.rs"));
        let text = if top_level {
            text.replace("super::", "crate::")
        } else {
            text
        };
        let mut refs = std::collections::BTreeSet::new();
        for part in text.split("crate::").skip(1) {
            let names: Vec<String> = if let Some(body) = part.strip_prefix('{') {
                body.split('}')
                    .next()
                    .unwrap_or("")
                    .split(',')
                    .map(|x| x.trim().split("::").next().unwrap_or("").to_string())
                    .collect()
            } else {
                vec![part
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect()]
            };
            for n in names {
                refs.insert(alias.get(&n).cloned().unwrap_or(n));
            }
        }
        graph
            .entry(top.clone())
            .or_default()
            .extend(refs.into_iter().filter(|r| *r != top));
    }
    let names: std::collections::BTreeSet<String> = graph.keys().cloned().collect();
    for refs in graph.values_mut() {
        refs.retain(|r| names.contains(r));
    }
    graph
}

/// One circle of the graph, if any (`a → b → a`).
fn a_circle(
    g: &std::collections::BTreeMap<String, std::collections::BTreeSet<String>>,
) -> Option<Vec<String>> {
    fn visit(
        u: &str,
        g: &std::collections::BTreeMap<String, std::collections::BTreeSet<String>>,
        state: &mut std::collections::BTreeMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(u.to_string(), 1);
        path.push(u.to_string());
        for v in g.get(u).into_iter().flatten() {
            match state.get(v) {
                Some(1) => {
                    let at = path.iter().position(|p| p == v).unwrap_or(0);
                    let mut c = path[at..].to_vec();
                    c.push(v.clone());
                    return Some(c);
                }
                Some(_) => {}
                None => {
                    if let Some(c) = visit(v, g, state, path) {
                        return Some(c);
                    }
                }
            }
        }
        path.pop();
        state.insert(u.to_string(), 2);
        None
    }
    let mut state: std::collections::BTreeMap<String, u8> = Default::default();
    g.keys().find_map(|k| {
        if state.contains_key(k) {
            None
        } else {
            visit(k, g, &mut state, &mut vec![])
        }
    })
}

#[test]
fn the_layer_table_holds_and_no_crate_has_an_import_circle() {
    let root = repo();
    let table = layer_table(&std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap());
    assert!(table.len() >= 20, "{table:?}");
    let problems = layer_problems(&table, &root);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    for (name, _) in &table {
        let g = module_graph(&root.join("crates").join(name).join("src"));
        if let Some(c) = a_circle(&g) {
            panic!(
                "crates/{name}: modules import each other in a circle: {}",
                c.join(" → ")
            );
        }
    }
}

#[test]
fn the_layer_checks_catch_an_upward_dependency_and_a_circle() {
    let table = vec![("a".to_string(), 1), ("b".to_string(), 2)];
    let dir = tempfile::tempdir().unwrap();
    for (name, deps) in [("a", "depthsense-b.workspace = true"), ("b", "")] {
        let c = dir.path().join("crates").join(name);
        std::fs::create_dir_all(c.join("src")).unwrap();
        std::fs::write(c.join("Cargo.toml"), format!("[dependencies]\n{deps}\n")).unwrap();
    }
    let p = layer_problems(&table, dir.path());
    assert_eq!(
        p,
        ["a (layer 1) depends on b (layer Some(2)): not a lower layer"]
    );
    let src = dir.path().join("crates/a/src");
    std::fs::write(src.join("lib.rs"), "mod x;\nmod y;\npub use y::Thing;\n").unwrap();
    std::fs::write(src.join("x.rs"), "use crate::Thing;\n").unwrap();
    std::fs::write(
        src.join("y.rs"),
        "// crate::z is a comment\nuse crate::{x::f, w};\n",
    )
    .unwrap();
    let g = module_graph(&src);
    assert_eq!(a_circle(&g).unwrap(), ["x", "y", "x"]);
    std::fs::write(src.join("y.rs"), "pub struct Thing;\n").unwrap();
    assert!(a_circle(&module_graph(&src)).is_none());
    // `super::` from a top-level module is the crate root: a circle as well.
    std::fs::write(src.join("y.rs"), "use super::x::f;\npub struct Thing;\n").unwrap();
    assert_eq!(a_circle(&module_graph(&src)).unwrap(), ["x", "y", "x"]);
    // A dev-dependency on a higher layer is refused like a normal one.
    std::fs::write(
        dir.path().join("crates/a/Cargo.toml"),
        "[dependencies]\n[dev-dependencies]\ndepthsense-b.workspace = true\n",
    )
    .unwrap();
    assert_eq!(layer_problems(&table, dir.path()).len(), 1);
}
