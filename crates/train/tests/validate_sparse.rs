//! Validation decodes the depth only where the scorer reads it (`validate_net`): its report
//! equals `evaluate_net`'s (every pixel decoded) up to the float rounding of the bilinear
//! interpolation, for the ordinal and a regression head, with and without upsampling.

use depthsense_config::{HeadKind, ModelConfig};
use depthsense_data::LoadOptions;
use depthsense_dataset::{partition, Dataset};
use depthsense_infer::run::{evaluate_net, validate_net};
use depthsense_metrics::Report;
use depthsense_model::DepthNet;
use depthsense_progress::Progress;

fn report_rmse(r: &Report) -> Vec<(String, f64, f64, u64)> {
    r.rows
        .iter()
        .map(|row| {
            (
                format!("{} {} {}", row.condition, row.region, row.cap_m),
                row.metrics.rmse,
                row.metrics.delta1,
                row.n_pixels,
            )
        })
        .collect()
}

#[test]
fn sparse_validation_equals_the_dense_evaluation() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 6, 3, 128, 64, 4).unwrap();
    let ds = Dataset::open(&data).unwrap();
    let part = partition(&ds, 5).unwrap();
    let samples = [part.val.clone(), part.test.clone()].concat();
    for (head, downscale) in [
        (HeadKind::Ordinal, 1),
        (HeadKind::Ordinal, 2),
        (HeadKind::L1, 2),
    ] {
        tch::manual_seed(3);
        let mut cfg = ModelConfig::tiny()
            .with_options(&[format!("input-downscale={downscale}")])
            .unwrap();
        cfg.head = head;
        (cfg.out_height, cfg.out_width) = (64, 128);
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let net = DepthNet::new(&vs.root(), &cfg).unwrap();
        let load = LoadOptions::default();
        let args = (&Default::default(), 4, 2, tch::Device::Cpu);
        let dense = evaluate_net(
            &net,
            &ds,
            &samples,
            &load,
            args.0,
            args.1,
            args.2,
            args.3,
            &Progress::hidden(),
            |_, _| Ok(()),
        )
        .unwrap();
        let sparse = validate_net(
            &net,
            &ds,
            &samples,
            &load,
            args.0,
            args.1,
            args.2,
            args.3,
            &Progress::hidden(),
        )
        .unwrap();
        let (d, s) = (report_rmse(&dense), report_rmse(&sparse));
        assert_eq!(d.len(), s.len());
        assert!(!d.is_empty());
        for (a, b) in d.iter().zip(&s) {
            assert_eq!((&a.0, a.3), (&b.0, b.3), "the same rows and pixels");
            let tol = 1e-3 * a.1.abs().max(1.0);
            assert!(
                (a.1 - b.1).abs() <= tol && (a.2 - b.2).abs() <= 1e-3,
                "{head:?}: {a:?} vs {b:?}"
            );
        }
    }
}
