//! The radar–pixel association network of MER (SPEC §5, RC-PDA): for every radar pixel of a
//! low-resolution grid, 180 logits, one per neighbour of its window (2 px left/right, 30 up,
//! 5 down), saying whether that neighbour shares the radar return's depth.
//!
//! - [`PdaConfig`] (`depthsense_config::pda`, torch-free): presets, the window, the grid and
//!   the label thresholds;
//! - [`PdaNet`]: a small U-Net (conv3x3 + BN + ReLU levels, stride-2 downsampling, nearest
//!   upsampling with skip concatenation, 1x1 head). Optical flow (an RC-PDA input) is optional
//!   in SPEC §5 and left out: the inputs are the image and the raw radar only.
//! - [`balanced_bce`]: class-balanced binary cross-entropy over labelled radar pixels only;
//! - [`save`] / [`load`]: one safetensors file with the config in its metadata (atomic).
//!
//! Initialisation is PyTorch's `nn.Conv2d` default for every conv (U(±1/√fan_in)) and
//! BatchNorm γ = 1, β = 0 (crate::layers, docs/guide/train.md).

use tch::{nn, nn::ModuleT, Kind, Tensor};

use crate::layers::{batch_norm2d, Conv, P};
use crate::ModelError;
use depthsense_config::pda::PdaConfig;

/// conv3x3 (no bias) + BN + ReLU.
struct Cbr {
    conv: Conv,
    bn: nn::BatchNorm,
}

impl Cbr {
    fn new(p: &P, cin: i64, cout: i64, stride: i64) -> Self {
        Cbr {
            conv: Conv::new(&p.sub("conv"), cin, cout, 3, stride, 1, 1, false),
            bn: batch_norm2d(&p.sub("bn"), cout),
        }
    }
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        self.bn.forward_t(&self.conv.forward(x), train).relu()
    }
}

/// The association network (see the module docs).
pub struct PdaNet {
    cfg: PdaConfig,
    /// Per level: two conv-BN-ReLU (the first with stride 2 from level 1 on).
    enc: Vec<[Cbr; 2]>,
    /// Per level below the last: conv-BN-ReLU on [upsampled coarser level, skip].
    dec: Vec<Cbr>,
    /// The 1x1 head as a matrix `[K·s², C0]` and bias `[K·s²]` (an `nn.Conv2d(C0, K·s², 1)`
    /// with PyTorch's init; s = `input_stride`, row k·s² + (dv·s + du) is neighbour k of the
    /// pixel at (du, dv) inside its s×s cell), applied only at the pixels asked for
    /// ([`PdaNet::logits_at`]).
    head_w: Tensor,
    head_b: Tensor,
    /// Affinity projections W_q, W_k `[E, C0]` (`affinity_channels` > 0).
    affinity: Option<(Tensor, Tensor)>,
    /// Window offsets (dx, dy) as Int64 `[K]` tensors, channel order.
    offsets: (Tensor, Tensor),
}

impl std::fmt::Debug for PdaNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PdaNet").field("cfg", &self.cfg).finish()
    }
}

/// Input channels: ImageNet-normalised RGB (3), radar depth / radar_scale_m (1), radar mask (1).
pub const INPUT_CHANNELS: i64 = 5;

