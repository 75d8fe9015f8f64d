//! Generate a synthetic world without the full CLI: `synth_gen OUT [SCENES] [KEYFRAMES] [SEED]`.
fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.get(1).map(|s| s.as_str()) == Some("--profile") {
        println!("{:?}", depthsense_synth::profile_stages(0, 4).unwrap());
        return;
    }
    let out = std::path::PathBuf::from(a.get(1).cloned().unwrap_or_else(|| "/tmp/synth".into()));
    let mut cfg = depthsense_synth::SynthConfig::default();
    if let Some(s) = a.get(2) {
        cfg.scenes = s.parse().unwrap_or(cfg.scenes);
    }
    if let Some(s) = a.get(3) {
        cfg.keyframes_per_scene = s.parse().unwrap_or(cfg.keyframes_per_scene);
    }
    if let Some(s) = a.get(4) {
        cfg.seed = s.parse().unwrap_or(0);
    }
    match depthsense_synth::generate(&out, &cfg, &depthsense_progress::Progress::hidden()) {
        Ok(s) => {
            println!("{s:?}");
            if let Ok(sheet) = std::env::var("SHEET") {
                depthsense_synth::contact_sheet(
                    &out,
                    &cfg.version_name,
                    std::path::Path::new(&sheet),
                )
                .unwrap();
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
