//! Calibration perturbation (SPEC §10.7) and per-radar failure (SPEC §10.8) on a prepared
//! synthetic world: radar maps re-rasterised from `radar_points.bin`.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use depthsense_config::RadarInput;
use depthsense_data::radar_failure::RadarFailure;
use depthsense_data::{load_sample, LoadOptions, Rng};
use depthsense_dataset::Dataset;
use depthsense_eval::evaluate::{run_eval, EvalOptions};
use depthsense_experiments::perturb::{
    run_perturb, PerturbOptions, PERTURB_CSV, PERTURB_JSON, PERTURB_MD, PERTURB_PNG,
};
use depthsense_nuscenes::depth_png::{decode_value, encode_value};
use depthsense_nuscenes::geometry::to_frame;
use depthsense_prep::layout::IndexEntry;
use depthsense_prep::radar_points::{
    PerturbAxis, Perturbation, RadarPoints, SweepGroup, RADAR_POINTS_FILE,
};
use depthsense_prep::{prepare, PrepareOptions};
use depthsense_progress::Progress;
use depthsense_synth::{generate, SynthConfig, Weather};

use crate::common;

/// A synthetic world of 1 scene × 2 keyframes, prepared once for every test; a random tiny
/// network.
fn prepared_once() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static ONCE: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    ONCE.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("world");
        let cfg = SynthConfig {
            scenes: 1,
            keyframes_per_scene: 2,
            conditions: vec![(Weather::Day, 1.0)],
            ..SynthConfig::default()
        };
        generate(&root, &cfg, &Progress::hidden()).unwrap();
        let data = tmp.path().join("prepared");
        let opts = PrepareOptions {
            dataroot: root,
            version: cfg.version_name.clone(),
            out: data.clone(),
            lidar_sweeps: 0,
            jobs: 2,
            ..Default::default()
        };
        let s = prepare(&opts, &Progress::hidden()).unwrap();
        assert_eq!((s.prepared, s.failed.len()), (2, 0), "{:?}", s.failed);
        let ck = common::tiny_checkpoint(tmp.path(), (350, 800));
        (tmp, data, ck)
    })
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

/// This test's own copy of the prepared world and the evaluation options on it.
fn setup() -> (tempfile::TempDir, PathBuf, EvalOptions) {
    let (_, prepared, ck) = prepared_once();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("prepared");
    copy_dir(prepared, &data);
    let eo = EvalOptions {
        checkpoint: ck.clone(),
        data: data.clone(),
        split: "all".into(),
        device: "cpu".into(),
        jobs: 2,
        batch_size: 2,
        max_samples: Some(2),
        ..EvalOptions::default()
    };
    (tmp, data, eo)
}

fn with_failure(eo: &EvalOptions, f: RadarFailure) -> EvalOptions {
    EvalOptions {
        failure: f,
        ..eo.clone()
    }
}

fn perturb(axis: PerturbAxis, amount: f64) -> RadarFailure {
    RadarFailure {
        perturb: Some(Perturbation { axis, amount }),
        ..Default::default()
    }
}

fn raw_map(ds: &Dataset, e: &IndexEntry, failure: RadarFailure) -> Vec<f32> {
    let opts = LoadOptions {
        radar: RadarInput::RawHeight,
        failure,
        ..LoadOptions::default()
    };
    let s = load_sample(ds, e, &opts, &mut Rng::new(0)).unwrap();
    s.radar[..800 * 350].to_vec()
}