impl PdaNet {
    pub fn new(p: &nn::Path, cfg: &PdaConfig) -> Result<Self, ModelError> {
        cfg.validate()?;
        let root = P::root(p);
        let w = &cfg.widths;
        let mut enc = Vec::with_capacity(w.len());
        for (i, &c) in w.iter().enumerate() {
            let pi = root.sub(&format!("enc{i}"));
            let (cin, stride) = if i == 0 {
                (INPUT_CHANNELS * cfg.input_stride * cfg.input_stride, 1)
            } else {
                (w[i - 1], 2)
            };
            enc.push([
                Cbr::new(&pi.sub("0"), cin, c, stride),
                Cbr::new(&pi.sub("1"), c, c, 1),
            ]);
        }
        let dec = (0..w.len() - 1)
            .map(|i| Cbr::new(&root.sub(&format!("dec{i}")), w[i + 1] + w[i], w[i], 1))
            .collect();
        // K logits for each of the s² positions of a cell (s = input_stride)
        let k = cfg.window.len() as i64 * cfg.input_stride * cfg.input_stride;
        let bound = 1.0 / (w[0] as f64).sqrt();
        let u = nn::Init::Uniform {
            lo: -bound,
            up: bound,
        };
        let head = p / "head";
        let head_w = head.var("weight", &[k, w[0]], u);
        let head_b = head.var("bias", &[k], u);
        let e = cfg.affinity_channels;
        let affinity = (e > 0).then(|| {
            let a = p / "affinity";
            // two bias-free 1x1 convs C0 → E, PyTorch's bound 1/√C0
            (a.var("query", &[e, w[0]], u), a.var("key", &[e, w[0]], u))
        });
        let (dx, dy): (Vec<i64>, Vec<i64>) = cfg.window.offsets().into_iter().unzip();
        let offsets = (
            Tensor::from_slice(&dx).to_device(p.device()),
            Tensor::from_slice(&dy).to_device(p.device()),
        );
        Ok(PdaNet {
            cfg: cfg.clone(),
            enc,
            dec,
            head_w,
            head_b,
            affinity,
            offsets,
        })
    }

    pub fn config(&self) -> &PdaConfig {
        &self.cfg
    }

    /// Image `[B,3,h,w]` (ImageNet-normalised) and radar `[B,1,h,w]` (metres, 0 = none), both
    /// at the MER grid → association logits `[B,K,h,w]`, K = window length (180); channel k is
    /// the neighbour at `window.offsets()[k]` of the radar return at that pixel. Training and
    /// `mer apply` only need the radar pixels: [`PdaNet::features_t`] + [`PdaNet::logits_at`].
    ///
    /// With the affinity term this evaluates every pixel's 180 neighbours (B·h·w·K·E floats):
    /// meant for tests and small images.
    pub fn forward_t(&self, image: &Tensor, radar: &Tensor, train: bool) -> Tensor {
        let f = self.features_t(image, radar, train);
        let (h, w) = f.grid_hw;
        let k = self.cfg.window.len() as i64;
        if self.affinity.is_some() {
            let b = f.map.size()[0];
            let idx = Tensor::arange(b * h * w, (Kind::Int64, f.map.device()));
            return self
                .logits_at(&f, &idx)
                .view([b, h, w, k])
                .permute([0, 3, 1, 2]);
        }
        let (ks, c) = (self.head_w.size()[0], self.head_w.size()[1]);
        let s = self.cfg.input_stride;
        f.map
            .conv2d(
                &self.head_w.view([ks, c, 1, 1]),
                Some(&self.head_b),
                [1, 1],
                [0, 0],
                [1, 1],
                1,
            )
            .pixel_shuffle(s)
            .narrow(2, 0, h)
            .narrow(3, 0, w)
    }

