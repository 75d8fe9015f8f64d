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

fn env_dir(var: &str) -> Option<PathBuf> {
    println!("cargo:rerun-if-env-changed={var}");
    std::env::var_os(var).map(PathBuf::from)
}

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
        let nvidia = torch.site_packages.as_ref().map(|s| s.join("nvidia"));
        let cuda_inc = env_dir("CUDA_INCLUDE").or_else(|| {
            let n = nvidia.as_ref()?;
            ["cu13/include", "cuda_runtime/include"]
                .iter()
                .map(|s| n.join(s))
                .find(|p| p.join("cuda_runtime_api.h").exists())
        });
        let nccl_inc = env_dir("NCCL_INCLUDE").or_else(|| {
            let p = nvidia.as_ref()?.join("nccl/include");
            p.join("nccl.h").exists().then_some(p)
        });
        // The runtime wheel lacks `crt/host_config.h`, which cuda_runtime.h includes; triton's
        // wheel ships the CUDA headers with it.
        let crt_inc = torch.site_packages.as_ref().and_then(|s| {
            let p = s.join("triton/backends/nvidia/include");
            p.join("crt/host_config.h").exists().then_some(p)
        });
        match (cuda_inc, nccl_inc) {
            (Some(c), Some(n)) => {
                let has_crt = c.join("crt/host_config.h").exists();
                let has_cccl = c.join("nv/target").exists();
                build.include(c).include(n);
                // libcu++'s <nv/target> (cuda_fp16.h includes it): the `nvidia-cuda-cccl`
                // wheel installs it next to the runtime headers, or `$CCCL_INCLUDE`.
                match env_dir("CCCL_INCLUDE") {
                    Some(cc) => {
                        build.include(cc);
                    }
                    None if !has_cccl => println!(
                        "cargo:warning=feature nccl: <nv/target> not found: `pip install \
                         nvidia-cuda-cccl==13.0.*` into the venv or set CCCL_INCLUDE"
                    ),
                    None => {}
                }
                if !has_crt {
                    if let Some(t) = crt_inc {
                        build.include(t);
                    }
                }
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