#[test]
fn zero_perturbation_is_the_unperturbed_eval_bit_for_bit() {
    let _torch = crate::torch_lock();
    let (tmp, _data, eo) = setup();
    let pb = Progress::hidden();
    let plain = run_eval(&eo, &pb).unwrap();
    // (every axis at 0 gives the very same points: radar_points unit tests)
    for axis in [PerturbAxis::Pitch, PerturbAxis::Z] {
        let zero = run_eval(&with_failure(&eo, perturb(axis, 0.0)), &pb).unwrap();
        assert_eq!(zero, plain, "{axis:?}");
    }

    // the experiment: baseline (yaw 0) = plain eval, every file written
    let out = tmp.path().join("perturb");
    let opts = PerturbOptions {
        rotate_deg: vec![5.0],
        translate_m: vec![0.5],
        axes: vec![PerturbAxis::Yaw],
    };
    let mp = depthsense_progress::Board::hidden();
    let r = run_perturb(&eo, &opts, &out, Some("cmd".into()), &mp).unwrap();
    assert_eq!(r.baseline.report, plain);
    assert_eq!(r.rows.len(), 1);
    assert_ne!(
        r.rows[0].report, plain,
        "a 5° yaw must change the result for the test to bite"
    );
    for f in [PERTURB_MD, PERTURB_CSV, PERTURB_JSON, PERTURB_PNG] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let md = std::fs::read_to_string(out.join(PERTURB_MD)).unwrap();
    assert!(
        md.contains("| none | 0 deg |") && md.contains("| yaw | 5 deg |"),
        "{md}"
    );
}

/// Replace a sample's radar points by one return on the optical axis, `depth_m` ahead of a
/// radar at `origin_cam`.
fn single_return(dir: &Path, origin_cam: [f32; 3], depth_m: f32) -> RadarPoints {
    let mut rp = RadarPoints::read_from_sample(dir).unwrap();
    rp.groups = vec![SweepGroup {
        channel: 0,
        sweep: 0,
        origin_cam,
        n_points: 1,
    }];
    rp.points_cam = vec![[0.0, 0.0, depth_m]];
    std::fs::write(dir.join(RADAR_POINTS_FILE), rp.encode()).unwrap();
    rp
}

#[test]
fn yaw_moves_an_optical_axis_return_as_the_pinhole_model_predicts() {
    let _torch = crate::torch_lock();
    let (_tmp, data, _eo) = setup();
    let ds = Dataset::open(&data).unwrap();
    let e = &ds.index.samples[0];
    let dir = ds.sample_dir(e);
    let rp = single_return(&dir, [0.0; 3], 30.0);
    let (fx, cx) = (rp.camera.fx, rp.camera.cx);
    for deg in [0.5f64, 1.0, 2.0, 5.0] {
        // pinhole: the return turns by δ about the camera's vertical axis → u = cx ± fx·tan δ
        let shift = fx * deg.to_radians().tan();
        let moved = rp.perturbed(&Perturbation {
            axis: PerturbAxis::Yaw,
            amount: deg,
        });
        let (u, _, _) = rp.camera.project(moved.points_cam[0]).unwrap();
        assert!(
            (u as f64 - (cx + shift)).abs() < 0.5,
            "{deg}°: u {u} vs {}",
            cx + shift
        );
        // through the loader (random sign per sample): the one raw pixel sits in the frame
        // column of cx + shift or cx − shift
        let map = raw_map(&ds, e, perturb(PerturbAxis::Yaw, deg));
        let hits: Vec<usize> = (0..map.len()).filter(|i| map[*i] > 0.0).collect();
        assert_eq!(hits.len(), 1, "{deg}°");
        let col = (hits[0] % 800) as f64;
        let want = [cx + shift, cx - shift].map(|u| (u / 2.0).floor());
        assert!(
            want.contains(&col),
            "{deg}°: column {col}, expected one of {want:?}"
        );
        assert_eq!(
            map[hits[0]],
            decode_value(encode_value(moved.points_cam[0][2]))
        );
    }
}

