//! Parameter and multiply-add report (`depthsense model-info`).

use std::collections::BTreeMap;

use serde::Serialize;
use tch::nn::VarStore;

use crate::DepthNet;

/// One row of the report: a module (dotted prefix) with its trainable parameters and
/// multiply-adds per image.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ModuleRow {
    /// Module prefix (`rgb.layer3`, `radar`, …).
    pub module: String,
    /// Trainable parameters (conv/linear weights and biases, BN affine).
    pub params: i64,
    /// Multiply-adds of its convolutions for one image.
    pub macs: u64,
}

/// The whole report.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ModelReport {
    /// Input height the multiply-adds were counted at.
    pub height: i64,
    /// Input width.
    pub width: i64,
    /// Rows at depth 1 (`rgb`, `decoder`, `radar`, `attention`, `head`).
    pub modules: Vec<ModuleRow>,
    /// Rows at depth 2 (`rgb.layer1`, `decoder.fpn`, …).
    pub submodules: Vec<ModuleRow>,
    /// Total trainable parameters.
    pub total_params: i64,
    /// Total multiply-adds per image.
    pub total_macs: u64,
    /// Output (head) resolution, height × width.
    pub head_hw: (i64, i64),
}

fn prefix(name: &str, depth: usize) -> String {
    let parts: Vec<&str> = name.split('.').collect();
    // Drop the trailing `weight`/`bias` and, inside blocks, keep `layerN` as the group.
    let n = depth.min(parts.len().saturating_sub(1)).max(1);
    parts[..n].join(".")
}

/// Trainable parameters per module.
pub fn param_counts(vs: &VarStore, depth: usize) -> BTreeMap<String, i64> {
    let mut m = BTreeMap::new();
    for (name, t) in vs.variables() {
        if !t.requires_grad() {
            continue; // BN running statistics
        }
        *m.entry(prefix(&name, depth)).or_insert(0) += t.numel() as i64;
    }
    m
}

/// Total trainable parameters of a var store.
pub fn total_params(vs: &VarStore) -> i64 {
    vs.trainable_variables()
        .iter()
        .map(|t| t.numel() as i64)
        .sum()
}

/// Builds the report for `net` (variables in `vs`) at `height`×`width`.
pub fn model_report(vs: &VarStore, net: &DepthNet, height: i64, width: i64) -> ModelReport {
    let rows = net.mac_rows(height, width);
    let mut rows_out = Vec::new();
    for depth in [1usize, 2] {
        let params = param_counts(vs, depth);
        let mut macs: BTreeMap<String, u64> = BTreeMap::new();
        let mut order: Vec<String> = Vec::new();
        for (name, m) in &rows {
            // conv rows are named like variables minus `.weight`
            let p = prefix(&format!("{name}.weight"), depth);
            if !macs.contains_key(&p) {
                order.push(p.clone());
            }
            *macs.entry(p).or_insert(0) += m;
        }
        for p in params.keys() {
            if !macs.contains_key(p) {
                order.push(p.clone());
                macs.insert(p.clone(), 0);
            }
        }
        rows_out.push(
            order
                .into_iter()
                .map(|p| ModuleRow {
                    params: params.get(&p).copied().unwrap_or(0),
                    macs: macs[&p],
                    module: p,
                })
                .collect::<Vec<_>>(),
        );
    }
    let submodules = rows_out.pop().unwrap_or_default();
    let modules = rows_out.pop().unwrap_or_default();
    let head_hw = net.head_resolution(height, width);
    ModelReport {
        height,
        width,
        total_params: total_params(vs),
        total_macs: rows.iter().map(|r| r.1).sum(),
        modules,
        submodules,
        head_hw,
    }
}

fn human(n: f64) -> String {
    if n >= 1e9 {
        format!("{:.2} G", n / 1e9)
    } else if n >= 1e6 {
        format!("{:.2} M", n / 1e6)
    } else if n >= 1e3 {
        format!("{:.1} k", n / 1e3)
    } else {
        format!("{n}")
    }
}

impl std::fmt::Display for ModelReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{:<28} {:>14} {:>10} {:>14}",
            "module", "parameters", "", "MACs/image"
        )?;
        for r in &self.modules {
            writeln!(
                f,
                "{:<28} {:>14} {:>10} {:>14}",
                r.module,
                r.params,
                human(r.params as f64),
                human(r.macs as f64)
            )?;
            for s in self
                .submodules
                .iter()
                .filter(|s| s.module.starts_with(&format!("{}.", r.module)))
            {
                writeln!(
                    f,
                    "  {:<26} {:>14} {:>10} {:>14}",
                    s.module,
                    s.params,
                    human(s.params as f64),
                    human(s.macs as f64)
                )?;
            }
        }
        writeln!(
            f,
            "{:<28} {:>14} {:>10} {:>14}",
            "total",
            self.total_params,
            human(self.total_params as f64),
            human(self.total_macs as f64)
        )?;
        write!(
            f,
            "input {}x{}, head output {}x{}; MACs = conv multiply-adds (×2 for FLOPs), upsampling and loss not counted",
            self.height, self.width, self.head_hw.0, self.head_hw.1
        )
    }
}
