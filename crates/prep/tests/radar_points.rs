//! `radar_points.bin` (issue 12, SPEC §10.7/§10.8): `prepare` stores the radar returns behind
//! its radar maps; re-rasterising them unchanged gives the stored PNGs byte for byte, and
//! leaving one radar out removes exactly that radar's returns.

use depthsense_nuscenes::depth_png::{encode_png_fast, DepthMap};
use depthsense_nuscenes::geometry::to_frame;
use depthsense_prep::layout::{PreparedIndex, RADAR_HEIGHT_FILE, RADAR_RAW_FILE};
use depthsense_prep::radar_points::{RadarPoints, RADAR_POINTS_FILE};
use depthsense_prep::{prepare, PrepareOptions};
use depthsense_progress::Progress;
use depthsense_synth::{generate, SynthConfig, Weather};

fn png(depth_m: &[f32]) -> Vec<u8> {
    encode_png_fast(&DepthMap {
        width: 800,
        height: 350,
        depth_m: depth_m.to_vec(),
    })
    .unwrap()
}

#[test]
fn stored_points_reproduce_the_radar_maps_and_drop_one_radar_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("world");
    let cfg = SynthConfig {
        scenes: 1,
        keyframes_per_scene: 1,
        conditions: vec![(Weather::Day, 1.0)],
        ..SynthConfig::default()
    };
    generate(&root, &cfg, &Progress::hidden()).unwrap();
    let out = tmp.path().join("prepared");
    let opts = PrepareOptions {
        dataroot: root,
        version: cfg.version_name.clone(),
        out: out.clone(),
        lidar_sweeps: 0,
        jobs: 1,
        ..Default::default()
    };
    let s = prepare(&opts, &Progress::hidden()).unwrap();
    assert_eq!((s.prepared, s.failed.len()), (1, 0), "{:?}", s.failed);
    let idx: PreparedIndex =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    let dir = out.join(&idx.samples[0].dir);
    let rp = RadarPoints::read_from_sample(&dir).unwrap();
    let size = std::fs::metadata(dir.join(RADAR_POINTS_FILE))
        .unwrap()
        .len();
    eprintln!(
        "{} channels, {} groups, {} points, {size} bytes",
        rp.channels.len(),
        rp.groups.len(),
        rp.points_cam.len()
    );
    assert!(rp.channels.len() >= 2, "{:?}", rp.channels);

    // identity: byte-identical PNGs
    let maps = rp.rasterise();
    assert!(maps.raw.valid() > 0);
    assert_eq!(
        png(&maps.raw.depth_m),
        std::fs::read(dir.join(RADAR_RAW_FILE)).unwrap()
    );
    assert_eq!(
        png(&maps.height.depth_m),
        std::fs::read(dir.join(RADAR_HEIGHT_FILE)).unwrap()
    );

    // drop the channel with the most in-image returns; the rest, projected by hand
    let in_image = |ch: usize| {
        rp.group_ranges()
            .filter(|(g, _)| g.channel as usize == ch)
            .flat_map(|(_, r)| rp.points_cam[r].to_vec())
            .filter(|p| rp.camera.project(*p).is_some())
            .count()
    };
    let drop = (0..rp.channels.len()).max_by_key(|c| in_image(*c)).unwrap();
    assert!(in_image(drop) > 0);
    let name = rp.channels[drop].clone();
    let kept = rp.without_channels(|c| c == name).rasterise();
    let mut want = vec![0f32; 800 * 350];
    for (g, r) in rp.group_ranges() {
        if g.channel as usize == drop {
            continue;
        }
        for p in &rp.points_cam[r] {
            if let Some((u, v, d)) = rp.camera.project(*p) {
                if let Some((x, y)) = to_frame(u, v) {
                    let w = &mut want[y as usize * 800 + x as usize];
                    if *w == 0.0 || d < *w {
                        *w = d;
                    }
                }
            }
        }
    }
    assert_eq!(kept.raw.depth_m, want, "dropping {name}");
    assert_ne!(kept.raw.depth_m, maps.raw.depth_m);
}