    /// Logits `[N,K]` at flat grid indices `idx` (b·h·w + v·w + u, Int64) of the features of
    /// [`PdaNet::features_t`]; equal to [`gather_pixels`] of [`PdaNet::forward_t`], without
    /// computing the head at every other pixel.
    pub fn logits_at(&self, f: &PdaFeatures, idx: &Tensor) -> Tensor {
        let s = self.cfg.input_stride;
        let (h, w) = f.grid_hw;
        // each pixel's cell of the feature map, and its position inside the cell (0 when s = 1)
        let (hc, wc) = (f.map.size()[2], f.map.size()[3]);
        let (b, v, u) = split_index(idx, h, w);
        let cell = &b * (hc * wc) + v.floor_divide_scalar(s) * wc + u.floor_divide_scalar(s);
        let phase = v.remainder(s) * s + u.remainder(s); // [N]
        let all = gather_pixels(&f.map, &cell).matmul(&self.head_w.tr()) + &self.head_b;
        let n = all.size()[0];
        let k = self.cfg.window.len() as i64;
        let pick = phase.view([n, 1, 1]).expand([n, k, 1], false);
        let head = all.view([n, k, s * s]).gather(2, &pick, false).view([n, k]);
        let Some((wq, wk)) = &self.affinity else {
            return head;
        };
        let c = f.map.size()[1];
        let e = wq.size()[0];
        // features at every grid pixel (a coarse cell's vector for each of its s² pixels)
        let full = if s == 1 {
            f.map.shallow_clone()
        } else {
            let (hc, wc) = (f.map.size()[2], f.map.size()[3]);
            f.map
                .upsample_nearest2d([hc * s, wc * s], None, None)
                .narrow(2, 0, h)
                .narrow(3, 0, w)
        };
        let flat = full.permute([0, 2, 3, 1]).reshape([-1, c]);
        let q = flat.index_select(0, idx).matmul(&wq.tr()); // [N,E]
        let keys = flat.matmul(&wk.tr()); // [B·h·w,E]
        let nidx = neighbour_indices(idx, h, w, &self.offsets); // [N,K]
        let (n, k) = (nidx.size()[0], nidx.size()[1]);
        let kn = keys.index_select(0, &nidx.reshape([-1])).view([n, k, e]);
        let kind = kn.kind();
        let dot = (kn * q.unsqueeze(1)).sum_dim_intlist(-1, false, kind);
        head + dot / (e as f64).sqrt()
    }

    /// The U-Net's level-0 features (inputs as [`PdaNet::forward_t`]).
    pub fn features_t(&self, image: &Tensor, radar: &Tensor, train: bool) -> PdaFeatures {
        let grid_hw = (image.size()[2], image.size()[3]);
        let radar = radar.to_kind(image.kind());
        let mask = radar.gt(0.0).to_kind(image.kind());
        let mut x = Tensor::cat(
            &[image.shallow_clone(), &radar / self.cfg.radar_scale_m, mask],
            1,
        );
        let s = self.cfg.input_stride;
        if s > 1 {
            let pad = |n: i64| (s - n % s) % s;
            let (ph, pw) = (pad(grid_hw.0), pad(grid_hw.1));
            if ph + pw > 0 {
                x = x.constant_pad_nd([0, pw, 0, ph]);
            }
            x = space_to_depth(&x, s);
        }
        let mut skips = Vec::with_capacity(self.enc.len());
        for [a, b] in &self.enc {
            x = b.forward_t(&a.forward_t(&x, train), train);
            skips.push(x.shallow_clone());
        }
        for i in (0..self.dec.len()).rev() {
            let skip = &skips[i];
            let sz = skip.size();
            let up = x.upsample_nearest2d([sz[2], sz[3]], None, None);
            x = self.dec[i].forward_t(&Tensor::cat(&[up, skip.shallow_clone()], 1), train);
        }
        PdaFeatures { map: x, grid_hw }
    }
}

/// The U-Net's level-0 features and the grid they describe.
pub struct PdaFeatures {
    /// `[B, C0, ⌈h/s⌉, ⌈w/s⌉]`, s = `input_stride`.
    pub map: Tensor,
    /// `(h, w)` of the grid the inputs were given at.
    pub grid_hw: (i64, i64),
}

/// `[B,C,H,W]` → `[B,C·s²,H/s,W/s]`, channel c·s² + i·s + j = pixel (s·y + i, s·x + j) of
/// channel c: `pixel_unshuffle`, as a view and one copy (about twice as fast on a CPU).
fn space_to_depth(x: &Tensor, s: i64) -> Tensor {
    let (b, c, h, w) = x.size4().expect("4-d input");
    x.view([b, c, h / s, s, w / s, s])
        .permute([0, 1, 3, 5, 2, 4])
        .reshape([b, c * s * s, h / s, w / s])
}

/// (b, v, u) of flat indices b·h·w + v·w + u.
fn split_index(idx: &Tensor, h: i64, w: i64) -> (Tensor, Tensor, Tensor) {
    let b = idx.floor_divide_scalar(h * w);
    let rem = idx - &b * (h * w);
    let v = rem.floor_divide_scalar(w);
    let u = &rem - &v * w;
    (b, v, u)
}

