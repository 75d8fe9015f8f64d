//! A user's day with the real binary (issue 33), one test binary (each links libtorch through
//! the CLI crate, and linking dominates the test build):
//! - `logs`: long commands followed from a log file;
//! - `keys`: one set of presets and `--set` keys, the same everywhere;
//! - `mistakes`: errors that name the cause once and the next step; unreadable samples;
//! - `finetune`: `--resume` of a finished run, `--extend`, `--init-from`.

#[path = "../common/mod.rs"]
mod common;
mod finetune;
mod keys;
mod logs;
mod mistakes;