#[test]
fn dropping_radars_all_equals_radar_drop_one_and_one_radar_removes_exactly_its_points() {
    let _torch = crate::torch_lock();
    let (_tmp, data, eo) = setup();
    let pb = Progress::hidden();
    let full_drop = run_eval(
        &EvalOptions {
            radar_drop: 1.0,
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    let drop = |names: Vec<String>| RadarFailure {
        drop_radars: names,
        ..Default::default()
    };
    let all = run_eval(&with_failure(&eo, drop(vec!["all".into()])), &pb).unwrap();
    assert_eq!(all, full_drop);
    let ds = Dataset::open(&data).unwrap();
    let e = &ds.index.samples[1];
    let rp = RadarPoints::read_from_sample(&ds.sample_dir(e)).unwrap();
    let by_name = run_eval(&with_failure(&eo, drop(rp.channels.clone())), &pb).unwrap();
    assert_eq!(by_name, full_drop);

    // one radar of several: the map holds exactly the other radars' returns
    assert!(rp.channels.len() >= 2, "{:?}", rp.channels);
    let intact = raw_map(&ds, e, RadarFailure::default());
    for (ci, ch) in rp.channels.iter().enumerate() {
        let map = raw_map(&ds, e, drop(vec![ch.clone()]));
        let mut want = vec![0f32; 800 * 350];
        let mut own = 0;
        for (g, r) in rp.group_ranges() {
            for p in &rp.points_cam[r] {
                let Some((x, y)) = rp.camera.project(*p).and_then(|(u, v, _)| to_frame(u, v))
                else {
                    continue;
                };
                if g.channel as usize == ci {
                    own += 1;
                    continue;
                }
                let w = &mut want[y as usize * 800 + x as usize];
                let d = decode_value(encode_value(p[2]));
                if *w == 0.0 || d < *w {
                    *w = d;
                }
            }
        }
        assert_eq!(map, want, "dropping {ch}");
        if own > 0 {
            assert_ne!(map, intact, "dropping {ch} ({own} returns in the image)");
        }
    }
}

#[test]
fn samples_without_radar_points_ask_for_a_new_prepare() {
    let _torch = crate::torch_lock();
    let (_tmp, data, eo) = setup();
    let ds = Dataset::open(&data).unwrap();
    for e in &ds.index.samples {
        std::fs::remove_file(ds.sample_dir(e).join(RADAR_POINTS_FILE)).unwrap();
    }
    let pb = Progress::hidden();
    // everything else still works
    run_eval(&eo, &pb).unwrap();
    let err = run_eval(&with_failure(&eo, perturb(PerturbAxis::Yaw, 1.0)), &pb).unwrap_err();
    assert!(
        err.to_string().contains("re-run depthsense prepare"),
        "{err}"
    );
}

/// The oracle radar (`train --radar-oracle`): every raw-map return holds the training
/// target's depth at its pixel or at a valid target pixel within 3 px; there are no more
/// returns than the sensor's; the oracle is refused with a sensor failure.
#[test]
fn oracle_radar_takes_the_lidar_target_depth_near_each_return() {
    let _torch = crate::torch_lock();
    let (_tmp, data, _eo) = setup();
    let ds = Dataset::open(&data).unwrap();
    let (w, h) = (800usize, 350usize);
    let mut checked = 0;
    for e in &ds.index.samples {
        let plain = raw_map(&ds, e, RadarFailure::default());
        let opts = LoadOptions {
            radar: RadarInput::RawHeight,
            radar_oracle: true,
            ..LoadOptions::default()
        };
        let s = load_sample(&ds, e, &opts, &mut Rng::new(0)).unwrap();
        let (raw, height) = s.radar.split_at(w * h);
        let target = &s.target_m;
        let valid = |p: &[f32]| p.iter().filter(|d| **d > 0.0).count();
        assert!(
            valid(raw) > 0 && valid(raw) <= valid(&plain),
            "{}",
            e.sample_token
        );
        assert_ne!(raw, &plain[..], "the oracle must change the maps");
        for (i, &d) in raw.iter().enumerate().filter(|(_, d)| **d > 0.0) {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let near = (-3i64..=3)
                .flat_map(|dy| (-3i64..=3).map(move |dx| (dx, dy)))
                .filter(|(dx, dy)| dx * dx + dy * dy <= 9)
                .filter_map(|(dx, dy)| {
                    let (xx, yy) = (x + dx, y + dy);
                    ((0..w as i64).contains(&xx) && (0..h as i64).contains(&yy))
                        .then(|| target[yy as usize * w + xx as usize])
                })
                .any(|t| t == d);
            assert!(
                near,
                "pixel ({x}, {y}) = {d} m is no target depth within 3 px"
            );
            assert!(height[i] > 0.0, "a return's strip covers its own pixel");
            checked += 1;
        }
        let refused = LoadOptions {
            failure: RadarFailure {
                drop_beyond_m: Some(30.0),
                ..Default::default()
            },
            ..opts
        };
        let err = load_sample(&ds, e, &refused, &mut Rng::new(0)).unwrap_err();
        assert!(err.to_string().contains("oracle"), "{err}");
    }
    assert!(checked > 10, "{checked} returns checked");
}
