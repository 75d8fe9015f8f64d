//! `torch-ext` (its tests live here: one libtorch-linked test executable fewer to build; issue
//! 35): pinned copies and CUDA autocast through the shim.

use depthsense_torch_ext::{cuda_autocast, cuda_autocast_state, pin_memory};
use tch::{Device, Kind, Tensor};

#[test]
fn autocast_region_sets_and_restores_the_cuda_state() {
    let before = cuda_autocast_state();
    assert!(!before.0, "autocast is off outside a region");
    let (inner, nested) = cuda_autocast(Kind::BFloat16, || {
        let inner = cuda_autocast_state();
        let nested = cuda_autocast(Kind::Half, cuda_autocast_state);
        (inner, nested)
    });
    assert_eq!(inner, (true, Kind::BFloat16));
    assert_eq!(nested, (true, Kind::Half));
    assert_eq!(
        cuda_autocast_state(),
        before,
        "the state before the region is back"
    );
}

#[test]
fn pin_memory_pins_on_cuda_and_is_an_error_without_it() {
    let t = Tensor::from_slice(&[1.0f32, 2.0, 3.0]);
    match pin_memory(&t) {
        Ok(p) => {
            assert!(tch::Cuda::is_available(), "pinned without an accelerator");
            assert_eq!(Vec::<f32>::try_from(&p).unwrap(), vec![1.0, 2.0, 3.0]);
            let on_gpu = p.to_device_(Device::Cuda(0), Kind::Float, true, false);
            assert_eq!(
                Vec::<f32>::try_from(&on_gpu.to_device(Device::Cpu)).unwrap(),
                vec![1.0, 2.0, 3.0]
            );
        }
        Err(e) => {
            assert!(
                !tch::Cuda::is_available(),
                "pin_memory failed with CUDA present: {e}"
            );
            assert!(!e.to_string().is_empty());
        }
    }
}

#[test]
fn a_nonblocking_copy_arrives_whole_pinned_or_not() {
    let t = Tensor::from_slice(&[1.5f32, -2.0, 3.25]).view([1, 3]);
    let device = if tch::Cuda::is_available() {
        Device::Cuda(0)
    } else {
        Device::Cpu // no pinned memory: the blocking fall-back
    };
    let d = depthsense_torch_ext::to_device_nonblocking(&t, device);
    assert_eq!(d.device(), device);
    assert_eq!(d.size(), [1, 3]);
    let back = Vec::<f32>::try_from(d.to_device(Device::Cpu).view([-1])).unwrap();
    assert_eq!(back, vec![1.5, -2.0, 3.25]);
}
