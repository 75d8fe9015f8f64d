//! The command line a newcomer meets (issue 43 item 4): headings on every command with many
//! flags, one name for one concept (`--config` everywhere, `--warmup` only for the learning
//! rate), one short `--set` help that points to the one list of keys, and examples in the help
//! of the first commands one runs. Each rule is a checker over `Cli::command()`, shown to catch
//! a broken command.

use clap::{Command, CommandFactory, Parser};

use crate::Cli;

/// More flags than this and a command's help needs headings.
const MANY_FLAGS: usize = 12;

/// Every command under `cmd` (itself included) with its path, depth first.
fn all(cmd: &Command, path: &str, out: &mut Vec<(String, Command)>) {
    out.push((path.to_string(), cmd.clone()));
    for sub in cmd.get_subcommands() {
        all(sub, &format!("{path} {}", sub.get_name()), out);
    }
}

fn commands() -> Vec<(String, Command)> {
    let mut out = vec![];
    all(&Cli::command(), "depthsense", &mut out);
    out
}

/// The flags `cmd` shows of its own (not the global ones, not `--help`/`--version`).
fn own_flags(cmd: &Command) -> Vec<&clap::Arg> {
    cmd.get_arguments()
        .filter(|a| !a.is_hide_set() && !a.is_global_set() && !a.is_positional())
        .filter(|a| !matches!(a.get_id().as_str(), "help" | "version"))
        .collect()
}

/// `path`'s flags without a heading, when it has more than [`MANY_FLAGS`].
fn heading_problems(path: &str, cmd: &Command) -> Vec<String> {
    let flags = own_flags(cmd);
    if flags.len() <= MANY_FLAGS {
        return vec![];
    }
    flags
        .iter()
        .filter(|a| a.get_help_heading().is_none())
        .map(|a| format!("{path} --{}: no heading", a.get_id()))
        .collect()
}

#[test]
fn every_command_with_many_flags_has_headings_on_all_of_them() {
    let cmds = commands();
    let many: Vec<&str> = cmds
        .iter()
        .filter(|(_, c)| own_flags(c).len() > MANY_FLAGS)
        .map(|(p, _)| p.as_str())
        .collect();
    for p in [
        "train",
        "eval",
        "predict",
        "synth",
        "mer train",
        "bench model",
    ] {
        assert!(
            many.contains(&format!("depthsense {p}").as_str()),
            "{p} has ≤ {MANY_FLAGS} flags? {many:?}"
        );
    }
    let problems: Vec<String> = cmds
        .iter()
        .flat_map(|(p, c)| heading_problems(p, c))
        .collect();
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // The checker catches a flag without a heading.
    let train = Cli::command().find_subcommand("train").unwrap().clone();
    let no_heading = clap::Arg::new("new_flag")
        .long("new-flag")
        .help_heading(None::<&'static str>);
    let broken = train.arg(no_heading);
    assert_eq!(
        heading_problems("train", &broken),
        ["train --new_flag: no heading"]
    );
}

/// A flag that names the network by another word than `--config`, or `--warmup` on anything
/// but the learning rate.
fn naming_problems(path: &str, cmd: &Command) -> Vec<String> {
    let presets = depthsense_config::cli::preset_list();
    let mut out = vec![];
    for a in cmd.get_arguments() {
        let long = a.get_long().unwrap_or_default();
        let help = a.get_help().map(|h| h.to_string()).unwrap_or_default();
        if long.contains("preset") || a.get_id().as_str().contains("preset") {
            out.push(format!("{path} --{long}: the network is `--config`"));
        }
        let lists_presets = help.contains(&format!("a preset ({presets})"));
        if lists_presets && !matches!(long, "config" | "configs") && !path.ends_with("mer train") {
            out.push(format!(
                "{path} --{long}: a network flag not named --config"
            ));
        }
        if long == "warmup" && !help.contains("learning-rate") {
            out.push(format!(
                "{path} --warmup: not the learning-rate warm-up: {help}"
            ));
        }
        if help.to_lowercase().contains("untimed") && long != "warmup-runs" {
            out.push(format!("{path} --{long}: untimed runs are --warmup-runs"));
        }
    }
    out
}

#[test]
fn one_name_for_one_concept() {
    let cmds = commands();
    let problems: Vec<String> = cmds
        .iter()
        .flat_map(|(p, c)| naming_problems(p, c))
        .collect();
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    let named = |long: &str| {
        cmds.iter()
            .filter(|(_, c)| c.get_arguments().any(|a| a.get_long() == Some(long)))
            .count()
    };
    assert!(
        named("config") >= 14,
        "only {} commands take --config",
        named("config")
    );
    assert!(named("warmup-runs") >= 4 && named("warmup") >= 4);
    // `--preset`: the old name of five commands, a hidden alias there, refused elsewhere.
    let parses = |line: &str| Cli::try_parse_from(line.split(' ')).is_ok();
    assert!(parses("depthsense bench model --preset tiny"));
    assert!(!parses("depthsense train --data d --preset tiny"));
    assert!(!parses("depthsense bench model --warmup 3"));
    assert!(parses("depthsense train --data d --warmup 3"));
    let help = Cli::command()
        .find_subcommand("bench")
        .and_then(|b| b.find_subcommand("model"))
        .unwrap()
        .clone()
        .render_long_help()
        .to_string();
    assert!(
        !help.contains("preset]") && !help.contains("--preset"),
        "{help}"
    );
    // The checker catches the old names.
    let old = Command::new("bench-model")
        .arg(clap::Arg::new("preset").long("preset").help("Network"))
        .arg(clap::Arg::new("warmup").long("warmup").help("Untimed runs"));
    assert_eq!(naming_problems("bench model", &old).len(), 3);
}

#[test]
fn every_set_help_is_short_and_points_to_the_keys() {
    let mut n = 0;
    for (path, cmd) in commands() {
        for a in cmd.get_arguments().filter(|a| a.get_long() == Some("set")) {
            n += 1;
            let help = a.get_help().map(|h| h.to_string()).unwrap_or_default();
            assert_eq!(help, crate::cmd::SET_HELP, "{path} --set");
            assert!(a.get_long_help().is_none(), "{path} --set has a long help");
        }
    }
    assert!(n >= 12, "only {n} --set flags");
    let set = crate::cmd::SET_HELP;
    assert!(set.len() < 160 && !set.contains('\n') && set.contains("model-info --keys"));
}

/// The help of the commands one runs first: its examples, each a command that parses.
#[test]
fn the_first_commands_show_examples_that_parse() {
    for name in ["prepare", "train", "eval", "predict"] {
        let mut cmd = Cli::command();
        cmd.build();
        let sub = cmd.find_subcommand(name).unwrap().clone();
        for help in [
            sub.clone().render_help().to_string(),
            sub.clone().render_long_help().to_string(),
        ] {
            let examples: Vec<&str> = help
                .lines()
                .skip_while(|l| *l != "Examples:")
                .filter(|l| l.starts_with(&format!("  depthsense {name} ")))
                .collect();
            assert!(examples.len() >= 2, "{name} --help: {help}");
            for e in examples {
                if let Err(err) = Cli::try_parse_from(e.split_whitespace()) {
                    panic!("{e}: {}", err.render());
                }
            }
        }
    }
    let train = Cli::command()
        .find_subcommand("train")
        .unwrap()
        .clone()
        .render_help()
        .to_string();
    for heading in [
        "Data:",
        "Model:",
        "Schedule:",
        "Output:",
        "Device:",
        "Data-parallel:",
    ] {
        assert!(
            train.lines().any(|l| l == heading),
            "train -h: no {heading}"
        );
    }
}
