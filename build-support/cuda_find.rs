// The CUDA runtime headers a shim built against libtorch's CUDA parts needs (`include!`d by the
// build scripts of crates/dist — feature `nccl` — and crates/torch-ext — feature `cuda-graphs`):
// the torch wheel's `nvidia-*` packages (or `$CUDA_INCLUDE`), `crt/` from triton's wheel when the
// runtime wheel lacks it, and libcu++'s `<nv/target>` from `nvidia-cuda-cccl` (or
// `$CCCL_INCLUDE`). Needs `Torch` from torch_find.rs.

/// `$var` as a folder, re-run when it changes.
fn env_dir(var: &str) -> Option<PathBuf> {
    println!("cargo:rerun-if-env-changed={var}");
    std::env::var_os(var).map(PathBuf::from)
}

/// The torch wheel's `site-packages/nvidia` folder.
fn nvidia_dir(torch: &Torch) -> Option<PathBuf> {
    torch.site_packages.as_ref().map(|s| s.join("nvidia"))
}

/// The include folders of the CUDA runtime headers (with `crt/` and libcu++'s `nv/`), or `None`
/// when `cuda_runtime_api.h` is nowhere; `feature` names the feature in the warning for a missing
/// libcu++.
fn cuda_includes(torch: &Torch, feature: &str) -> Option<Vec<PathBuf>> {
    let nvidia = nvidia_dir(torch);
    let cuda = env_dir("CUDA_INCLUDE").or_else(|| {
        let n = nvidia.as_ref()?;
        ["cu13/include", "cuda_runtime/include"]
            .iter()
            .map(|s| n.join(s))
            .find(|p| p.join("cuda_runtime_api.h").exists())
    })?;
    let mut dirs = vec![cuda.clone()];
    if !cuda.join("crt/host_config.h").exists() {
        // The runtime wheel lacks `crt/host_config.h`, which cuda_runtime.h includes; triton's
        // wheel ships the CUDA headers with it.
        if let Some(t) = torch.site_packages.as_ref() {
            let p = t.join("triton/backends/nvidia/include");
            if p.join("crt/host_config.h").exists() {
                dirs.push(p);
            }
        }
    }
    match env_dir("CCCL_INCLUDE") {
        Some(cc) => dirs.push(cc),
        None if !cuda.join("nv/target").exists() => println!(
            "cargo:warning=feature {feature}: <nv/target> not found: `pip install \
             nvidia-cuda-cccl==13.0.*` into the venv or set CCCL_INCLUDE"
        ),
        None => {}
    }
    Some(dirs)
}
