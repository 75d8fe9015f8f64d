//! The CLI crate's one integration-test binary (each test binary links libtorch through the
//! crate, and linking dominates the test build; issue 35):
//! - `docs`: the docs that stay true (commands parse, result numbers, links, the CLI reference,
//!   ARCHITECTURE's layer table);
//! - `errors`: no catch-all `…Error::Other(String)` built outside tests (issue 43 item 3);
//! - `front`: the torch-free `depthsense` front and its hand-over to `depthsense-net`;
//! - `gpu_check`: `scripts/gpu-check.sh --cpu-dry-run`, the science step first (issue 45);
//! - `interruptions`, `run_folders`, `train_nproc`, `bench_export`: the binary under signals,
//!   in run folders, with `--nproc` and `bench export`;
//!
//! and a user's day with the real binary (issue 33):
//! - `logs`: long commands followed from a log file;
//! - `keys`: one set of presets and `--set` keys, the same everywhere;
//! - `mistakes`: errors that name the cause once and the next step; unreadable samples;
//! - `finetune`: `--resume` of a finished run, `--extend`, `--init-from`;
//! - `predict_frames`: `predict` over a list of sample tokens, pipelined.

mod bench_export;
mod common;
mod docs;
mod errors;
mod finetune;
mod front;
mod gpu_check;
mod interruptions;
mod keys;
mod logs;
mod mistakes;
mod predict_frames;
mod run_folders;
mod train_nproc;
