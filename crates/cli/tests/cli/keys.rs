//! One set of presets and `--set` keys, the same everywhere: every preset and key named anywhere
//! in the documentation is in the registry (`depthsense-config`) and is accepted by every command
//! that takes `--config`/`--configs`/`--set`; every such flag is built from the registry (its
//! help lists the presets; every `--set` points to the one list of keys, `model-info --keys`,
//! which the binary prints from the registry); and every preset builds a network in
//! `model-info`, through the real binary.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

use clap::error::ErrorKind;
use clap::{CommandFactory, Parser};
use depthsense_cli::Cli;
use depthsense_config::{options, presets};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn markdown_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
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

/// Every word following `flag` (`--set radar-skip=8`, `--config=tiny`), up to the next blank,
/// backtick or quote.
fn values_after(text: &str, flag: &str) -> Vec<String> {
    let mut out = vec![];
    for (i, _) in text.match_indices(flag) {
        let rest = &text[i + flag.len()..];
        let Some(rest) = rest.strip_prefix(' ').or_else(|| rest.strip_prefix('=')) else {
            continue;
        };
        let word: String = rest
            .chars()
            .take_while(|c| !c.is_whitespace() && !"`'\"|)".contains(*c))
            .collect();
        if !word.is_empty() && !word.starts_with('<') && !word.starts_with('-') {
            out.push(word);
        }
    }
    out
}

/// The words of a list of presets in prose, e.g. "every preset (`paper`, `released`, `tiny`,
/// `tiny-wide`)": a run of two or more backticked words joined by `, ` / ` or ` / ` and ` on a
/// line that speaks of presets, one of them a registry preset (so that the others must be too).
/// Lines about the PDA network's own presets (`mer train --config`) are another vocabulary.
fn preset_list_in(line: &str) -> Vec<String> {
    let lower = line.to_ascii_lowercase();
    if !lower.contains("preset") || lower.contains("pda") || lower.contains("mer train") {
        return vec![];
    }
    let mut runs: Vec<Vec<String>> = vec![];
    let mut current: Vec<String> = vec![];
    let mut rest = line;
    while let Some(i) = rest.find('`') {
        let Some(j) = rest[i + 1..].find('`') else {
            break;
        };
        let word = &rest[i + 1..i + 1 + j];
        let gap = &rest[..i];
        let joined =
            current.is_empty() || matches!(gap, ", " | " or " | " and " | ", or " | ", and ");
        if !joined {
            runs.push(std::mem::take(&mut current));
        }
        if word.chars().all(|c| c.is_ascii_lowercase() || c == '-') && !word.starts_with('-') {
            current.push(word.to_string());
        } else {
            runs.push(std::mem::take(&mut current));
        }
        rest = &rest[i + 1 + j + 1..];
    }
    runs.push(current);
    runs.into_iter()
        .filter(|r| r.len() >= 2 && r.iter().any(|w| presets::find(w).is_some()))
        .flatten()
        .collect()
}

/// The presets and `--set KEY=VALUE`s the Markdown documentation names.
fn documented() -> (BTreeSet<String>, BTreeSet<(String, String)>) {
    let mut files = vec![];
    markdown_files(&repo(), &mut files);
    let (mut presets, mut sets) = (BTreeSet::new(), BTreeSet::new());
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        for flag in ["--config", "--configs"] {
            for v in values_after(&text, flag) {
                for p in v.split(',') {
                    // Paths are files; `KEY=VALUE`-like words are other flags' values.
                    let word = p.trim_end_matches(['.', ',', ';', ':']);
                    if !word.is_empty()
                        && !word.contains(['/', '.', '=', '$', '{'])
                        && word.chars().all(|c| c.is_ascii_lowercase() || c == '-')
                    {
                        presets.insert(word.to_string());
                    }
                }
            }
        }
        for line in text.lines() {
            presets.extend(preset_list_in(line));
        }
        for v in values_after(&text, "--set") {
            if let Some((k, val)) = v.split_once('=') {
                let placeholder = k == "key" || k.chars().any(|c| c.is_ascii_uppercase());
                if !k.is_empty() && !val.is_empty() && !k.contains(['<', '…']) && !placeholder {
                    let val = val.trim_end_matches(['.', ',', ';', ':']);
                    sets.insert((k.to_string(), val.to_string()));
                }
            }
        }
    }
    // PDA presets of `mer train --config` are another vocabulary (depthsense_config::pda).
    for pda in ["fast", "test"] {
        presets.remove(pda);
    }
    (presets, sets)
}

/// Every subcommand path (`["experiment", "ablation"]`) with its command.
fn leaves(cmd: &clap::Command, path: Vec<String>, out: &mut Vec<(Vec<String>, clap::Command)>) {
    if cmd.get_subcommands().next().is_none() {
        out.push((path, cmd.clone()));
        return;
    }
    for s in cmd.get_subcommands() {
        let mut p = path.clone();
        p.push(s.get_name().to_string());
        leaves(s, p, out);
    }
}

