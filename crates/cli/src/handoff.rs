//! `depthsense` hands a network command to `depthsense-net`, the binary beside it that links
//! libtorch, so that the data commands start without loading libtorch (≈ 0.5 s, 470 MB).

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

/// File name of the binary that runs the network commands.
pub const NET_BINARY: &str = "depthsense-net";

/// `depthsense-net` in the folder of the running executable.
pub fn net_binary() -> anyhow::Result<PathBuf> {
    let exe = std::env::current_exe()
        .map_err(|e| anyhow::anyhow!("cannot find the running executable: {e}"))?;
    let name = format!("{NET_BINARY}{}", std::env::consts::EXE_SUFFIX);
    Ok(exe.with_file_name(name))
}

/// Replaces this process with `depthsense-net ARGS` (same process id, standard streams and
/// environment; its exit code is the user's). Returns only when that fails.
pub fn run_in_net(args: Vec<OsString>) -> anyhow::Result<ExitCode> {
    let net = net_binary()?;
    if !net.is_file() {
        anyhow::bail!(
            "{}: not found; the network commands (train, eval --checkpoint, predict, export, \
             demo, …) run in {NET_BINARY}, which is built and installed beside depthsense \
             (`make build`, or `cargo build --release -p depthsense-cli`)",
            net.display()
        );
    }
    let mut command = std::process::Command::new(&net);
    command.args(args);
    // The user's argv[0] (`depthsense`), so the command lines outputs record (tables.json,
    // report pages) read as typed; depthsense-net finds itself through /proc/self/exe.
    #[cfg(unix)]
    if let Some(arg0) = std::env::args_os().next() {
        use std::os::unix::process::CommandExt;
        command.arg0(arg0);
    }
    exec(command, &net)
}

#[cfg(unix)]
fn exec(mut command: std::process::Command, net: &std::path::Path) -> anyhow::Result<ExitCode> {
    use std::os::unix::process::CommandExt;
    let err = command.exec();
    anyhow::bail!("cannot start {}: {err}", net.display())
}

#[cfg(not(unix))]
fn exec(mut command: std::process::Command, net: &std::path::Path) -> anyhow::Result<ExitCode> {
    let status = command
        .status()
        .map_err(|e| anyhow::anyhow!("cannot start {}: {e}", net.display()))?;
    Ok(match status.code() {
        Some(0) => ExitCode::SUCCESS,
        Some(c) => ExitCode::from(u8::try_from(c).unwrap_or(1)),
        None => ExitCode::FAILURE,
    })
}
