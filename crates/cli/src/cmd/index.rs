//! `depthsense index`: operations on prepared output folders.

use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Combine the parts of a sharded `prepare --shard I/N` into OUT/index.json.
    ///
    /// Shards written to one shared OUT leave OUT/index.shard-I-of-N.json files: run
    /// `depthsense index merge OUT`. Shards written to separate folders (one per machine):
    /// `depthsense index merge OUT DIR...` moves their sample folders into OUT (same file
    /// system) and merges their indexes. Refuses sources of another dataset version or with
    /// other map settings, and an incomplete shard set.
    Merge {
        /// The output folder (its own shard indexes and index.json are included).
        out: PathBuf,
        /// Other prepared folders to merge into OUT.
        dirs: Vec<PathBuf>,
    },
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.command {
        Command::Merge { out, dirs } => {
            let s = depthsense_prep::index::merge(&out, &dirs)?;
            eprintln!(
                "merged {} index files into {} ({} samples, {} sample folders moved)",
                s.sources.len(),
                out.join(depthsense_prep::layout::INDEX_FILE).display(),
                s.samples,
                s.moved
            );
            Ok(ExitCode::SUCCESS)
        }
    }
}
