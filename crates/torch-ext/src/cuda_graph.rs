//! CUDA graphs ([`CudaGraph`]): the work a closure queues on a GPU, captured once and replayed
//! with one launch — libtorch's `at::cuda::CUDAGraph` through the shim (`shim/cuda_graph.cpp`).
//! Built with the feature `cuda-graphs`; without it [`built`] is false and capturing fails with
//! that reason, so that a caller runs eagerly.

use std::ffi::{c_char, c_int, c_void, CStr};

use tch::TchError;

#[repr(C)]
struct DsxGraph {
    _private: [u8; 0],
}

extern "C" {
    fn dsx_cuda_graphs_built() -> bool;
    fn dsx_graph_new() -> *mut DsxGraph;
    fn dsx_graph_free(g: *mut DsxGraph);
    fn dsx_graph_capture_begin(g: *mut DsxGraph, device: c_int, err: *mut *mut c_char) -> c_int;
    fn dsx_graph_capture_end(g: *mut DsxGraph, err: *mut *mut c_char) -> c_int;
    fn dsx_graph_replay(g: *mut DsxGraph, err: *mut *mut c_char) -> c_int;
    fn free(p: *mut c_void);
}

/// Whether this build has CUDA graphs (feature `cuda-graphs`).
pub fn built() -> bool {
    // SAFETY: a constant of the shim.
    unsafe { dsx_cuda_graphs_built() }
}

/// The shim's result: Ok, or its message (freed here).
fn check(rc: c_int, err: *mut c_char, what: &str) -> Result<(), TchError> {
    if rc == 0 {
        return Ok(());
    }
    let msg = if err.is_null() {
        "unknown error".to_string()
    } else {
        // SAFETY: `err` is a NUL-terminated string from strdup, freed once here.
        unsafe {
            let s = CStr::from_ptr(err).to_string_lossy().into_owned();
            free(err.cast());
            s
        }
    };
    Err(TchError::Torch(format!("cuda graph {what}: {msg}")))
}

/// A captured CUDA graph; freed (with its private memory pool) when dropped.
pub struct CudaGraph {
    ptr: *mut DsxGraph,
}

impl CudaGraph {
    /// Captures the work `f` queues on CUDA device `device` (a side stream; nothing runs until
    /// [`CudaGraph::replay`]) and returns the graph with `f`'s value — tensors that every replay
    /// rewrites in place. `f` must not synchronise with the host (no `.item()`, no copy to the
    /// CPU) and must take its inputs from tensors that stay alive and keep their shape.
    pub fn capture<T>(device: usize, f: impl FnOnce() -> T) -> Result<(Self, T), TchError> {
        // SAFETY: a new shim object, owned by the returned CudaGraph (freed in Drop).
        let g = CudaGraph {
            ptr: unsafe { dsx_graph_new() },
        };
        let mut err: *mut c_char = std::ptr::null_mut();
        let device = c_int::try_from(device).map_err(|_| TchError::Torch("device index".into()))?;
        // SAFETY: `g.ptr` is live; `err` receives a malloc'ed message on failure.
        check(
            unsafe { dsx_graph_capture_begin(g.ptr, device, &mut err) },
            err,
            "capture",
        )?;
        let out = f();
        let mut err: *mut c_char = std::ptr::null_mut();
        // SAFETY: as above; ends the capture begun on this object.
        check(
            unsafe { dsx_graph_capture_end(g.ptr, &mut err) },
            err,
            "capture end",
        )?;
        Ok((g, out))
    }

    /// Runs the captured work again on the current stream.
    pub fn replay(&self) -> Result<(), TchError> {
        let mut err: *mut c_char = std::ptr::null_mut();
        // SAFETY: `self.ptr` is a captured graph.
        check(
            unsafe { dsx_graph_replay(self.ptr, &mut err) },
            err,
            "replay",
        )
    }
}

impl Drop for CudaGraph {
    fn drop(&mut self) {
        // SAFETY: `ptr` came from dsx_graph_new and is freed once.
        unsafe { dsx_graph_free(self.ptr) }
    }
}
