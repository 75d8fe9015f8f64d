//! The ResNet encoders (SPEC §6): the RGB encoder (VarStore `rgb.`) and the radar branch's
//! backbone (`radar.`), torchvision layout and names, with the paper's and the released stems.

use tch::Tensor;

use std::rc::Rc;

use crate::layers::{out_len, ConvBn, MacRows, P};
use crate::sync_bn::BatchNormHook;
use depthsense_config::StemKind;

/// Residual block kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BlockKind {
    Basic,
    Bottleneck,
}

impl BlockKind {
    pub fn expansion(self) -> i64 {
        match self {
            BlockKind::Basic => 1,
            BlockKind::Bottleneck => 4,
        }
    }
}

/// A ResNet basic block or v1.5 bottleneck (stride and dilation on the 3x3), torchvision names.
pub(crate) struct Block {
    kind: BlockKind,
    c1: ConvBn,
    c2: ConvBn,
    c3: Option<ConvBn>,
    down: Option<ConvBn>,
}

impl Block {
    fn new(
        p: &P,
        kind: BlockKind,
        [cin, planes, stride, dil]: [i64; 4],
        bn: Option<&Rc<dyn BatchNormHook>>,
    ) -> Block {
        let out = planes * kind.expansion();
        let down = (stride != 1 || cin != out).then(|| {
            ConvBn::new(
                &p.sub("downsample").sub("0"),
                &p.sub("downsample").sub("1"),
                cin,
                out,
                1,
                stride,
                0,
                1,
                bn,
            )
        });
        let hook = bn;
        // `conv{i}` + `bn{i}`: [cin, cout, k, stride, pad, dil].
        let cb = |i: usize, [cin, cout, k, stride, pad, dil]: [i64; 6]| {
            let (conv, bn) = (format!("conv{i}"), format!("bn{i}"));
            ConvBn::new(
                &p.sub(&conv),
                &p.sub(&bn),
                cin,
                cout,
                k,
                stride,
                pad,
                dil,
                hook,
            )
        };
        match kind {
            BlockKind::Basic => Block {
                kind,
                c1: cb(1, [cin, planes, 3, stride, dil, dil]),
                c2: cb(2, [planes, planes, 3, 1, dil, dil]),
                c3: None,
                down,
            },
            BlockKind::Bottleneck => Block {
                kind,
                c1: cb(1, [cin, planes, 1, 1, 0, 1]),
                c2: cb(2, [planes, planes, 3, stride, dil, dil]),
                c3: Some(cb(3, [planes, out, 1, 1, 0, 1])),
                down,
            },
        }
    }

    /// `[B,cin,H,W]` → `[B,planes·expansion,H/stride,W/stride]`.
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let mut y = self.c1.forward_t(x, train).relu();
        y = self.c2.forward_t(&y, train);
        if let Some(c3) = &self.c3 {
            y = c3.forward_t(&y.relu(), train);
        }
        let short = match &self.down {
            Some(d) => d.forward_t(x, train),
            None => x.shallow_clone(),
        };
        debug_assert!(self.kind == BlockKind::Basic || self.c3.is_some());
        (y + short).relu()
    }

    fn count(&self, hw: (i64, i64), rows: &mut MacRows) -> (i64, i64) {
        let mut o = self.c1.conv.count(hw, rows);
        o = self.c2.conv.count(o, rows);
        if let Some(c3) = &self.c3 {
            o = c3.conv.count(o, rows);
        }
        if let Some(d) = &self.down {
            d.conv.count(hw, rows);
        }
        o
    }
}

/// Geometry of a ResNet encoder.
#[derive(Clone, Debug)]
pub(crate) struct ResNetSpec {
    pub in_channels: i64,
    pub width: i64,
    pub stem: StemKind,
    pub block: BlockKind,
    pub blocks: [usize; 4],
    pub strides: [i64; 4],
    pub dilations: [i64; 4],
}

impl ResNetSpec {
    /// The standard torchvision layout for a depth (18/34 basic, 50/101 bottleneck).
    pub fn standard(depth: u32, in_channels: i64, width: i64, stem: StemKind) -> ResNetSpec {
        let (block, blocks) = match depth {
            18 => (BlockKind::Basic, [2, 2, 2, 2]),
            34 => (BlockKind::Basic, [3, 4, 6, 3]),
            50 => (BlockKind::Bottleneck, [3, 4, 6, 3]),
            _ => (BlockKind::Bottleneck, [3, 4, 23, 3]),
        };
        ResNetSpec {
            in_channels,
            width,
            stem,
            block,
            blocks,
            strides: [1, 2, 2, 2],
            dilations: [1, 1, 1, 1],
        }
    }
}

#[allow(clippy::large_enum_variant)] // built once per network
enum Stem {
    Torchvision(ConvBn),
    Deep([ConvBn; 3]),
    Radar([ConvBn; 4]),
}

/// A ResNet encoder; `forward_t` returns C1..C4 (outputs of layer1..layer4, SPEC §6).
pub(crate) struct ResNet {
    stem: Stem,
    layers: Vec<Vec<Block>>,
    /// Channels of C1..C4.
    pub channels: [i64; 4],
}

impl ResNet {
    /// Folds every BatchNorm into its conv for the inference graph ([`ConvBn::fold_batch_norm`]).
    pub fn fold_batch_norm(&self, layout: crate::precision::InferenceLayout) {
        let stem: &[ConvBn] = match &self.stem {
            Stem::Torchvision(c) => std::slice::from_ref(c),
            Stem::Deep(c) => c,
            Stem::Radar(c) => c,
        };
        let blocks = self.layers.iter().flatten();
        let in_blocks =
            blocks.flat_map(|b| [Some(&b.c1), Some(&b.c2), b.c3.as_ref(), b.down.as_ref()]);
        for c in stem.iter().chain(in_blocks.flatten()) {
            c.fold_batch_norm(layout);
        }
    }

