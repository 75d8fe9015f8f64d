//! `depthsense inspect PATH...`: JSON summary of sensor files, folders of them, or a version
//! folder.

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_prep::inspect::{
    expand_paths, inspect, inspect_all, is_prepared_folder, is_prepared_sample, is_version_folder,
};

#[derive(clap::Args)]
pub struct Args {
    /// Radar `.pcd` files (ascii, binary or binary_compressed), lidar `.pcd.bin`, camera
    /// `.jpg`/`.png`, folders of them (read recursively, sorted), a version folder (e.g.
    /// DATAROOT/v1.0-mini), or depthsense's outputs: a prepared folder, a prepared sample
    /// folder (every map summarised), a 16-bit depth PNG (valid pixels, depth range),
    /// `radar_points.bin`, a JSON file (`tables.json`: each model's headline row). One file or
    /// folder of those prints one JSON object; more print a JSON array with one object per file
    /// (`{"path", "error"}` for a file that cannot be read, and the exit code is then 1).
    #[arg(required = true)]
    paths: Vec<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let p = &a.paths[0];
    let one_entry =
        !p.is_dir() || is_version_folder(p) || is_prepared_sample(p) || is_prepared_folder(p);
    let single = a.paths.len() == 1 && one_entry;
    if single {
        let v = inspect(&a.paths[0])?;
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(ExitCode::SUCCESS);
    }
    let files = expand_paths(&a.paths)?;
    let mut failed = 0usize;
    let all: Vec<serde_json::Value> = files
        .iter()
        .zip(inspect_all(&files))
        .map(|(p, r)| {
            r.unwrap_or_else(|e| {
                failed += 1;
                serde_json::json!({"path": p.display().to_string(), "error": e.to_string()})
            })
        })
        .collect();
    println!("{}", serde_json::to_string_pretty(&all)?);
    if failed > 0 {
        eprintln!("{failed} of {} file(s) could not be read", files.len());
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
