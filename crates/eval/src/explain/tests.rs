//! Grad-CAM++ against hand-derived cases and a finite-difference check of the gradients.

use super::*;

fn t(v: &[f64], shape: &[i64]) -> Tensor {
    Tensor::from_slice(v).view(shape).to_kind(Kind::Double)
}

#[test]
fn gradcam_pp_hand_derived() {
    // Channel 0: A = [[1,2],[3,0]] (ΣA = 6), g = 1: α = 1 / (2 + 6) = 1/8, w = 4 · 1/8 = 1/2.
    // Channel 1: A = 1 (ΣA = 4), g = −1: relu(g) = 0 → w = 0.
    // Channel 2: g = 0: denominator 0 → α = 0 → w = 0.
    // L = relu(½ A_0) = [[0.5, 1], [1.5, 0]].
    let a = t(
        &[1., 2., 3., 0., 1., 1., 1., 1., 5., 5., 5., 5.],
        &[3, 2, 2],
    );
    let g = t(
        &[1., 1., 1., 1., -1., -1., -1., -1., 0., 0., 0., 0.],
        &[3, 2, 2],
    );
    let l = gradcam_pp(&a, &g);
    let v: Vec<f64> = Vec::try_from(l.view([-1])).unwrap();
    assert_eq!(v, vec![0.5, 1.0, 1.5, 0.0]);
}

#[test]
fn gradcam_pp_through_a_tiny_network() {
    // A (1 channel) = [[1,2],[3,4]], z = 2·A (a 1x1 conv), S = z at pixel (0,0):
    // g = [[2,0],[0,0]], α(0,0) = 4 / (2·4 + 10·8) = 1/22, w = 2/22 = 1/11, L = A/11.
    let x = t(&[1., 2., 3., 4.], &[1, 1, 2, 2]).set_requires_grad(true);
    let a = &x * 1.0; // an intermediate tensor, as a tap is
    let z = a.conv2d(
        &t(&[2.0], &[1, 1, 1, 1]),
        None::<Tensor>,
        [1, 1],
        [0, 0],
        [1, 1],
        1,
    );
    let mask = t(&[1., 0., 0., 0.], &[2, 2]);
    let s = (z.squeeze() * mask).sum(Kind::Double);
    let g = Tensor::run_backward(&[&s], &[&a], false, false);
    let l = gradcam_pp(&a.get(0).detach(), &g[0].get(0));
    let v: Vec<f64> = Vec::try_from(l.view([-1])).unwrap();
    for (x, want) in v.iter().zip([1.0, 2.0, 3.0, 4.0]) {
        assert!((x - want / 11.0).abs() < 1e-7, "{v:?}");
    }
}

#[test]
fn evidence_gradient_matches_finite_differences() {
    tch::manual_seed(5);
    let opt = (Kind::Double, Device::Cpu);
    let w1 = Tensor::randn([4, 2, 3, 3], opt).set_requires_grad(true);
    let w2 = Tensor::randn([8, 4, 1, 1], opt).set_requires_grad(true);
    let x = Tensor::randn([1, 2, 6, 6], opt);
    let a = x
        .conv2d(&w1, None::<Tensor>, [1, 1], [1, 1], [1, 1], 1)
        .relu(); // the tapped layer
    let sid = SidConfig {
        bins: 4,
        ..SidConfig::default()
    };
    let gt = Tensor::rand([12, 12], (Kind::Double, Device::Cpu)) * 80.0;
    let d = 20.0;
    let ch = channels_at(&sid, d, 0.5);
    let mask = band_mask(&gt, d, 0.5);
    assert!(mask.sum(Kind::Double).double_value(&[]) > 0.0);
    let head = |a: &Tensor| -> Tensor {
        let y = a
            .conv2d(&w2, None::<Tensor>, [1, 1], [0, 0], [1, 1], 1)
            .tanh();
        let z = ordinal::upsample(&ordinal::pair_differences(&y), 12, 12, true);
        evidence(&z, &mask, &ch)
    };
    let s = head(&a);
    let g = Tensor::run_backward(&[&s], &[&a], false, false).remove(0);
    let a0 = a.detach();
    // libtorch's CPU kernels leave ~1e-9 relative noise on S; a smooth head (tanh) and a
    // central difference with ε = 1e-2 keep truncation and noise below the tolerance.
    let eps = 1e-2;
    for idx in [[0, 0, 0, 0], [0, 1, 2, 3], [0, 3, 5, 5], [0, 2, 4, 1]] {
        let mut ev = vec![0f64; 4 * 36];
        ev[(idx[1] * 36 + idx[2] * 6 + idx[3]) as usize] = eps;
        let e = Tensor::from_slice(&ev).view([1, 4, 6, 6]);
        let fd = (head(&(&a0 + &e)).double_value(&[]) - head(&(&a0 - &e)).double_value(&[]))
            / (2.0 * eps);
        let an = g.double_value(&idx);
        assert!(
            (fd - an).abs() <= 1e-3 * (1.0 + an.abs()),
            "{idx:?}: fd {fd} vs autograd {an}"
        );
    }
}

#[test]
fn thresholds_at_a_distance_lie_in_the_band() {
    let s = SidConfig::default();
    let t = sid::thresholds_m(&s);
    for d in [35.0, 55.0, 70.0] {
        let ch = channels_at(&s, d, 0.1);
        assert!(!ch.is_empty());
        for &k in &ch {
            let ti = t[k as usize + 1];
            assert!(ti >= 0.9 * d && ti <= 1.1 * d, "{d}: t {ti}");
        }
        // the neighbours just outside are outside the band
        let lo = t[ch[0] as usize];
        let hi = t
            .get(*ch.last().unwrap() as usize + 2)
            .copied()
            .unwrap_or(f64::INFINITY);
        assert!(lo < 0.9 * d && hi > 1.1 * d);
    }
    // heat fraction: all heat on band pixels → 1; chance = band / GT pixels
    let gt = [35.0f32, 10.0, 0.0, 36.0];
    let heat = [1.0f32, 0.0, 1.0, 1.0];
    let (f, chance, nb, ng) = heat_fraction(&heat, &gt, 35.0, 0.1);
    assert_eq!((f, nb, ng), (Some(1.0), 2, 3));
    assert!((chance - 2.0 / 3.0).abs() < 1e-12);
}