    /// The encoder of `s` under `p`; `bn`: the BatchNorm hook of data-parallel training
    /// (`crate::sync_bn`), or None.
    pub fn new(p: &P, s: &ResNetSpec, bn: Option<&Rc<dyn BatchNormHook>>) -> ResNet {
        let (stem, cin) = Self::stem(p, s, bn);
        let (layers, channels) = Self::layers(p, s, cin, bn);
        ResNet {
            stem,
            layers,
            channels,
        }
    }

    /// The stem of `s` under `p` and its output channels.
    fn stem(p: &P, s: &ResNetSpec, bn: Option<&Rc<dyn BatchNormHook>>) -> (Stem, i64) {
        let w = s.width;
        let cb = |i: usize, cin: i64, cout: i64, k: i64, st: i64, pad: i64| {
            ConvBn::new(
                &p.sub(&format!("conv{i}")),
                &p.sub(&format!("bn{i}")),
                cin,
                cout,
                k,
                st,
                pad,
                1,
                bn,
            )
        };
        match s.stem {
            StemKind::Torchvision => (Stem::Torchvision(cb(1, s.in_channels, w, 7, 2, 3)), w),
            // SPEC §6.1 image stem: 3x3/2 3→64, 3x3 64→64, 3x3 64→128.
            StemKind::Deep => (
                Stem::Deep([
                    cb(1, s.in_channels, w, 3, 2, 1),
                    cb(2, w, w, 3, 1, 1),
                    cb(3, w, 2 * w, 3, 1, 1),
                ]),
                2 * w,
            ),
            // SPEC §6.1 radar stem: 3x3/2 1→64, 3x3 64→64, 3x3 64→64, 7x7/2 p3 64→128.
            StemKind::Radar => (
                Stem::Radar([
                    cb(1, s.in_channels, w, 3, 2, 1),
                    cb(2, w, w, 3, 1, 1),
                    cb(3, w, w, 3, 1, 1),
                    cb(4, w, 2 * w, 7, 2, 3),
                ]),
                2 * w,
            ),
        }
    }

    /// layer1..layer4 of `s` under `p`, from `cin` stem channels, and the channels of C1..C4.
    fn layers(
        p: &P,
        s: &ResNetSpec,
        mut cin: i64,
        bn: Option<&Rc<dyn BatchNormHook>>,
    ) -> (Vec<Vec<Block>>, [i64; 4]) {
        let w = s.width;
        let mut layers = Vec::new();
        let mut channels = [0; 4];
        #[allow(clippy::needless_range_loop)] // li indexes four parallel arrays
        for li in 0..4 {
            let planes = w << li;
            let lp = p.sub(&format!("layer{}", li + 1));
            let mut blocks = Vec::new();
            for bi in 0..s.blocks[li] {
                let stride = if bi == 0 { s.strides[li] } else { 1 };
                blocks.push(Block::new(
                    &lp.sub(&bi.to_string()),
                    s.block,
                    [cin, planes, stride, s.dilations[li]],
                    bn,
                ));
                cin = planes * s.block.expansion();
            }
            channels[li] = cin;
            layers.push(blocks);
        }
        (layers, channels)
    }

    fn pool_geometry(&self) -> (i64, i64, i64) {
        match self.stem {
            Stem::Radar(_) => (7, 4, 1), // SPEC §6.1: max-pool 7x7 s4 p1
            _ => (3, 2, 1),
        }
    }

    /// `[B,in,H,W]` → [C1 `[B,c1,H/4,W/4]`, C2 (/8), C3 (/16), C4 (/32)] for the standard
    /// strides (other strides/dilations per the spec).
    pub fn forward_t(&self, x: &Tensor, train: bool) -> Vec<Tensor> {
        let mut y = match &self.stem {
            Stem::Torchvision(c) => c.forward_t(x, train).relu(),
            Stem::Deep(cs) => cs
                .iter()
                .fold(x.shallow_clone(), |y, c| c.forward_t(&y, train).relu()),
            Stem::Radar(cs) => cs
                .iter()
                .fold(x.shallow_clone(), |y, c| c.forward_t(&y, train).relu()),
        };
        let (k, s, p) = self.pool_geometry();
        y = y.max_pool2d([k, k], [s, s], [p, p], [1, 1], false);
        let mut outs = Vec::with_capacity(4);
        for layer in &self.layers {
            for b in layer {
                y = b.forward_t(&y, train);
            }
            outs.push(y.shallow_clone());
        }
        outs
    }

    /// Multiply-adds per conv for one `hw` image; returns the sizes of C1..C4.
    pub fn count(&self, hw: (i64, i64), rows: &mut MacRows) -> Vec<(i64, i64)> {
        let mut o = hw;
        let convs: Vec<&ConvBn> = match &self.stem {
            Stem::Torchvision(c) => vec![c],
            Stem::Deep(cs) => cs.iter().collect(),
            Stem::Radar(cs) => cs.iter().collect(),
        };
        for c in convs {
            o = c.conv.count(o, rows);
        }
        let (k, s, p) = self.pool_geometry();
        o = (out_len(o.0, k, s, p, 1), out_len(o.1, k, s, p, 1));
        let mut sizes = Vec::new();
        for layer in &self.layers {
            for b in layer {
                o = b.count(o, rows);
            }
            sizes.push(o);
        }
        sizes
    }
}