/// Weights of the two classes so that positives and negatives weigh half each (class-balanced
/// BCE, SPEC §5): (w_pos, w_neg) = (1/(2·n_pos), 1/(2·n_neg)); a class that is absent gets
/// weight 0 and the other one 1/n (a plain mean). Both absent: (0, 0).
pub fn class_weights(n_pos: f64, n_neg: f64) -> (f64, f64) {
    match (n_pos > 0.0, n_neg > 0.0) {
        (true, true) => (0.5 / n_pos, 0.5 / n_neg),
        (true, false) => (1.0 / n_pos, 0.0),
        (false, true) => (0.0, 1.0 / n_neg),
        (false, false) => (0.0, 0.0),
    }
}

/// Class-balanced binary cross-entropy with logits over the labelled pairs only:
/// `logits`, `labels` (1 = associated, 0 = not) and `mask` (1 = labelled) of one shape, e.g.
/// `[N,K]` for N radar pixels. Returns a scalar: Σ mask·(w_pos·y·softplus(−x) +
/// w_neg·(1−y)·softplus(x)) with [`class_weights`] from this batch's counts.
pub fn balanced_bce(logits: &Tensor, labels: &Tensor, mask: &Tensor) -> Tensor {
    let x = logits.to_kind(Kind::Float);
    let pos = labels * mask;
    let neg = (labels.ones_like() - labels) * mask;
    let (wp, wn) = class_weights(pos.sum(Kind::Double).double_value(&[]), {
        neg.sum(Kind::Double).double_value(&[])
    });
    let lp = (-&x).softplus() * pos * wp;
    let ln = x.softplus() * neg * wn;
    (lp + ln).sum(Kind::Float)
}

/// Rows of `logits` `[B,K,h,w]` at flat pixel indices `idx` (b·h·w + v·w + u, Int64) → `[N,K]`.
pub fn gather_pixels(logits: &Tensor, idx: &Tensor) -> Tensor {
    let k = logits.size()[1];
    logits
        .permute([0, 2, 3, 1])
        .reshape([-1, k])
        .index_select(0, idx)
}

/// Flat indices `[N,K]` of the K window neighbours of the pixels `idx` (b·h·w + v·w + u) of
/// `[B,·,h,w]` maps; neighbours outside the image are clamped to its border (their pairs are
/// unlabelled in training and ignored by `mer apply`).
fn neighbour_indices(idx: &Tensor, h: i64, w: i64, offsets: &(Tensor, Tensor)) -> Tensor {
    let hw = h * w;
    let (b, v, u) = split_index(idx, h, w);
    let nv = (v.unsqueeze(1) + offsets.1.unsqueeze(0)).clamp(0, h - 1);
    let nu = (u.unsqueeze(1) + offsets.0.unsqueeze(0)).clamp(0, w - 1);
    b.unsqueeze(1) * hw + nv * w + nu
}

