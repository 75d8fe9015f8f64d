//! Every subcommand's flags (`Args`, torch-free, parsed by both binaries) and the `run` of
//! the commands that need no network. The network commands' `run` live in
//! `src/bin/depthsense-net/<name>.rs`.

/// The help of every `--set`: what it does and the one place that lists every key
/// (`depthsense model-info --keys`, and the last section of docs/guide/cli.md, both generated
/// from `depthsense_config::options`) — the list itself is printed nowhere else.
pub const SET_HELP: &str = "Override one model-config option, KEY=VALUE, repeatable, applied in \
     order; every key and its values: `depthsense model-info --keys`";

pub use depthsense_config::heading;

pub mod bench;
pub mod bench_data;
pub mod bench_export;
pub mod bench_model;
pub mod bench_synth;
pub mod bench_train;
pub mod calibration;
pub mod demo;
pub mod eval;
pub mod experiment;
pub mod explain;
pub mod export;
pub mod help_markdown;
pub mod index;
pub mod inference_args;
pub mod inspect;
pub mod mer;
pub mod model_info;
pub mod model_source;
pub mod predict;
pub mod prepare;
pub mod progress;
pub mod radar_args;
pub use depthsense_config::ranges;
pub mod report;
pub mod scoring_args;
pub mod synth;
pub mod train;
pub use depthsense_config::words_parser as words;
