//! `depthsense model-info`: parameters per module and multiply-adds at 350x800. (the network side; its flags: `depthsense_cli::cmd::model_info`).

use anyhow::Context;
use depthsense_cli::cmd::model_info::Args;
use depthsense_model::{report, DepthNet};
use std::process::ExitCode;

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let cfg = depthsense_checkpoint::config::resolve(&args.config)?.with_options(&args.set)?;
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
        depthsense_checkpoint::files::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
