//! `depthsense experiment cost` (SPEC §10.9): parameters, multiply-adds and inference time
//! of every preset × fusion variant on the current device, next to the paper's figures
//! (0.118 s per batch of 3 at 350x800 on an RTX 3090; DORN 0.221 s).
//!
//! Parameters: every trainable tensor of the VarStore (BN running statistics excluded).
//! MACs: `depthsense_model::report::model_report`, counted analytically per convolution
//! from the layer geometry for one image of H×W (bilinear upsampling, pooling and the
//! decode are not counted). Time: `forward_t` + decode of a random batch under `no_grad`
//! in evaluation mode, `warmup` untimed passes then `repeats` timed ones (CUDA synchronised);
//! mean and minimum reported. Random weights (time does not depend on their values).

use std::path::Path;
use std::time::Instant;

use crate::ExperimentError;
use depthsense_config::ModelConfig;
use depthsense_infer::NetError;
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{csv_field, csv_row, Align, MdTable, MISSING};
use depthsense_model::{report::model_report, DepthNet};
use serde::{Deserialize, Serialize};
use tch::{nn::VarStore, Device, Kind, Tensor};

use super::Machine;
use depthsense_config::variant::Variant;

/// The paper's inference time, seconds per batch of 3 at 350x800 on an RTX 3090.
pub const PAPER_S_PER_BATCH3: f64 = 0.118;
/// DORN's, as the paper reports it.
pub const DORN_S_PER_BATCH3: f64 = 0.221;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CostOptions {
    pub presets: Vec<String>,
    pub variants: Vec<Variant>,
    pub batch: i64,
    pub height: i64,
    pub width: i64,
    pub warmup: usize,
    pub repeats: usize,
    pub device: String,
    pub command_line: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CostRow {
    pub preset: String,
    pub variant: String,
    pub params: i64,
    pub macs_per_image: u64,
    pub mean_ms_per_batch: f64,
    pub min_ms_per_batch: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CostResult {
    pub options: CostOptions,
    pub machine: Machine,
    pub threads: i32,
    pub rows: Vec<CostRow>,
}

pub const MD_FILE: &str = "cost.md";
pub const CSV_FILE: &str = "cost.csv";
pub const JSON_FILE: &str = "cost.json";

fn sync(d: Device) {
    if let Device::Cuda(i) = d {
        tch::Cuda::synchronize(i as i64);
    }
}

/// Cost of one model config.
pub fn measure(
    cfg: &ModelConfig,
    o: &CostOptions,
    device: Device,
) -> Result<CostRow, ExperimentError> {
    let mut cfg = cfg.clone();
    cfg.out_height = o.height;
    cfg.out_width = o.width;
    cfg.validate()?;
    let vs = VarStore::new(device);
    let net = DepthNet::new(&vs.root(), &cfg)?;
    let rep = model_report(&vs, &net, o.height, o.width);
    let image = Tensor::randn([o.batch, 3, o.height, o.width], (Kind::Float, device));
    let radar = Tensor::rand(
        [o.batch, cfg.radar_channels.max(1), o.height, o.width],
        (Kind::Float, device),
    ) * 80.0;
    let mut times = vec![];
    for i in 0..o.warmup + o.repeats.max(1) {
        sync(device);
        let t = Instant::now();
        let d = tch::no_grad(|| net.decode(&net.forward_t(&image, &radar, false)));
        let _ = d.size();
        sync(device);
        if i >= o.warmup {
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    Ok(CostRow {
        preset: cfg.name.clone(),
        variant: String::new(),
        params: rep.total_params,
        macs_per_image: rep.total_macs,
        mean_ms_per_batch: times.iter().sum::<f64>() / times.len() as f64,
        min_ms_per_batch: times.iter().copied().fold(f64::INFINITY, f64::min),
    })
}

/// Every preset × variant; writes OUT/cost.{md,csv,json}.
pub fn run_cost(
    o: &CostOptions,
    out: &Path,
    progress: &depthsense_progress::Progress,
) -> Result<CostResult, ExperimentError> {
    let device = depthsense_model::device::parse_device(&o.device)?;
    progress.set_length((o.presets.len() * o.variants.len()) as u64);
    progress.println(format!(
        "{} presets × {} variants on {}",
        o.presets.len(),
        o.variants.len(),
        depthsense_model::device::describe(device)
    ));
    let mut rows = vec![];
    for p in &o.presets {
        let base = super::ablation::base_model(p)?;
        for v in &o.variants {
            progress.set_message(format!("{p} {}", v.name()));
            let mut c = base.clone();
            v.apply(&mut c);
            let mut row = measure(&c, o, device)?;
            row.preset = p.clone();
            row.variant = v.name().to_string();
            rows.push(row);
            progress.inc(1);
        }
    }
    let r = CostResult {
        options: o.clone(),
        machine: Machine::describe(device),
        threads: tch::get_num_threads(),
        rows,
    };
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    super::save_record(&out.join(JSON_FILE), &out.join(MD_FILE), &r, &document(&r))?;
    super::save(&out.join(CSV_FILE), csv(&r).as_bytes())?;
    Ok(r)
}

/// The cost table with its setup (cost.md, and the report's section).
pub fn document(r: &CostResult) -> Doc {
    let o = &r.options;
    let mut doc = Doc::new();
    doc.heading(1, "Parameters, MACs and inference time (SPEC §10.9)");
    doc.paragraph(format!(
        "Batch {} at {}x{} (H×W), forward + decode, no_grad, eval mode; {} warm-up + {} timed \
         passes on {} ({} torch threads). MACs: convolutions per image, analytic.",
        o.batch,
        o.height,
        o.width,
        o.warmup,
        o.repeats,
        r.machine.line(),
        r.threads
    ));
    let mut t = MdTable::new(&[
        ("preset", Align::Left),
        ("variant", Align::Left),
        ("params (M)", Align::Right),
        ("GMACs / image", Align::Right),
        ("ms / batch (mean)", Align::Right),
        ("ms / batch (min)", Align::Right),
    ]);
    for x in &r.rows {
        t.row(&[
            x.preset.clone(),
            x.variant.clone(),
            format!("{:.2}", x.params as f64 / 1e6),
            format!("{:.1}", x.macs_per_image as f64 / 1e9),
            format!("{:.0}", x.mean_ms_per_batch),
            format!("{:.0}", x.min_ms_per_batch),
        ]);
    }
    t.row(&[
        "paper (RTX 3090)",
        "late-sam",
        "68.40 (released)",
        MISSING,
        &format!("{:.0}", PAPER_S_PER_BATCH3 * 1e3),
        MISSING,
    ]);
    t.row(&[
        "DORN (paper's figure)",
        MISSING,
        MISSING,
        MISSING,
        &format!("{:.0}", DORN_S_PER_BATCH3 * 1e3),
        MISSING,
    ]);
    doc.table(t).command(o.command_line.as_deref());
    doc
}

fn csv(r: &CostResult) -> String {
    let mut s =
        String::from("preset,variant,params,macs_per_image,mean_ms_per_batch,min_ms_per_batch\n");
    for x in &r.rows {
        s.push_str(&csv_row(&[
            csv_field(&x.preset),
            csv_field(&x.variant),
            x.params.to_string(),
            x.macs_per_image.to_string(),
            format!("{:.3}", x.mean_ms_per_batch),
            format!("{:.3}", x.min_ms_per_batch),
        ]));
    }
    s.push_str(&format!(
        "paper-rtx3090,late-sam,,,{:.3},\ndorn-paper,,,,{:.3},\n",
        PAPER_S_PER_BATCH3 * 1e3,
        DORN_S_PER_BATCH3 * 1e3
    ));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cost_rows_count_params_and_macs() {
        let o = CostOptions {
            presets: vec!["tiny".into()],
            variants: vec![Variant::Rgb, Variant::LateSam],
            batch: 1,
            height: 64,
            width: 128,
            warmup: 0,
            repeats: 1,
            device: "cpu".into(),
            command_line: None,
        };
        let dir = tempfile::tempdir().unwrap();
        let r = run_cost(&o, dir.path(), &depthsense_progress::Progress::hidden()).unwrap();
        assert_eq!(r.rows.len(), 2);
        // the radar branch adds parameters and MACs
        assert!(r.rows[1].params > r.rows[0].params);
        assert!(r.rows[1].macs_per_image > r.rows[0].macs_per_image);
        assert!(r.rows.iter().all(|x| x.mean_ms_per_batch > 0.0));
        let md = std::fs::read_to_string(dir.path().join(MD_FILE)).unwrap();
        assert!(
            md.contains("| tiny | late-sam |") && md.contains("| 118 |"),
            "{md}"
        );
    }
}
