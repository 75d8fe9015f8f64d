//! What libtorch 2.11 has and tch 0.24 reaches only through deprecated calls, through a small C++
//! shim (`shim/torch_ext.cpp`): a pinned host copy without the deprecated `device` argument
//! ([`pin_memory`]) and CUDA autocast through the device-typed API ([`cuda_autocast`]). tch's
//! `Tensor::pin_memory(device)` and `tch::autocast` log a libtorch deprecation warning on every
//! call — hundreds of lines a minute in a GPU training log (first H200 run, 2026-12-04).

pub mod cuda_graph;

use std::ffi::{c_char, c_void, CStr};

use tch::{Device, Kind, TchError, Tensor};
use torch_sys::C_tensor;

extern "C" {
    fn dsx_pin_memory(t: *const C_tensor, err: *mut *mut c_char) -> *mut C_tensor;
    fn dsx_autocast_cuda_enabled() -> bool;
    fn dsx_autocast_cuda_set(enabled: bool, dtype: i8);
    fn dsx_autocast_cuda_dtype() -> i8;
    fn dsx_autocast_increment_nesting() -> i32;
    fn dsx_autocast_decrement_nesting() -> i32;
    fn dsx_autocast_clear_cache();
    fn free(p: *mut c_void);
}

/// `t` copied into pinned (page-locked) host memory for the current accelerator, ready for a
/// non-blocking copy to it. Fails without an accelerator (libtorch has no pinned allocator then).
pub fn pin_memory(t: &Tensor) -> Result<Tensor, TchError> {
    let mut err: *mut c_char = std::ptr::null_mut();
    // SAFETY: `t.as_ptr()` is a live `at::Tensor*` for the call; the shim returns a new
    // `at::Tensor*` (owned by the returned Tensor, freed by tch) or null with a malloc'ed message.
    let ptr = unsafe { dsx_pin_memory(t.as_ptr(), &mut err) };
    if ptr.is_null() {
        let msg = if err.is_null() {
            "pin_memory failed".to_string()
        } else {
            // SAFETY: `err` is a NUL-terminated string from strdup, freed once here.
            unsafe {
                let s = CStr::from_ptr(err).to_string_lossy().into_owned();
                free(err.cast());
                s
            }
        };
        return Err(TchError::Torch(msg));
    }
    // SAFETY: a fresh `at::Tensor*` from `new`, owned by nobody else.
    Ok(unsafe { Tensor::from_ptr(ptr) })
}

/// `t` on `device` without blocking the host: copied once into pinned memory, then sent with a
/// non-blocking copy (ordered on the current stream before any kernel that reads it; the
/// caching host allocator keeps the pinned block until the copy is done). Without pinned memory,
/// a blocking copy. Either way `t` has been read when this returns.
pub fn to_device_nonblocking(t: &Tensor, device: Device) -> Tensor {
    match pin_memory(t) {
        Ok(pinned) => pinned.to_device_(device, t.kind(), true, false),
        Err(_) => t.to_device(device),
    }
}

/// The autocast dtypes by their `c10::ScalarType` code (tch keeps its own mapping private).
const AUTOCAST_KINDS: [(Kind, i8); 2] = [(Kind::Half, 5), (Kind::BFloat16, 15)];

/// Runs `f` with CUDA autocast enabled for `dtype` (`Kind::BFloat16` or `Kind::Half`; any other
/// kind runs `f` without autocast), as
/// `torch.autocast("cuda", dtype)` does: the previous state (enabled, dtype) is restored after,
/// and the cast cache is cleared when the outermost autocast region ends. The state is
/// thread-local, and setting it needs no GPU; only CUDA operations read it.
pub fn cuda_autocast<T>(dtype: Kind, f: impl FnOnce() -> T) -> T {
    let Some(&(_, code)) = AUTOCAST_KINDS.iter().find(|(k, _)| *k == dtype) else {
        return f();
    };
    // SAFETY (all calls below): plain functions on libtorch's thread-local autocast state.
    let (prev_enabled, prev_dtype) =
        unsafe { (dsx_autocast_cuda_enabled(), dsx_autocast_cuda_dtype()) };
    unsafe {
        dsx_autocast_cuda_set(true, code);
        dsx_autocast_increment_nesting();
    }
    let out = f();
    unsafe {
        if dsx_autocast_decrement_nesting() == 0 {
            dsx_autocast_clear_cache();
        }
        dsx_autocast_cuda_set(prev_enabled, prev_dtype);
    }
    out
}

/// Whether CUDA autocast is on in this thread, and its dtype (for tests and diagnostics).
pub fn cuda_autocast_state() -> (bool, Kind) {
    // SAFETY: reads libtorch's thread-local autocast state.
    let (on, code) = unsafe { (dsx_autocast_cuda_enabled(), dsx_autocast_cuda_dtype()) };
    let kind = AUTOCAST_KINDS
        .iter()
        .find(|(_, c)| *c == code)
        .map_or(Kind::Float, |(k, _)| *k);
    (on, kind)
}
