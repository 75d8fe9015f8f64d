//! `depthsense`: the torch-free front. It parses every command (so `--help` and flag errors
//! are instant), runs the data commands itself and hands the network commands to
//! `depthsense-net` beside it (`depthsense_cli::handoff`). It never links libtorch.

use std::process::ExitCode;

use depthsense_cli::{finish, handoff, run_without_torch};

fn main() -> ExitCode {
    let cli = match depthsense_cli::parse() {
        Ok(cli) => cli,
        Err(e) => return finish(Err(e)),
    };
    depthsense_progress::configure(cli.log_every);
    finish(match run_without_torch(cli.command) {
        Ok(result) => result,
        Err(_network_command) => handoff::run_in_net(std::env::args_os().skip(1).collect()),
    })
}