/// Trainable parameters of a var store.
pub fn parameter_count(vs: &nn::VarStore) -> i64 {
    vs.trainable_variables()
        .iter()
        .map(|t| t.numel() as i64)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn forward_shapes_and_pytorch_init() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = PdaNet::new(&vs.root(), &PdaConfig::test()).unwrap();
        let img = Tensor::randn([2, 3, 19, 23], (Kind::Float, Device::Cpu));
        let radar = Tensor::zeros([2, 1, 19, 23], (Kind::Float, Device::Cpu));
        let y = net.forward_t(&img, &radar, false);
        assert_eq!(y.size(), vec![2, 180, 19, 23]);
        // The head at chosen pixels equals the full map there.
        let idx = Tensor::from_slice(&[0i64, 5, 19 * 23 + 7, 2 * 19 * 23 - 1]);
        let at = net.logits_at(&net.features_t(&img, &radar, false), &idx);
        let full = gather_pixels(&y, &idx);
        assert_eq!(at.size(), vec![4, 180]);
        assert!((at - full).abs().max().double_value(&[]) < 1e-5);
        // PyTorch nn.Conv2d bound 1/√fan_in, BN γ = 1.
        let vars = vs.variables();
        let w0 = &vars["enc0.0.conv.weight"];
        let bound = 1.0 / ((5 * 9) as f64).sqrt();
        assert!(w0.abs().max().double_value(&[]) <= bound + 1e-7);
        assert!(w0.abs().max().double_value(&[]) > 0.8 * bound);
        assert_eq!(vars["enc0.0.bn.weight"].min().double_value(&[]), 1.0);
        let hb = &vars["head.bias"];
        assert!(hb.abs().max().double_value(&[]) <= 1.0 / 2.0 + 1e-7); // fan_in = 4
    }

    #[test]
    fn affinity_head_matches_the_full_map_and_compares_the_right_neighbours() {
        let cfg = PdaConfig {
            affinity_channels: 6,
            ..PdaConfig::test()
        };
        tch::manual_seed(5);
        let vs = nn::VarStore::new(Device::Cpu);
        let net = PdaNet::new(&vs.root(), &cfg).unwrap();
        let img = Tensor::randn([2, 3, 19, 23], (Kind::Float, Device::Cpu));
        let radar = Tensor::zeros([2, 1, 19, 23], (Kind::Float, Device::Cpu));
        let f = net.features_t(&img, &radar, false);
        let y = net.forward_t(&img, &radar, false);
        assert_eq!(y.size(), vec![2, 180, 19, 23]);
        let idx = Tensor::from_slice(&[0i64, 5, 19 * 23 + 7, 2 * 19 * 23 - 1]);
        let at = net.logits_at(&f, &idx);
        assert!(
            (&at - gather_pixels(&y, &idx))
                .abs()
                .max()
                .double_value(&[])
                < 1e-5
        );
        // By hand for pixel (b = 1, v = 10, u = 4) and offset (dx, dy) = (2, −3).
        let (v, u) = (10i64, 4i64);
        let k = cfg
            .window
            .offsets()
            .iter()
            .position(|&o| o == (2, -3))
            .unwrap();
        let p = Tensor::from_slice(&[19 * 23 + v * 23 + u]);
        let fp = f.map.get(1).select(1, v).select(1, u); // [C0]
        let fnb = f.map.get(1).select(1, v - 3).select(1, u + 2);
        let (wq, wk) = net.affinity.as_ref().unwrap();
        let dot = wq.mv(&fp).dot(&wk.mv(&fnb)).double_value(&[]) / 6f64.sqrt();
        let head = (net.head_w.get(k as i64).dot(&fp) + net.head_b.get(k as i64)).double_value(&[]);
        let got = net.logits_at(&f, &p).double_value(&[0, k as i64]);
        assert!((got - (head + dot)).abs() < 1e-5, "{got} vs {}", head + dot);
        // a config without the field (older checkpoints) reads back with no affinity
        let mut js = serde_json::to_value(PdaConfig::tiny()).unwrap();
        js.as_object_mut().unwrap().remove("affinity_channels");
        let old: PdaConfig = serde_json::from_value(js).unwrap();
        assert_eq!(old.affinity_channels, 0);
    }

    #[test]
    fn input_stride_2_head_picks_the_cell_position_and_matches_the_full_map() {
        let cfg = PdaConfig {
            input_stride: 2,
            ..PdaConfig::test()
        };
        tch::manual_seed(3);
        let vs = nn::VarStore::new(Device::Cpu);
        let net = PdaNet::new(&vs.root(), &cfg).unwrap();
        let vars = vs.variables();
        assert_eq!(vars["enc0.0.conv.weight"].size(), vec![4, 20, 3, 3]);
        assert_eq!(vars["head.weight"].size(), vec![4 * 180, 4]);
        // odd grid: padded to 20x24, folded to 10x12
        let img = Tensor::randn([2, 3, 19, 23], (Kind::Float, Device::Cpu));
        let radar = Tensor::rand([2, 1, 19, 23], (Kind::Float, Device::Cpu)) * 30.0;
        let f = net.features_t(&img, &radar, false);
        assert_eq!(f.map.size(), vec![2, 4, 10, 12]);
        assert_eq!(f.grid_hw, (19, 23));
        let y = net.forward_t(&img, &radar, false);
        assert_eq!(y.size(), vec![2, 180, 19, 23]);
        // every pixel, all four cell positions and the padded border included
        let idx = Tensor::arange(2 * 19 * 23, (Kind::Int64, Device::Cpu));
        let diff = (net.logits_at(&f, &idx) - gather_pixels(&y, &idx))
            .abs()
            .max();
        assert!(diff.double_value(&[]) < 1e-5);
        // by hand: pixel (b = 1, v = 7, u = 4) lies at (dv, du) = (1, 0) of cell (3, 2)
        let (v, u, k) = (7i64, 4i64, 37i64);
        let fp = f.map.get(1).select(1, 3).select(1, 2);
        let row = k * 4 + 2;
        let want = (net.head_w.get(row).dot(&fp) + net.head_b.get(row)).double_value(&[]);
        let p = Tensor::from_slice(&[19 * 23 + v * 23 + u]);
        let got = net.logits_at(&f, &p).double_value(&[0, k]);
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        // older configs read back with stride 1, and stride 1 is not written
        let js = serde_json::to_value(PdaConfig::tiny()).unwrap();
        assert!(js.get("input_stride").is_none());
        assert_eq!(
            serde_json::from_value::<PdaConfig>(js)
                .unwrap()
                .input_stride,
            1
        );
        let x = Tensor::randn([2, 5, 8, 12], (Kind::Float, Device::Cpu));
        assert!(space_to_depth(&x, 2).equal(&x.pixel_unshuffle(2)));
        assert!(space_to_depth(&x, 4).equal(&x.pixel_unshuffle(4)));
        let bad = PdaConfig {
            input_stride: 3,
            ..PdaConfig::test()
        };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn class_weights_balance_the_two_classes() {
        assert_eq!(class_weights(2.0, 8.0), (0.25, 0.0625));
        assert_eq!(class_weights(0.0, 4.0), (0.0, 0.25));
        assert_eq!(class_weights(3.0, 0.0), (1.0 / 3.0, 0.0));
        assert_eq!(class_weights(0.0, 0.0), (0.0, 0.0));
        // Total weight of each present class is ½.
        let (wp, wn) = class_weights(7.0, 93.0);
        assert!((wp * 7.0 - 0.5).abs() < 1e-12 && (wn * 93.0 - 0.5).abs() < 1e-12);
    }

    #[test]
    fn balanced_bce_by_hand() {
        // 1 positive (logit 0), 3 negatives (logit 0, 0, 0), one unlabelled pair (ignored).
        let x = Tensor::from_slice(&[0f32, 0.0, 0.0, 0.0, 50.0]);
        let y = Tensor::from_slice(&[1f32, 0.0, 0.0, 0.0, 1.0]);
        let m = Tensor::from_slice(&[1f32, 1.0, 1.0, 1.0, 0.0]);
        let l = balanced_bce(&x, &y, &m).double_value(&[]);
        assert!((l - 2f64.ln()).abs() < 1e-6, "{l}");
        // A confident wrong positive costs as much as 3 wrong negatives of the same margin.
        let x = Tensor::from_slice(&[-3f32, -3.0, -3.0, -3.0]);
        let y = Tensor::from_slice(&[1f32, 0.0, 0.0, 0.0]);
        let m = Tensor::ones([4], (Kind::Float, Device::Cpu));
        let l = balanced_bce(&x, &y, &m).double_value(&[]);
        let sp = |v: f64| (1.0 + v.exp()).ln();
        assert!((l - (0.5 * sp(3.0) + 0.5 * sp(-3.0))).abs() < 1e-5, "{l}");
    }
}
