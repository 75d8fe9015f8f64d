//! `depthsense help-markdown` (hidden): the command-line reference as Markdown, generated from
//! the clap definitions both binaries parse with — `docs/guide/cli.md` is its output, and a test
//! (`cli/tests/cli/docs.rs`) fails when the two differ.

use std::process::ExitCode;

use clap::CommandFactory;

#[derive(clap::Args)]
pub struct Args {}

/// The reference: one section per subcommand (depth first), each with its `--help` text.
pub fn reference(root: &clap::Command) -> String {
    let mut out = String::from(
        "# Command-line reference\n\n\
         Generated from the command-line definitions by `depthsense help-markdown` — do not \
         edit by hand; after changing a flag run\n\
         `target/debug/depthsense help-markdown > docs/guide/cli.md`.\n\n\
         `depthsense` runs the data commands itself and hands the network commands to \
         `depthsense-net` beside it (both parse this same command line).\n",
    );
    let mut root = root.clone().term_width(100);
    root.build();
    section(&mut out, &root, "depthsense");
    out
}

fn section(out: &mut String, cmd: &clap::Command, path: &str) {
    let level = if path.contains(' ') { "###" } else { "##" };
    out.push_str(&format!("\n{level} `{path}`\n\n```text\n"));
    let help = cmd.clone().render_long_help().to_string();
    for line in help.trim_end().lines() {
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out.push_str("```\n");
    for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
        if sub.get_name() == "help" {
            continue;
        }
        section(out, sub, &format!("{path} {}", sub.get_name()));
    }
}

pub fn run(_: Args) -> anyhow::Result<ExitCode> {
    print!("{}", reference(&crate::Cli::command()));
    Ok(ExitCode::SUCCESS)
}
