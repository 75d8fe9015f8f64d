//! `depthsense model-info`: parameters per module and multiply-adds at 350x800.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use depthsense_model::{report, DepthNet, ModelConfig};

#[derive(clap::Args)]
pub struct Args {
    /// Network: a preset (paper, released, tiny), a model-config JSON file, or a depthsense
    /// checkpoint (.safetensors; its stored config is used).
    #[arg(long, default_value = "paper")]
    config: String,
    /// Override one config option, `key=value`, repeatable (e.g. `--set backbone=50
    /// --set fusion=early --set attention=off --set head=l1 --set radar-channels=7`). Keys:
    /// backbone (18|34|50|101), width, fusion (late|early|none), attention (on|off),
    /// head (ordinal|l1|l2), radar-channels (1|7), radar-branch (basic|bottleneck),
    /// radar-width, radar-out-channels, decoder (topdown|released), decoder-channels,
    /// stem (torchvision|deep), head-channels, head-pre-dropout, dropout, bins, alpha, beta,
    /// decode-offset (m), align-corners (on|off), out-height, out-width.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Input height the multiply-adds are counted at.
    #[arg(long, default_value_t = 350)]
    height: i64,
    /// Input width the multiply-adds are counted at.
    #[arg(long, default_value_t = 800)]
    width: i64,
    /// Also write the report (and the resolved config) as JSON to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Print the resolved config as JSON before the table.
    #[arg(long)]
    print_config: bool,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let cfg = ModelConfig::resolve(&args.config)?.with_options(&args.set)?;
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let net = DepthNet::new(&vs.root(), &cfg)?;
    let rep = report::model_report(&vs, &net, args.height, args.width);
    if args.print_config {
        println!("{}", serde_json::to_string_pretty(&cfg)?);
    }
    println!(
        "config `{}`: ResNet-{} ({} stem, width {}), {:?} decoder, fusion {:?}, attention {}, head {:?} (K = {}), radar channels {}",
        cfg.name,
        cfg.backbone_depth,
        format!("{:?}", cfg.stem).to_lowercase(),
        cfg.backbone_width,
        cfg.decoder,
        cfg.fusion,
        if cfg.attention { "on" } else { "off" },
        cfg.head,
        cfg.sid.bins,
        cfg.radar_channels
    );
    println!("{rep}");
    if let Some(path) = &args.json {
        let v = serde_json::json!({"config": cfg, "report": rep});
        let text = serde_json::to_string_pretty(&v)?;
        depthsense_model::checkpoint::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
