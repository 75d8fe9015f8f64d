// Shared by the build scripts that compile a C++ shim against libtorch (`dist`, `torch-ext`):
// libtorch's include paths, lib dir and C++ ABI, found as torch-sys finds them — `$LIBTORCH`
// (include/, lib/) or the active Python's `torch` package (`LIBTORCH_USE_PYTORCH=1`, the
// project's `.venv`). `include!`d, not a crate: build scripts cannot share code otherwise.

#[allow(dead_code)]
struct Torch {
    includes: Vec<PathBuf>,
    lib: PathBuf,
    cxx11_abi: String,
    site_packages: Option<PathBuf>,
}

fn find_torch() -> Torch {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    println!("cargo:rerun-if-env-changed=LIBTORCH_CXX11_ABI");
    if let Ok(root) = std::env::var("LIBTORCH") {
        let root = PathBuf::from(root);
        return Torch {
            includes: vec![
                root.join("include"),
                root.join("include/torch/csrc/api/include"),
            ],
            lib: root.join("lib"),
            cxx11_abi: std::env::var("LIBTORCH_CXX11_ABI").unwrap_or_else(|_| "1".into()),
            site_packages: None,
        };
    }
    let python = if std::env::var_os("VIRTUAL_ENV").is_some() {
        "python"
    } else {
        "python3"
    };
    let script = "import os, torch\n\
                  d = os.path.dirname(torch.__file__)\n\
                  print('DIR:', d)\n\
                  print('ABI:', int(torch._C._GLIBCXX_USE_CXX11_ABI))\n";
    let out = Command::new(python)
        .args(["-c", script])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    if !out.status.success() {
        panic!(
            "`{python} -c 'import torch'` failed (activate .venv or set LIBTORCH): {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let mut dir = None;
    let mut abi = "1".to_string();
    for l in text.lines() {
        if let Some(d) = l.strip_prefix("DIR: ") {
            dir = Some(PathBuf::from(d.trim()));
        }
        if let Some(a) = l.strip_prefix("ABI: ") {
            abi = a.trim().to_string();
        }
    }
    let dir = dir.expect("python printed no torch directory");
    Torch {
        includes: vec![
            dir.join("include"),
            dir.join("include/torch/csrc/api/include"),
        ],
        lib: dir.join("lib"),
        cxx11_abi: abi,
        site_packages: dir.parent().map(Path::to_path_buf),
    }
}

/// A C++17 build against this libtorch: its include paths and the C++ ABI torch-sys uses.
#[allow(dead_code)]
fn shim_build(torch: &Torch) -> cc::Build {
    let mut build = cc::Build::new();
    build
        .cpp(true)
        .pic(true)
        .warnings(false)
        .includes(&torch.includes)
        .flag("-std=c++17")
        .flag(format!("-D_GLIBCXX_USE_CXX11_ABI={}", torch.cxx11_abi));
    build
}
