//! Builds `shim/torch_ext.cpp` against the libtorch that tch links (same include paths, C++17
//! and `_GLIBCXX_USE_CXX11_ABI` as torch-sys; build-support/torch_find.rs) and links libtorch.

use std::path::{Path, PathBuf};
use std::process::Command;

include!("../../build-support/torch_find.rs");
include!("../../build-support/torch_link.rs");

fn main() {
    println!("cargo:rerun-if-changed=shim/torch_ext.cpp");
    let torch = find_torch();
    shim_build(&torch)
        .file("shim/torch_ext.cpp")
        .compile("depthsense_torch_ext_shim");
    println!("cargo:rustc-link-search=native={}", torch.lib.display());
    println!("cargo:rustc-link-lib=dylib=torch_cpu");
    println!("cargo:rustc-link-lib=dylib=c10");
    link_torch();
}
