//! Builds `shim/dist.cpp` against the libtorch that tch links (same include paths, C++17 and
//! `_GLIBCXX_USE_CXX11_ABI` as torch-sys), and links libtorch_cpu (c10d, Gloo, TCPStore).
//!
//! libtorch is found as torch-sys finds it: `$LIBTORCH` (include/, lib/) or the active
//! Python's `torch` package (`LIBTORCH_USE_PYTORCH=1`, the project's `.venv`).
//!
//! The wheel ships `ProcessGroupGloo.hpp` without the Gloo headers it includes; the shim uses
//! only ProcessGroupGloo's library functions, so `shim/gloo_decl/` declares the few Gloo names
//! that header mentions. `$GLOO_INCLUDE` points at a real Gloo checkout instead.
//!
//! Feature `nccl`: also compile ProcessGroupNCCL (`-DUSE_C10D_NCCL`), with the CUDA runtime and
//! NCCL headers of the wheel's `nvidia-*` packages (or `$CUDA_INCLUDE` / `$NCCL_INCLUDE`), libcu++
//! from `nvidia-cuda-cccl` (or `$CCCL_INCLUDE`) and `crt/` from triton's wheel, and link
//! libtorch_cuda.

use std::path::{Path, PathBuf};
use std::process::Command;

include!("../../build-support/torch_find.rs");
include!("../../build-support/torch_link.rs");
include!("../../build-support/cuda_find.rs");

fn main() {
    println!("cargo:rerun-if-changed=shim/dist.cpp");
    println!("cargo:rerun-if-changed=shim/gloo_decl");
    let torch = find_torch();
    let mut build = shim_build(&torch);
    build
        .flag("-DGLOG_USE_GLOG_EXPORT")
        .define("USE_C10D_GLOO", None)
        .file("shim/dist.cpp");
    match env_dir("GLOO_INCLUDE") {
        Some(g) => build.include(g),
        None => build.include("shim/gloo_decl"),
    };
    let nccl = std::env::var_os("CARGO_FEATURE_NCCL").is_some();
    if nccl {
        let nccl_inc = env_dir("NCCL_INCLUDE").or_else(|| {
            let p = nvidia_dir(&torch)?.join("nccl/include");
            p.join("nccl.h").exists().then_some(p)
        });
        match (cuda_includes(&torch, "nccl"), nccl_inc) {
            (Some(c), Some(n)) => {
                build.includes(c).include(n);
                build
                    .define("USE_C10D_NCCL", None)
                    .define("USE_CUDA", None)
                    .define("DSD_NCCL", None);
            }
            (c, n) => panic!(
                "depthsense-dist feature `nccl`: CUDA runtime headers {} and nccl.h {}; set \
                 CUDA_INCLUDE / NCCL_INCLUDE",
                if c.is_some() { "found" } else { "not found" },
                if n.is_some() { "found" } else { "not found" }
            ),
        }
    }
    build.compile("depthsense_dist_shim");
    println!("cargo:rustc-link-search=native={}", torch.lib.display());
    println!("cargo:rustc-link-lib=dylib=torch_cpu");
    println!("cargo:rustc-link-lib=dylib=c10");
    if nccl {
        println!("cargo:rustc-link-lib=dylib=torch_cuda");
    }
    link_torch();
}
