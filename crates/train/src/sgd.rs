//! SGD with momentum and weight decay over a VarStore's trainable variables (SPEC §8), with
//! state that can be saved and restored — tch's `nn::Optimizer` cannot save its momentum
//! buffers, and an exact `--resume` needs them.
//!
//! Update (PyTorch `torch.optim.SGD` semantics, dampening 0, no Nesterov):
//! g ← ∇p + wd·p;  b ← μ·b + g (b ← g on the first step);  p ← p − lr·b.

use std::collections::BTreeMap;
use std::path::Path;

use tch::{nn::VarStore, Kind, Tensor};

use crate::optim::Optimizer;
use crate::optim_state::{self, bad_state, Trainable};
use depthsense_infer::NetError;

/// The optimiser: named trainable variables and one momentum buffer each.
pub struct Sgd {
    vars: Trainable,
    buffers: BTreeMap<String, Tensor>,
    pub momentum: f64,
    pub weight_decay: f64,
}

impl Sgd {
    pub fn new(vs: &VarStore, momentum: f64, weight_decay: f64) -> Self {
        Self {
            vars: Trainable::new(vs),
            buffers: BTreeMap::new(),
            momentum,
            weight_decay,
        }
    }

    /// Number of trainable tensors.
    pub fn len(&self) -> usize {
        self.vars.vars.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vars.vars.is_empty()
    }
}

impl Optimizer for Sgd {
    fn zero_grad(&mut self) {
        self.vars.zero_grad();
    }

    /// One update with learning rate `lr`. Variables without a gradient are left alone.
    fn step(&mut self, lr: f64) {
        tch::no_grad(|| {
            for (name, p) in self.vars.vars.iter_mut() {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let g = if self.weight_decay != 0.0 {
                    &g + &*p * self.weight_decay
                } else {
                    g
                };
                let buf = match self.buffers.get_mut(name) {
                    Some(b) => {
                        let _ = b.g_mul_scalar_(self.momentum);
                        let _ = b.g_add_(&g);
                        b.shallow_clone()
                    }
                    None => {
                        let b = g.detach().copy();
                        self.buffers.insert(name.clone(), b.shallow_clone());
                        b
                    }
                };
                let _ = p.g_sub_(&(buf * lr));
            }
        });
    }

    /// Write the momentum buffers (safetensors, atomically) with the iteration they belong to.
    fn save(&self, path: &Path, iteration: u64) -> Result<(), NetError> {
        let mut named: Vec<(String, Tensor)> = self
            .buffers
            .iter()
            .map(|(k, v)| (format!("momentum.{k}"), v.shallow_clone()))
            .collect();
        named.push((
            "__iteration".into(),
            Tensor::from_slice(&[iteration as i64]).to_kind(Kind::Int64),
        ));
        optim_state::write_atomic(path, named)
    }

    /// Restore buffers saved by [`Optimizer::save`]; returns the iteration stored with them.
    fn load(&mut self, path: &Path) -> Result<u64, NetError> {
        let named = optim_state::read(path)?;
        let device = self.vars.device();
        let known = self.vars.sizes();
        let mut iteration = None;
        let mut buffers = BTreeMap::new();
        for (name, t) in named {
            if name == "__iteration" {
                iteration = Some(t.int64_value(&[0]) as u64);
                continue;
            }
            let Some(var_name) = name.strip_prefix("momentum.") else {
                return Err(bad_state(path, format!("unexpected tensor {name}")));
            };
            let Some(size) = known.get(var_name) else {
                return Err(bad_state(
                    path,
                    format!("momentum for unknown variable {var_name}"),
                ));
            };
            if *size != t.size() {
                return Err(bad_state(
                    path,
                    format!("momentum {var_name}: network {size:?}, file {:?}", t.size()),
                ));
            }
            buffers.insert(var_name.to_string(), t.to_device(device));
        }
        self.buffers = buffers;
        iteration.ok_or_else(|| bad_state(path, "no __iteration record".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::{self, Module};

    #[test]
    fn matches_hand_computed_momentum_sgd() {
        // p = 1, loss = p² → g = 2p. wd = 0.1, μ = 0.9, lr = 0.1.
        // step 1: g = 2 + 0.1 = 2.1, b = 2.1, p = 1 − 0.21 = 0.79
        // step 2: g = 1.58 + 0.079 = 1.659, b = 0.9·2.1 + 1.659 = 3.549, p = 0.79 − 0.3549 = 0.4351
        let vs = VarStore::new(tch::Device::Cpu);
        let p = vs.root().var("p", &[1], nn::Init::Const(1.0));
        let mut opt = Sgd::new(&vs, 0.9, 0.1);
        for _ in 0..2 {
            opt.zero_grad();
            let loss = (&p * &p).sum(Kind::Float);
            loss.backward();
            opt.step(0.1);
        }
        let v = p.double_value(&[0]);
        assert!((v - 0.4351).abs() < 1e-6, "{v}");
    }

    #[test]
    fn save_load_roundtrip_continues_identically() {
        let run = |split: Option<usize>, dir: &Path| -> Vec<f64> {
            tch::manual_seed(3);
            let vs = VarStore::new(tch::Device::Cpu);
            let mut lin = nn::linear(vs.root(), 4, 1, Default::default());
            // Fixed weights: `manual_seed` is process-wide and parallel tests draw from the
            // same generator, so a seeded random init is not reproducible here.
            tch::no_grad(|| {
                let w = Tensor::from_slice(&[0.1f32, -0.2, 0.3, 0.05]).view([1, 4]);
                lin.ws.copy_(&w);
                if let Some(b) = lin.bs.as_mut() {
                    b.copy_(&Tensor::from_slice(&[0.2f32]));
                }
            });
            let x = Tensor::arange(8, (Kind::Float, tch::Device::Cpu)).view([2, 4]) / 8.0;
            let mut opt = Sgd::new(&vs, 0.9, 1e-4);
            let mut out = vec![];
            for i in 0..6 {
                if Some(i) == split {
                    opt.save(&dir.join("o.safetensors"), i as u64).unwrap();
                    let mut fresh = Sgd::new(&vs, 0.9, 1e-4);
                    assert_eq!(fresh.load(&dir.join("o.safetensors")).unwrap(), i as u64);
                    opt = fresh;
                }
                opt.zero_grad();
                let loss = lin.forward(&x).pow_tensor_scalar(2).mean(Kind::Float);
                out.push(loss.double_value(&[]));
                loss.backward();
                opt.step(0.05);
            }
            out
        };
        let dir = tempfile::tempdir().unwrap();
        let a = run(None, dir.path());
        let b = run(Some(3), dir.path());
        assert_eq!(a, b);
        assert!(a[5] < a[0]);
    }
}
