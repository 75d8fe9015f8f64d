//! Building blocks with analytic multiply-add counting: var-store paths, conv, conv + BN and
//! their initialisation (SPEC §6); the ResNet encoders built from them are in [`crate::encoder`].

use crate::precision::InferenceLayout;
use tch::{nn, Tensor};

/// A var-store path together with its dotted name (for FLOP reports).
#[derive(Clone)]
pub(crate) struct P<'a> {
    pub p: nn::Path<'a>,
    pub name: String,
}

impl<'a> P<'a> {
    pub fn root(p: &nn::Path<'a>) -> Self {
        P {
            p: p.clone(),
            name: String::new(),
        }
    }
    pub fn sub(&self, s: &str) -> P<'a> {
        let name = if self.name.is_empty() {
            s.to_string()
        } else {
            format!("{}.{s}", self.name)
        };
        P {
            p: &self.p / s,
            name,
        }
    }
}

/// Multiply-adds per named layer, collected by walking the module structure.
pub type MacRows = Vec<(String, u64)>;

/// Output size of a conv / pool along one axis.
pub(crate) fn out_len(n: i64, k: i64, s: i64, p: i64, d: i64) -> i64 {
    (n + 2 * p - d * (k - 1) - 1) / s + 1
}

/// How a conv's parameters start (DEVELOPERS: initialisation is part of the method).
///
/// tch's `ConvConfig::default()` is He-uniform with ReLU gain (bound √6/√fan_in, bias 0): 2.45×
/// PyTorch's `nn.Conv2d` bound per layer, which compounds through the decoder, attention and
/// head (no BatchNorm there) into saturated initial logits — the network then sits on the label
/// marginal (../shared/notes/training-init-evidence.md). We never use tch's default.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ConvInit {
    /// PyTorch's `nn.Conv2d.reset_parameters`: kaiming_uniform(a = √5), i.e. weight and bias
    /// ~ U(±1/√fan_in), fan_in = cin·k·k. Every conv without BatchNorm after it.
    PyTorch,
    /// torchvision's ResNet: weight ~ N(0, 2/fan_out), fan_out = cout·k·k (kaiming_normal,
    /// mode fan_out, ReLU), bias 0. Convs followed by BatchNorm.
    TorchvisionResNet,
    /// Weight and bias 0: the spatial-attention conv, so that its gate starts as the identity.
    Zero,
}

impl ConvInit {
    fn inits(self, cin: i64, cout: i64, k: i64) -> (nn::Init, nn::Init) {
        match self {
            ConvInit::PyTorch => {
                let bound = 1.0 / ((cin * k * k) as f64).sqrt();
                let u = nn::Init::Uniform {
                    lo: -bound,
                    up: bound,
                };
                (u, u)
            }
            ConvInit::TorchvisionResNet => (
                nn::Init::Randn {
                    mean: 0.0,
                    stdev: (2.0 / (cout * k * k) as f64).sqrt(),
                },
                nn::Init::Const(0.0),
            ),
            ConvInit::Zero => (nn::Init::Const(0.0), nn::Init::Const(0.0)),
        }
    }
}

/// BatchNorm as PyTorch starts it: γ = 1, β = 0 (tch's default draws γ ~ U(0, 1)).
pub(crate) fn batch_norm2d(p: &P, channels: i64) -> nn::BatchNorm {
    let cfg = nn::BatchNormConfig {
        ws_init: nn::Init::Const(1.0),
        bs_init: nn::Init::Const(0.0),
        ..Default::default()
    };
    nn::batch_norm2d(&p.p, channels, cfg)
}

/// A 2-d convolution remembering its geometry.
pub(crate) struct Conv {
    conv: nn::Conv2D,
    name: String,
    cin: i64,
    cout: i64,
    k: i64,
    stride: i64,
    pad: i64,
    dil: i64,
}

impl Conv {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        p: &P,
        cin: i64,
        cout: i64,
        k: i64,
        stride: i64,
        pad: i64,
        dil: i64,
        bias: bool,
    ) -> Conv {
        Self::with_init(p, [cin, cout, k, stride, pad, dil], bias, ConvInit::PyTorch)
    }

    /// A conv with an explicit initialisation; `geom` = [cin, cout, k, stride, pad, dil].
    pub fn with_init(p: &P, geom: [i64; 6], bias: bool, init: ConvInit) -> Conv {
        let [cin, cout, k, stride, pad, dil] = geom;
        let (ws_init, bs_init) = init.inits(cin, cout, k);
        let cfg = nn::ConvConfig {
            stride,
            padding: pad,
            dilation: dil,
            bias,
            ws_init,
            bs_init,
            ..Default::default()
        };
        Conv {
            conv: nn::conv2d(&p.p, cin, cout, k, cfg),
            name: p.name.clone(),
            cin,
            cout,
            k,
            stride,
            pad,
            dil,
        }
    }
    /// `[B,cin,H,W]` → `[B,cout,H',W']`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        x.apply(&self.conv)
    }
    /// This conv's geometry with other weights `[cout,cin,k,k]` and bias `[cout]`.
    fn forward_with(&self, x: &Tensor, weight: &Tensor, bias: &Tensor) -> Tensor {
        let (s, p, d) = (self.stride, self.pad, self.dil);
        x.conv2d(weight, Some(bias), [s, s], [p, p], [d, d], 1)
    }
    pub fn out_hw(&self, hw: (i64, i64)) -> (i64, i64) {
        (
            out_len(hw.0, self.k, self.stride, self.pad, self.dil),
            out_len(hw.1, self.k, self.stride, self.pad, self.dil),
        )
    }
    /// Records this conv's multiply-adds for one image and returns its output size.
    pub fn count(&self, hw: (i64, i64), rows: &mut MacRows) -> (i64, i64) {
        let o = self.out_hw(hw);
        let macs = (self.cin * self.cout * self.k * self.k * o.0 * o.1) as u64;
        rows.push((self.name.clone(), macs));
        o
    }
    pub fn out_channels(&self) -> i64 {
        self.cout
    }
}

