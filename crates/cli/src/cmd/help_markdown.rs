//! `depthsense help-markdown` (hidden): the command-line reference as Markdown, generated from
//! the clap definitions both binaries parse with — `docs/guide/cli.md` is its output, and a test
//! (`cli/tests/cli/docs.rs`) fails when the two differ.
//!
//! Said once: the global flags (`--log-every`) and `-h`/`--help` are printed in the first
//! section only, the `--set` keys in the last one (every `--set` points there), and the options
//! of a section are listed without blank lines between them.

use std::process::ExitCode;

use clap::CommandFactory;

#[derive(clap::Args)]
pub struct Args {}

/// The title of the reference's last section: every `--set` key (`model-info --keys`).
pub const KEYS_SECTION: &str = "Model-config keys (`--set`)";

/// The reference: one section per subcommand (depth first), each with its `--help` text, and
/// the `--set` keys at the end.
pub fn reference(root: &clap::Command) -> String {
    let mut out = String::from(
        "# Command-line reference\n\n\
         Generated from the command-line definitions by `depthsense help-markdown` — do not \
         edit by hand; after changing a flag run\n\
         `target/debug/depthsense help-markdown > docs/guide/cli.md`.\n\n\
         `depthsense` runs the data commands itself and hands the network commands to \
         `depthsense-net` beside it (both parse this same command line). Every command also \
         takes the options of `depthsense` itself (below: `--log-every`, and `-h` for a summary, \
         `--help` for the text here); each `--set` takes a key of the last section.\n",
    );
    let mut root = root.clone().term_width(100);
    root.build();
    section(&mut out, &root, "depthsense");
    out.push_str(&format!(
        "\n## {KEYS_SECTION}\n\nThe keys of every `--set KEY=VALUE` (`depthsense model-info \
         --keys` prints the same list).\n\n```text\n{}\n```\n",
        depthsense_config::cli::set_help().trim_end()
    ));
    out
}

fn section(out: &mut String, cmd: &clap::Command, path: &str) {
    let level = if path.contains(' ') { "###" } else { "##" };
    out.push_str(&format!("\n{level} `{path}`\n\n```text\n"));
    let mut shown = cmd.clone();
    if path.contains(' ') {
        // The global flags and the help flag: printed once, in the first section.
        let said_once: Vec<clap::Id> = cmd
            .get_arguments()
            .filter(|a| a.is_global_set() || a.get_id() == "help")
            .map(|a| a.get_id().clone())
            .collect();
        for id in said_once {
            shown = shown.mut_arg(id, |a| a.hide(true));
        }
    }
    let help = shown.render_long_help().to_string();
    out.push_str(&compact(&help));
    out.push_str("```\n");
    for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
        if sub.get_name() == "help" {
            continue;
        }
        section(out, sub, &format!("{path} {}", sub.get_name()));
    }
}

/// `--help`'s text with one line per option: its flags, its description, its `[default: …]`
/// (clap's long help puts each on a line of its own, between blank lines); blank lines inside a
/// list dropped, trailing blanks trimmed. Headings, paragraphs and examples stay as they are.
fn compact(help: &str) -> String {
    let lines: Vec<&str> = help.trim_end().lines().map(str::trim_end).collect();
    let indented = |i: usize| lines.get(i).is_some_and(|l| l.starts_with(' '));
    let mut out: Vec<String> = vec![];
    // Inside an option's entry (its flag line seen), and whether its description began.
    let (mut in_entry, mut described) = (false, false);
    for (i, line) in lines.iter().enumerate() {
        if line.is_empty() {
            if i > 0 && indented(i - 1) && indented(i + 1) {
                continue;
            }
            in_entry = false;
            out.push(String::new());
            continue;
        }
        let body = line.trim_start();
        let depth = line.len() - body.len();
        if let (true, Some(last)) = (in_entry && depth >= 8, out.last_mut()) {
            last.push_str(if described { " " } else { "  " });
            last.push_str(body);
            described = true;
            continue;
        }
        in_entry = (1..8).contains(&depth) && (body.starts_with('-') || body.starts_with('<'));
        described = false;
        out.push(line.to_string());
    }
    out.join("\n") + "\n"
}

pub fn run(_: Args) -> anyhow::Result<ExitCode> {
    print!("{}", reference(&crate::Cli::command()));
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compact_puts_each_option_on_one_line() {
        let help = "About.\n\nUsage: x\n\nOptions:\n      --a <A>\n          Aaa\n\n          \
                    [default: 1]\n\n      --b\n          Bbb\n\nData:\n  <C>\n          C\n\n\
                    Examples:\n  x --a 2\n  x --b\n";
        assert_eq!(
            compact(help),
            "About.\n\nUsage: x\n\nOptions:\n      --a <A>  Aaa [default: 1]\n      --b  Bbb\n\n\
             Data:\n  <C>  C\n\nExamples:\n  x --a 2\n  x --b\n"
        );
    }

    /// Each thing said once: the reference stays short (issue 43: 2,457 lines before), the global
    /// flag and the `--set` keys appear once, every command's section is there.
    #[test]
    fn the_reference_says_each_thing_once() {
        let md = reference(&crate::Cli::command());
        let lines = md.lines().count();
        assert!(lines <= 1200, "docs/guide/cli.md: {lines} lines");
        let flag_lines = |flag: &str| {
            md.lines()
                .filter(|l| l.trim_start().starts_with(flag))
                .count()
        };
        assert_eq!(flag_lines("--log-every "), 1);
        assert_eq!(flag_lines("-h, --help"), 1);
        for o in depthsense_config::options::OPTIONS {
            let described = format!("{} (", o.key);
            assert_eq!(flag_lines(&described), 1, "{described}");
        }
        assert_eq!(md.matches(KEYS_SECTION).count(), 1);
        for section in [
            "`depthsense train`",
            "`depthsense bench model`",
            "`depthsense mer train`",
        ] {
            assert!(md.contains(&format!("### {section}")), "{section}");
        }
        // Still every option of train, one line each, with its default.
        assert!(md
            .lines()
            .any(|l| l.starts_with("      --warmup <N>  ") && l.ends_with("[default: 0]")));
    }
}
