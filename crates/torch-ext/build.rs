//! Builds `shim/torch_ext.cpp` and `shim/cuda_graph.cpp` against the libtorch that tch links
//! (same include paths, C++17 and `_GLIBCXX_USE_CXX11_ABI` as torch-sys;
//! build-support/torch_find.rs) and links libtorch. Feature `cuda-graphs`: `cuda_graph.cpp` with
//! `at::cuda::CUDAGraph`, against the CUDA runtime headers of the torch wheel's `nvidia-*`
//! packages (or `$CUDA_INCLUDE`), libcu++ from `nvidia-cuda-cccl` (or `$CCCL_INCLUDE`), as
//! crates/dist's NCCL build; without it the graph functions are stubs.

use std::path::{Path, PathBuf};
use std::process::Command;

include!("../../build-support/torch_find.rs");
include!("../../build-support/torch_link.rs");
include!("../../build-support/cuda_find.rs");

fn main() {
    println!("cargo:rerun-if-changed=shim/torch_ext.cpp");
    println!("cargo:rerun-if-changed=shim/cuda_graph.cpp");
    let torch = find_torch();
    let graphs = std::env::var_os("CARGO_FEATURE_CUDA_GRAPHS").is_some();
    let mut build = shim_build(&torch);
    build.file("shim/torch_ext.cpp").file("shim/cuda_graph.cpp");
    if graphs {
        build
            .includes(cuda_includes(&torch, "cuda-graphs").unwrap_or_else(|| {
                panic!(
                    "depthsense-torch-ext feature `cuda-graphs`: CUDA runtime headers not found; \
                     set CUDA_INCLUDE"
                )
            }))
            .define("USE_CUDA", None)
            .define("DSX_CUDA_GRAPHS", None);
    }
    build.compile("depthsense_torch_ext_shim");
    println!("cargo:rustc-link-search=native={}", torch.lib.display());
    println!("cargo:rustc-link-lib=dylib=torch_cpu");
    println!("cargo:rustc-link-lib=dylib=c10");
    if graphs {
        println!("cargo:rustc-link-lib=dylib=torch_cuda");
        println!("cargo:rustc-link-lib=dylib=c10_cuda");
    }
    link_torch();
}
