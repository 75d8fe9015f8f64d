//! `depthsense inspect PATH`: JSON summary of a sensor file or a version folder.

use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// A radar `.pcd` (ascii, binary or binary_compressed), a lidar `.pcd.bin`, a camera
    /// `.jpg`/`.png`, or a version folder (e.g. DATAROOT/v1.0-mini).
    path: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let v = depthsense_prep::inspect::inspect(&a.path)?;
    println!("{}", serde_json::to_string_pretty(&v)?);
    Ok(ExitCode::SUCCESS)
}
