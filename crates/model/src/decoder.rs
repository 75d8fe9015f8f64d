//! The image decoder over C2..C4 (SPEC §6; the released FPN + `convfeat` form, SPEC §6.1):
//! VarStore `decoder.`.

use tch::Tensor;

use crate::layers::{hw_of, resize_to, Conv, MacRows, P};
use depthsense_config::DecoderKind;

/// Image decoder over C2..C4 (SPEC §6).
#[allow(clippy::large_enum_variant)] // built once per network
pub(crate) enum Decoder {
    /// Paper: laterals 1x1(b) → ch, nearest ×2 top-down addition, 3x3(b) smoothing, the three
    /// levels upsampled (bilinear) to the finest (stride 8) and concatenated → 3·ch.
    Topdown {
        lateral: [Conv; 3],
        smooth: [Conv; 3],
    },
    /// Released (SPEC §6.1): FPN P3..P5 then `convfeat1` 7x7/4, `convfeat2` 3x3/2,
    /// `convfeat3` 3x3/1 + ReLU to stride 32, concatenated → 3·ch.
    Released {
        lateral: [Conv; 3],
        smooth: [Conv; 3],
        feat: [Conv; 3],
    },
}

impl Decoder {
    pub(crate) fn new(p: &P, kind: DecoderKind, cin: [i64; 3], ch: i64) -> Decoder {
        let d = p.sub("decoder");
        match kind {
            DecoderKind::Topdown => Self::topdown(&d, cin, ch),
            DecoderKind::Released => Self::released(&d, cin, ch),
        }
    }

    /// The paper's decoder under `d` (`decoder.`): `lateral2..4`, `smooth2..4`.
    fn topdown(d: &P, cin: [i64; 3], ch: i64) -> Decoder {
        let lat = |i: usize| {
            Conv::new(
                &d.sub(&format!("lateral{}", i + 2)),
                cin[i],
                ch,
                1,
                1,
                0,
                1,
                true,
            )
        };
        let sm = |i: usize| {
            Conv::new(
                &d.sub(&format!("smooth{}", i + 2)),
                ch,
                ch,
                3,
                1,
                1,
                1,
                true,
            )
        };
        Decoder::Topdown {
            lateral: [lat(0), lat(1), lat(2)],
            smooth: [sm(0), sm(1), sm(2)],
        }
    }

    /// The released decoder under `d` (`decoder.`): `fpn.P3_1..P5_2`, `convfeat1..3`.
    fn released(d: &P, cin: [i64; 3], ch: i64) -> Decoder {
        let f = d.sub("fpn");
        // P3 ← C2, P4 ← C3, P5 ← C4.
        let lat = |i: usize| {
            Conv::new(
                &f.sub(&format!("P{}_1", i + 3)),
                cin[i],
                ch,
                1,
                1,
                0,
                1,
                true,
            )
        };
        let sm = |i: usize| Conv::new(&f.sub(&format!("P{}_2", i + 3)), ch, ch, 3, 1, 1, 1, true);
        // Created before the FPN convs (variable creation order = initialisation order).
        let feat = [
            Conv::new(&d.sub("convfeat1"), ch, ch, 7, 4, 2, 1, false),
            Conv::new(&d.sub("convfeat2"), ch, ch, 3, 2, 1, 1, false),
            Conv::new(&d.sub("convfeat3"), ch, ch, 3, 1, 1, 1, false),
        ];
        Decoder::Released {
            lateral: [lat(0), lat(1), lat(2)],
            smooth: [sm(0), sm(1), sm(2)],
            feat,
        }
    }

    /// Top-down pyramid: [t2, t3, t4] after smoothing (finest first).
    fn pyramid(lateral: &[Conv; 3], smooth: &[Conv; 3], c: &[Tensor]) -> [Tensor; 3] {
        let t4 = lateral[2].forward(&c[3]);
        let t3 = lateral[1].forward(&c[2]) + resize_to(&t4, hw_of(&c[2]), true);
        let t2 = lateral[0].forward(&c[1]) + resize_to(&t3, hw_of(&c[1]), true);
        [
            smooth[0].forward(&t2),
            smooth[1].forward(&t3),
            smooth[2].forward(&t4),
        ]
    }

    /// C1..C4 → `[B,3·ch,h,w]` (h,w = C2's size for top-down, C4's for released).
    pub(crate) fn forward(&self, c: &[Tensor]) -> Tensor {
        match self {
            Decoder::Topdown { lateral, smooth } => {
                let [p2, p3, p4] = Self::pyramid(lateral, smooth, c);
                let hw = hw_of(&p2);
                Tensor::cat(
                    &[p2, resize_to(&p3, hw, false), resize_to(&p4, hw, false)],
                    1,
                )
            }
            Decoder::Released {
                lateral,
                smooth,
                feat,
            } => {
                let [p3, p4, p5] = Self::pyramid(lateral, smooth, c);
                let f3 = feat[2].forward(&p5).relu();
                let hw = hw_of(&f3);
                let f1 = resize_to(&feat[0].forward(&p3).relu(), hw, false);
                let f2 = resize_to(&feat[1].forward(&p4).relu(), hw, false);
                Tensor::cat(&[f1, f2, f3], 1)
            }
        }
    }

    pub(crate) fn count(&self, sizes: &[(i64, i64)], rows: &mut MacRows) -> (i64, i64) {
        let (lateral, smooth) = match self {
            Decoder::Topdown { lateral, smooth }
            | Decoder::Released {
                lateral, smooth, ..
            } => (lateral, smooth),
        };
        for i in 0..3 {
            let o = lateral[i].count(sizes[i + 1], rows);
            smooth[i].count(o, rows);
        }
        match self {
            Decoder::Topdown { .. } => sizes[1],
            Decoder::Released { feat, .. } => {
                feat[0].count(sizes[1], rows);
                feat[1].count(sizes[2], rows);
                feat[2].count(sizes[3], rows)
            }
        }
    }

    pub(crate) fn out_channels(&self) -> i64 {
        match self {
            Decoder::Topdown { smooth, .. } | Decoder::Released { smooth, .. } => {
                3 * smooth[0].out_channels()
            }
        }
    }
}
