//! Time `NuScenes::load` on a version folder: `load_tables DATAROOT VERSION`, or generate
//! trainval-sized tables first with `load_tables --generate DIR [SCALE]`.

use std::path::Path;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.first().map(String::as_str) == Some("--generate") {
        let scale = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1.0);
        let n =
            depthsense_prep::bench::generate_trainval_tables(Path::new(&a[1]), "v1.0-gen", scale)?;
        println!("wrote {n} bytes");
        return Ok(());
    }
    depthsense_prep::bench::reset_peak_rss();
    let t = Instant::now();
    let nu = depthsense_nuscenes::NuScenes::load(Path::new(&a[0]), &a[1])?;
    println!(
        "load {:.2} s, peak RSS {:.0} MB, {:?}",
        t.elapsed().as_secs_f64(),
        depthsense_prep::bench::peak_rss_bytes().unwrap_or(0) as f64 / 1e6,
        nu.row_counts()
    );
    Ok(())
}
