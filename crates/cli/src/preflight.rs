//! What every command refuses before it reads or computes anything (docs/guide/reliability.md,
//! "Refused before any work"): an output path it could not create ([`check_outputs`]) and
//! flag combinations that need more than clap can say ([`check_combinations`]). Both binaries
//! run it right after parsing, so a mistake costs no time and leaves nothing behind.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

use clap::ArgMatches;

/// The ids of the flags that name something a command writes (a folder or a file).
const OUTPUT_FLAGS: [&str; 5] = ["out", "json", "preview_dir", "contact_sheet", "work"];

/// The leaf subcommand's name and matches (`mer train` → `train`'s).
fn leaf(m: &ArgMatches) -> (Vec<&str>, &ArgMatches) {
    let mut names = vec![];
    let mut cur = m;
    while let Some((name, sub)) = cur.subcommand() {
        names.push(name);
        cur = sub;
    }
    (names, cur)
}

/// Every check, on the parsed command line.
pub fn check(m: &ArgMatches) -> anyhow::Result<()> {
    let (names, leaf) = leaf(m);
    check_combinations(&names, leaf)?;
    check_outputs(leaf)
}

/// Each output flag given (or defaulted) names a place where this process can create files:
/// the folder itself when it exists, else the nearest folder above it that exists. Tried by
/// creating and removing an empty folder there, so that even root finds out that /proc or a
/// read-only mount refuses.
pub fn check_outputs(leaf: &ArgMatches) -> anyhow::Result<()> {
    for id in OUTPUT_FLAGS {
        let Ok(Some(values)) = leaf.try_get_raw(id) else {
            continue;
        };
        for v in values {
            check_output(&flag_name(id), Path::new(v))?;
        }
    }
    Ok(())
}

/// `--preview-dir` for the id `preview_dir`.
fn flag_name(id: &str) -> String {
    format!("--{}", id.replace('_', "-"))
}

/// One output path: refused in one sentence naming the flag, the cause and the next step.
pub fn check_output(flag: &str, path: &Path) -> anyhow::Result<()> {
    let place = writable_place(path);
    let probe = place.join(format!(".depthsense-write-check-{}", std::process::id()));
    match std::fs::create_dir(&probe) {
        Ok(()) => {
            let _ = std::fs::remove_dir(&probe);
            Ok(())
        }
        Err(e) => anyhow::bail!(
            "{flag} {}: cannot create files in {} ({}); choose a folder you can write to",
            path.display(),
            place.display(),
            io_cause(&e)
        ),
    }
}

/// The folder in which `path`'s first missing component would be created (or `path` itself
/// when it is a folder).
fn writable_place(path: &Path) -> PathBuf {
    let mut p = if path.as_os_str().is_empty() {
        Path::new(".").to_path_buf()
    } else {
        path.to_path_buf()
    };
    if p.is_dir() {
        return p;
    }
    loop {
        match p.parent() {
            Some(parent) if parent.as_os_str().is_empty() => return PathBuf::from("."),
            Some(parent) if parent.is_dir() => return parent.to_path_buf(),
            Some(parent) => p = parent.to_path_buf(),
            None => return p,
        }
    }
}

/// An I/O error's cause without Rust's "(os error N)".
fn io_cause(e: &std::io::Error) -> String {
    let text = e.to_string();
    match text.find(" (os error") {
        Some(i) => text[..i].to_string(),
        None => text,
    }
}

/// Combinations clap's own words cannot explain well.
pub fn check_combinations(names: &[&str], leaf: &ArgMatches) -> anyhow::Result<()> {
    let given = |id: &str| {
        leaf.try_get_raw(id)
            .ok()
            .flatten()
            .is_some_and(|mut v| v.next().is_some_and(|x: &OsStr| !x.is_empty()))
            && leaf.value_source(id) == Some(clap::parser::ValueSource::CommandLine)
    };
    if names.first() == Some(&"predict") && given("image") && !given("calibration") {
        anyhow::bail!(
            "--image needs --calibration FILE.json (the camera intrinsics and every radar \
             file's transform into the camera); write one for a nuScenes sample with \
             `depthsense calibration --dataroot DATAROOT --version VERSION --token SAMPLE_TOKEN \
             --out FILE.json` \
             (docs/guide/deploy.md, \"Raw files\")"
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_under_proc_is_refused_naming_the_flag() {
        let e = check_output("--out", Path::new("/proc/x/y"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--out /proc/x/y: cannot create files in /proc ("),
            "{e}"
        );
        assert!(e.ends_with("choose a folder you can write to"), "{e}");
        assert!(!e.contains("os error"), "{e}");
    }

    #[test]
    fn a_writable_output_passes_and_leaves_nothing() {
        let d = tempfile::tempdir().unwrap();
        check_output("--out", &d.path().join("a/b/c")).unwrap();
        check_output("--out", d.path()).unwrap();
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 0);
        assert_eq!(writable_place(&d.path().join("a/b")), d.path());
    }
}
