// Shared by the build scripts of every crate that links libtorch (each also depends on
// torch-sys directly, for DEP_TCH_LIBTORCH_LIB below).
// `include!`d, not a crate: build scripts cannot share code otherwise.
//
// Two link facts (see DEVELOPERS.md / README "Set-up"):
// 1. rustc links with `--as-needed`, which silently drops `libtorch_cuda.so` because no
//    symbol of it is referenced directly; CUDA then looks absent at run time. We re-add it
//    between `--no-as-needed` ... `--as-needed`.
// 2. An rpath to the wheel's `torch/lib` so binaries, tests and benches run without
//    `LD_LIBRARY_PATH` on the machine that built them.

fn torch_lib_dir() -> Option<std::path::PathBuf> {
    // torch-sys (`links = "tch"`) already found libtorch and passes its lib dir to the build
    // scripts of crates that depend on it directly: no second Python start (~2 s a crate).
    if let Some(dir) = std::env::var_os("DEP_TCH_LIBTORCH_LIB") {
        return Some(std::path::PathBuf::from(dir));
    }
    println!("cargo:rerun-if-env-changed=VIRTUAL_ENV");
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    if let Ok(libtorch) = std::env::var("LIBTORCH") {
        return Some(std::path::PathBuf::from(libtorch).join("lib"));
    }
    let python = if std::env::var_os("VIRTUAL_ENV").is_some() {
        "python"
    } else {
        "python3"
    };
    let out = std::process::Command::new(python)
        .args([
            "-c",
            "import torch, os; print(os.path.join(os.path.dirname(torch.__file__), 'lib'))",
        ])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let dir = String::from_utf8_lossy(&out.stdout).trim().to_string();
    (!dir.is_empty()).then(|| std::path::PathBuf::from(dir))
}

#[allow(dead_code)]
fn link_torch() {
    link_torch_for(None);
}

/// The link arguments for every target of the package (`None`), or for one binary and the
/// package's tests.
#[allow(dead_code)]
fn link_torch_for(bin: Option<&str>) {
    let arg = |a: String| match bin {
        Some(b) => {
            println!("cargo:rustc-link-arg-bin={b}={a}");
            println!("cargo:rustc-link-arg-tests={a}");
        }
        None => println!("cargo:rustc-link-arg={a}"),
    };
    let Some(dir) = torch_lib_dir() else {
        println!("cargo:warning=torch not found by the active python: run `make setup` and build through `make` (or `source .venv/bin/activate`)");
        return;
    };
    let target_os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    if target_os != "linux" {
        return;
    }
    arg(format!("-Wl,-rpath,{}", dir.display()));
    if dir.join("libtorch_cuda.so").exists() {
        arg(format!("-L{}", dir.display()));
        arg("-Wl,--no-as-needed".into());
        arg("-ltorch_cuda".into());
        arg("-Wl,--as-needed".into());
    }
}
