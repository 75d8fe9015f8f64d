//! Every subcommand's flags (`Args`, torch-free, parsed by both binaries) and the `run` of
//! the commands that need no network. The network commands' `run` live in
//! `src/bin/depthsense-net/<name>.rs`.

/// The short help of every `--set` (its `--help` lists every key: `depthsense_config`).
pub const SET_SHORT: &str =
    "Override one model-config option, KEY=VALUE, repeatable (--help lists every key)";

pub mod bench;
pub mod bench_data;
pub mod bench_export;
pub mod bench_model;
pub mod bench_synth;
pub mod bench_train;
pub mod calibration;
pub mod demo;
pub mod device_arg;
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
pub mod ranges;
pub mod report;
pub mod scoring_args;
pub mod synth;
pub mod train;
pub mod words;