/// Conv (no bias) + BatchNorm, as ResNet uses them.
pub(crate) struct ConvBn {
    pub conv: Conv,
    bn: nn::BatchNorm,
    /// The training-mode BatchNorm of data-parallel training (`crate::sync_bn`), if any.
    hook: Option<std::rc::Rc<dyn crate::sync_bn::BatchNormHook>>,
    /// The inference graph's conv with the BatchNorm folded in, once
    /// [`ConvBn::fold_batch_norm`] has run; the training graph never uses it.
    folded: std::cell::RefCell<Option<Folded>>,
}

impl ConvBn {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        pc: &P,
        pb: &P,
        cin: i64,
        cout: i64,
        k: i64,
        stride: i64,
        pad: i64,
        dil: i64,
        hook: Option<&std::rc::Rc<dyn crate::sync_bn::BatchNormHook>>,
    ) -> ConvBn {
        ConvBn {
            hook: hook.cloned(),
            conv: Conv::with_init(
                pc,
                [cin, cout, k, stride, pad, dil],
                false,
                ConvInit::TorchvisionResNet,
            ),
            bn: batch_norm2d(pb, cout),
            folded: std::cell::RefCell::new(None),
        }
    }
    /// Conv then BN (no activation), shapes as [`Conv::forward`]. In evaluation mode after
    /// [`ConvBn::fold_batch_norm`]: one conv with the folded weights — folded again first if
    /// the conv's or the BatchNorm's tensors changed since (weights loaded afterwards).
    pub fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        if !train {
            let mut folded = self.folded.borrow_mut();
            if let Some(f) = folded.as_mut() {
                if f.versions != self.versions() {
                    *f = self.fold(f.layout);
                }
                return self.conv.forward_with(x, &f.weight, &f.bias);
            }
        }
        crate::sync_bn::forward_t(&self.bn, &self.conv.forward(x), train, self.hook.as_ref())
    }
    /// Folds the evaluation-mode BatchNorm into the conv (the weights as they are now; again at
    /// the next forward if they change): with s = γ / √(σ² + ε), W' = W·s per output channel
    /// and b' = β − μ·s, so that conv(x; W', b') = BN(conv(x; W)). W' is stored in `layout`.
    pub fn fold_batch_norm(&self, layout: InferenceLayout) {
        let mut folded = self.folded.borrow_mut();
        if folded.is_none() {
            *folded = Some(self.fold(layout));
        }
    }
    /// The in-place version counters of W, γ, β, μ and σ² (libtorch bumps one at every
    /// in-place write: `copy_` when weights are loaded).
    fn versions(&self) -> [i64; 5] {
        let bn = &self.bn;
        let v = |t: Option<&Tensor>| t.map_or(-1, Tensor::internal_version);
        [
            self.conv.conv.ws.internal_version(),
            v(bn.ws.as_ref()),
            v(bn.bs.as_ref()),
            bn.running_mean.internal_version(),
            bn.running_var.internal_version(),
        ]
    }
    fn fold(&self, layout: InferenceLayout) -> Folded {
        tch::no_grad(|| {
            let bn = &self.bn;
            let gamma = bn.ws.as_ref().expect("affine BatchNorm");
            let beta = bn.bs.as_ref().expect("affine BatchNorm");
            let scale = gamma * (&bn.running_var + crate::sync_bn::BN_EPS).rsqrt();
            let ws = &self.conv.conv.ws;
            let mut w = ws * scale.view([-1, 1, 1, 1]);
            if layout.channels_last_on(ws.device()) {
                w = crate::precision::channels_last(&w);
            }
            let b = beta - &bn.running_mean * &scale;
            Folded {
                weight: w.detach(),
                bias: b.detach(),
                layout,
                versions: self.versions(),
            }
        })
    }
}

/// A conv's weights with its BatchNorm folded in, and what they were folded from.
struct Folded {
    weight: Tensor,
    bias: Tensor,
    layout: InferenceLayout,
    /// [`ConvBn::versions`] when folded.
    versions: [i64; 5],
}

pub(crate) fn resize_to(x: &Tensor, hw: (i64, i64), nearest: bool) -> Tensor {
    let (_, _, h, w) = x.size4().expect("4-d feature map");
    if (h, w) == hw {
        x.shallow_clone()
    } else if nearest {
        x.upsample_nearest2d([hw.0, hw.1], None, None)
    } else {
        x.upsample_bilinear2d([hw.0, hw.1], false, None, None)
    }
}

pub(crate) fn hw_of(x: &Tensor) -> (i64, i64) {
    let s = x.size();
    (s[s.len() - 2], s[s.len() - 1])
}
