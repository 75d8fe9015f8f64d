//! Fixed-shape inference through a CUDA graph (issue 44): the forward (and decode) of a batch
//! captured once on the GPU and replayed with one launch instead of the several hundred kernel
//! launches of libtorch's eager mode ([`depthsense_torch_ext::cuda_graph`]). A batch of another
//! shape, an input on the CPU, reduced precision or a build without CUDA graphs runs eagerly and
//! says why — once per reason — never an error.

use tch::{Device, Tensor};

use depthsense_torch_ext::cuda_graph::{self, CudaGraph};

/// Whether this build has CUDA graphs (the feature `cuda-graphs`).
pub fn built() -> bool {
    cuda_graph::built()
}

/// The captured graph and its static tensors: inputs copied in before every replay, and the
/// output every replay rewrites.
struct Captured {
    image: Tensor,
    radar: Tensor,
    out: Tensor,
    graph: CudaGraph,
}

/// How a [`GraphedForward::run`] ran.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ran {
    /// Captured on this call, then replayed.
    Captured,
    /// Replayed.
    Replayed,
    /// Run eagerly, for this reason.
    Eager(String),
}

/// One fixed-shape CUDA graph of a network's inference, captured on the first CUDA batch.
#[derive(Default)]
pub struct GraphedForward {
    captured: Option<Captured>,
    /// The reasons already said (each is said once).
    said: Vec<String>,
    /// Capture failed: eager from then on.
    failed: bool,
    /// How the last [`GraphedForward::run`] ran.
    last: Option<Ran>,
}

impl GraphedForward {
    pub fn new() -> Self {
        Self::default()
    }

    /// `f(image, radar)` — a forward and decode that does not synchronise with the host — on
    /// `image` `[B,3,H,W]` and `radar` `[B,C,H,W]`: captured on the first CUDA call (after one
    /// eager warm-up run, which also autotunes cuDNN), replayed for inputs of the same shapes.
    /// Returns a copy of the output and a line to print when the way it ran changed
    /// (`None` otherwise).
    pub fn run(
        &mut self,
        image: &Tensor,
        radar: &Tensor,
        f: impl Fn(&Tensor, &Tensor) -> Tensor,
    ) -> (Tensor, Option<String>) {
        let (out, ran, line) = match self.try_graph(image, radar, &f) {
            Ok((out, ran)) => {
                let line = (ran == Ran::Captured).then(|| {
                    format!(
                        "cuda graph: captured for inputs {:?} and {:?}; later batches of that \
                         shape replay it",
                        image.size(),
                        radar.size()
                    )
                });
                (out, ran, line)
            }
            Err(reason) => {
                let line = (!self.said.contains(&reason)).then(|| {
                    self.said.push(reason.clone());
                    format!("cuda graph: {reason}: eager")
                });
                (f(image, radar), Ran::Eager(reason), line)
            }
        };
        self.last = Some(ran);
        (out, line)
    }

    /// How the last [`GraphedForward::run`] ran (`None` before the first).
    pub fn last(&self) -> Option<&Ran> {
        self.last.as_ref()
    }

    /// The graph's run, or why it cannot take this batch.
    fn try_graph(
        &mut self,
        image: &Tensor,
        radar: &Tensor,
        f: &impl Fn(&Tensor, &Tensor) -> Tensor,
    ) -> Result<(Tensor, Ran), String> {
        let Device::Cuda(device) = image.device() else {
            return Err("the input is not on a CUDA device".into());
        };
        if !cuda_graph::built() {
            return Err("this build has no CUDA graphs (feature cuda-graphs)".into());
        }
        if self.failed {
            return Err("the capture failed earlier".into());
        }
        if let Some(c) = &self.captured {
            if c.image.size() != image.size() || c.radar.size() != radar.size() {
                return Err(format!(
                    "input {:?} is not the captured {:?}",
                    image.size(),
                    c.image.size()
                ));
            }
            tch::no_grad(|| {
                let (mut i, mut r) = (c.image.shallow_clone(), c.radar.shallow_clone());
                i.copy_(image);
                r.copy_(radar);
            });
            c.graph.replay().map_err(|e| e.to_string())?;
            return Ok((c.out.copy(), Ran::Replayed));
        }
        // Warm-up (cuDNN autotuning, first allocations) outside the capture.
        let _ = f(image, radar);
        let (static_image, static_radar) = (image.copy(), radar.copy());
        let captured = CudaGraph::capture(device, || f(&static_image, &static_radar));
        let (graph, out) = match captured {
            Ok(c) => c,
            Err(e) => {
                self.failed = true;
                return Err(format!("capture failed ({e})"));
            }
        };
        graph.replay().map_err(|e| e.to_string())?;
        let result = out.copy();
        self.captured = Some(Captured {
            image: static_image,
            radar: static_radar,
            out,
            graph,
        });
        Ok((result, Ran::Captured))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Kind;

    #[test]
    fn a_cpu_input_runs_eagerly_and_says_why_once() {
        let mut g = GraphedForward::new();
        let img = Tensor::ones([1, 3, 4, 4], (Kind::Float, Device::Cpu));
        let radar = Tensor::zeros([1, 1, 4, 4], (Kind::Float, Device::Cpu));
        let f = |i: &Tensor, r: &Tensor| i.sum_dim_intlist(1, true, Kind::Float) + r;
        let (out, line) = g.run(&img, &radar, f);
        assert_eq!(out.double_value(&[0, 0, 1, 1]), 3.0, "the eager result");
        assert!(line.unwrap().contains("not on a CUDA device"));
        let (_, line) = g.run(&img, &radar, f);
        assert!(line.is_none(), "said once");
        assert!(matches!(g.last(), Some(Ran::Eager(r)) if r.contains("not on a CUDA device")));
    }
}