/// `depthsense PATH FLAG VALUE` parses, or fails only for a missing required argument or a
/// conflict with another (absent) input of the same command.
fn accepted(path: &[String], flag: &str, value: &str) -> Result<(), String> {
    let mut argv = vec!["depthsense".to_string()];
    argv.extend(path.iter().cloned());
    argv.push(flag.to_string());
    argv.push(value.to_string());
    match Cli::try_parse_from(&argv) {
        Ok(_) => Ok(()),
        Err(e) if matches!(e.kind(), ErrorKind::MissingRequiredArgument) => Ok(()),
        Err(e) => Err(format!("{}: {}", argv.join(" "), e.render())),
    }
}

/// The registry's flags of `cmd`: (flag, its help text) for config/configs/set.
fn registry_flags(cmd: &clap::Command) -> Vec<(String, String)> {
    cmd.get_arguments()
        .filter_map(|a| {
            let long = a.get_long()?;
            matches!(long, "config" | "configs" | "set").then(|| {
                let help = a
                    .get_long_help()
                    .or(a.get_help())
                    .map(|h| h.to_string())
                    .unwrap_or_default();
                (format!("--{long}"), help)
            })
        })
        .collect()
}

#[test]
fn every_documented_preset_and_key_is_accepted_by_every_command_that_takes_them() {
    let (doc_presets, doc_sets) = documented();
    for p in ["paper", "released", "tiny", "tiny-wide"] {
        assert!(
            doc_presets.contains(p),
            "{p} not found in the docs: {doc_presets:?}"
        );
    }
    assert!(
        doc_sets.len() >= 5,
        "few --set found in the docs: {doc_sets:?}"
    );
    for p in &doc_presets {
        assert!(
            presets::find(p).is_some(),
            "the docs name preset `{p}`, which is not in the registry"
        );
    }
    for (k, _) in &doc_sets {
        assert!(
            options::find(k).is_some(),
            "the docs set key `{k}`, unknown to the registry"
        );
    }

    let mut all = vec![];
    leaves(&Cli::command(), vec![], &mut all);
    let (mut commands, mut problems) = (0, vec![]);
    for (path, cmd) in &all {
        let flags = registry_flags(cmd);
        if flags.is_empty() {
            continue;
        }
        commands += 1;
        for (flag, help) in &flags {
            if path == &["mer", "train"] && flag == "--config" {
                continue; // the PDA network's presets
            }
            let words: Vec<String> = if flag == "--set" {
                assert!(
                    help == depthsense_cli::cmd::SET_HELP && help.contains("model-info --keys"),
                    "{} {flag}: its help does not point to the one list of keys: {help}",
                    path.join(" ")
                );
                doc_sets.iter().map(|(k, v)| format!("{k}={v}")).collect()
            } else {
                assert!(
                    help.contains(&depthsense_config::cli::preset_list()),
                    "{} {flag}: its help does not list the presets: {help}",
                    path.join(" ")
                );
                doc_presets.iter().cloned().collect()
            };
            for w in &words {
                if let Err(e) = accepted(path, flag, w) {
                    problems.push(e);
                }
            }
            // And a word outside the registry is refused while parsing.
            let bad = if flag == "--set" {
                "colour=red"
            } else {
                "huge"
            };
            if accepted(path, flag, bad).is_ok() {
                problems.push(format!("{} {flag} {bad} was accepted", path.join(" ")));
            }
        }
    }
    assert!(
        commands >= 10,
        "only {commands} commands take --config/--set"
    );
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn every_preset_builds_its_network_in_model_info() {
    for p in presets::PRESETS {
        let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
            .args([
                "model-info",
                "--config",
                p.name,
                "--set",
                "input-downscale=2",
            ])
            .output()
            .unwrap();
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "{}: {}",
            p.name,
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(out.contains("parameters") || out.contains("total"), "{out}");
    }
    let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args(["train", "--data", "nowhere", "--config", "tiny-wider"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("`tiny-wider`") && err.contains(&depthsense_config::cli::preset_list()),
        "{err}"
    );
}

/// The one list of `--set` keys: `model-info --keys`, printed by the torch-free binary from the
/// registry — every key with its values, and nothing else.
#[test]
fn model_info_keys_prints_every_key_once() {
    let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args(["model-info", "--keys"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    for o in options::OPTIONS {
        let described = out
            .lines()
            .filter(|l| l.trim_start().starts_with(o.key))
            .filter(|l| l.trim_start()[o.key.len()..].starts_with(['=', ' ']))
            .count();
        assert_eq!(described, 1, "`{}` in model-info --keys:\n{out}", o.key);
    }
    assert!(
        !out.contains("parameters"),
        "--keys prints the keys only: {out}"
    );
}
