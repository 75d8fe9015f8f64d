//! Errors with a place (issue 43 item 3): each crate's error names what went wrong in its own
//! terms, so no library builds a catch-all `…Error::Other(…)` outside its tests, and no error
//! enum declares a catch-all variant of a category and a free text (`Other(String)`,
//! `Data(String)`, `Config(String)`, …). The checker reads every `crates/*/src/**/*.rs` without
//! its `#[cfg(test)]` items and modules; a unit test shows it catches both.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `src` without its test-only items: every item after `#[cfg(test)]` (a module, a function,
/// a `use`) is blanked, lines kept so that line numbers still hold. The names of the modules
/// declared test-only in another file (`#[cfg(test)] mod tests;`) are returned.
fn without_tests(src: &str) -> (String, Vec<String>) {
    const MARK: &str = "#[cfg(test)]";
    let mut out = String::with_capacity(src.len());
    let mut test_mods = vec![];
    let mut rest = src;
    while let Some(at) = rest.find(MARK) {
        out.push_str(&rest[..at]);
        let item = &rest[at..];
        let end = item_end(item, MARK.len());
        let blanked = &item[..end];
        let head = blanked[MARK.len()..].trim();
        if let Some(name) = head
            .strip_prefix("mod ")
            .and_then(|m| m.strip_suffix(';'))
            .map(str::trim)
        {
            test_mods.push(name.to_string());
        }
        out.extend(blanked.chars().filter(|&c| c == '\n'));
        rest = &item[end..];
    }
    out.push_str(rest);
    (out, test_mods)
}

/// The byte offset just past the item that starts at `from` in `s`: its `;` when one comes
/// before any `{`, else the `}` that closes its first `{` (string and char literals skipped).
fn item_end(s: &str, from: usize) -> usize {
    let b = s.as_bytes();
    let (mut i, mut depth) = (from, 0usize);
    while i < b.len() {
        match b[i] {
            b'"' => {
                i += 1;
                while i < b.len() && b[i] != b'"' {
                    i += if b[i] == b'\\' { 2 } else { 1 };
                }
            }
            b'\'' if i + 2 < b.len() && b[i + 2] == b'\'' => i += 2,
            b'/' if b.get(i + 1) == Some(&b'/') => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            b';' if depth == 0 => return i + 1,
            b'{' => depth += 1,
            b'}' => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    return i + 1;
                }
            }
            _ => {}
        }
        i += 1;
    }
    b.len()
}

/// Each `…Error::Other(` built in `code` (comments skipped): (line, the line).
fn other_constructions(code: &str) -> Vec<(usize, String)> {
    code.lines()
        .enumerate()
        .filter_map(|(n, line)| {
            let code = line.split("//").next().unwrap_or("");
            let hit = code.match_indices("::Other(").any(|(at, _)| {
                let before = &code[..at];
                let name_start = before
                    .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
                    .map_or(0, |p| p + 1);
                before[name_start..].ends_with("Error")
            });
            hit.then(|| (n + 1, line.trim().to_string()))
        })
        .collect()
}

/// The catch-all variants an error enum may not declare: a category and a free text, where a
/// variant should say what went wrong with the values at fault (issue 43 removed each of them).
const CATCH_ALL_VARIANTS: [&str; 7] = [
    "Other(String)",
    "Data(String)",
    "Config(String)",
    "Options(String)",
    "Encode(String)",
    "Shard(String)",
    "InvalidConfig(String)",
];

/// A catch-all variant (`CATCH_ALL_VARIANTS`) declared in `code`: its line.
fn other_variant(code: &str) -> Option<usize> {
    code.lines()
        .position(|l| CATCH_ALL_VARIANTS.iter().any(|v| l.trim().starts_with(v)))
        .map(|n| n + 1)
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Every library and binary source file, and the files of the modules declared test-only.
fn sources() -> (Vec<PathBuf>, BTreeSet<PathBuf>) {
    let mut files = vec![];
    for krate in std::fs::read_dir(repo().join("crates")).unwrap().flatten() {
        rust_files(&krate.path().join("src"), &mut files);
    }
    files.sort();
    let mut test_only = BTreeSet::new();
    for f in &files {
        let (_, mods) = without_tests(&std::fs::read_to_string(f).unwrap());
        let dir = f.parent().unwrap();
        let stem_dir = f.with_extension("");
        for m in mods {
            for c in [
                dir.join(format!("{m}.rs")),
                dir.join(&m).join("mod.rs"),
                stem_dir.join(format!("{m}.rs")),
            ] {
                test_only.insert(c);
            }
        }
    }
    (files, test_only)
}

#[test]
fn no_catch_all_error_is_built_outside_tests() {
    let (files, test_only) = sources();
    assert!(files.len() > 100, "only {} source files found", files.len());
    let root = repo().canonicalize().unwrap();
    let mut found = vec![];
    for f in files.iter().filter(|f| !test_only.contains(*f)) {
        let (code, _) = without_tests(&std::fs::read_to_string(f).unwrap());
        let rel = f.canonicalize().unwrap();
        let rel = rel.strip_prefix(&root).unwrap().display().to_string();
        for (line, text) in other_constructions(&code) {
            found.push(format!("{rel}:{line}: {text}"));
        }
        if let Some(line) = other_variant(&code) {
            found.push(format!("{rel}:{line}: a catch-all String variant"));
        }
    }
    assert!(
        found.is_empty(),
        "a catch-all error outside tests: give each a variant that says what went wrong \
         (issue 43 item 3):\n{}",
        found.join("\n")
    );
}

/// The checker sees a construction, skips one in a test module, a test function or a comment,
/// and names test-only module files.
#[test]
fn the_checker_catches_a_catch_all() {
    let src = r#"
fn f() -> Result<(), PrepError> {
    Err(PrepError::Other(format!("x {}", 1)))
}
// Err(NetError::Other("in a comment".into()))
#[cfg(test)]
mod tests {
    fn g() { let _ = NetError::Other("killed".into()); let _ = '{'; }
}
#[cfg(test)]
fn h() { DataError::Other("test".into()); }
#[cfg(test)]
mod more;
fn k() -> DistError { DistError::Other("after".into()) }
fn not_an_error() { NotPrepared::Other; Kind::Other(1); }
"#;
    let (code, mods) = without_tests(src);
    assert_eq!(mods, ["more"]);
    assert_eq!(code.lines().count(), src.lines().count());
    let hits: Vec<usize> = other_constructions(&code).iter().map(|h| h.0).collect();
    assert_eq!(hits, [3, 14]);
    assert_eq!(
        other_variant("enum E {\n    A,\n    Other(String),\n}"),
        Some(3)
    );
    assert_eq!(
        other_variant("enum E {\n    Config(#[from] ConfigError),\n    Data(String),\n}"),
        Some(3)
    );
    assert_eq!(other_variant("enum E {\n    Plot(String),\n}"), None);
    assert_eq!(other_variant("enum NotPrepared {\n    Other,\n}"), None);
}
