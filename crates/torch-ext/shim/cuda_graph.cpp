// CUDA graphs for fixed-shape inference (issue 44): libtorch's at::cuda::CUDAGraph, which tch
// 0.24 does not reach. Compiled with DSX_CUDA_GRAPHS (feature `cuda-graphs`: the CUDA runtime
// headers of the torch wheel's nvidia-* packages, as crates/dist's NCCL build); without it every
// function is a stub and dsx_cuda_graphs_built() says so, so callers run eagerly.
#include <cstring>
#include <exception>

#ifdef DSX_CUDA_GRAPHS
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAFunctions.h>
#include <c10/cuda/CUDAStream.h>

#include <optional>

struct DsxGraph {
  at::cuda::CUDAGraph graph;
  // The stream that was current before the capture, which ran on a side stream of the pool (a
  // graph cannot be captured on the default stream); set from capture_begin to capture_end.
  // (No CUDAStreamGuard: its inline functions call the CUDA runtime, which this shim does not
  // link; c10_cuda's functions do.)
  std::optional<c10::cuda::CUDAStream> previous;
};
#else
struct DsxGraph {};
#endif

extern "C" {

bool dsx_cuda_graphs_built() {
#ifdef DSX_CUDA_GRAPHS
  return true;
#else
  return false;
#endif
}

#ifdef DSX_CUDA_GRAPHS
// The stream that was current before the capture, current again.
static void restore(DsxGraph* g) {
  if (g->previous) {
    c10::cuda::setCurrentCUDAStream(*g->previous);
    g->previous.reset();
  }
}
#endif

static int fail(char** err, const char* what) {
  *err = strdup(what);
  return 1;
}

DsxGraph* dsx_graph_new() { return new DsxGraph(); }

void dsx_graph_free(DsxGraph* g) { delete g; }

// Begins capturing the work this thread queues on `device` from now on, on a side stream of
// the pool. 0, or 1 with a malloc'ed message in *err.
int dsx_graph_capture_begin(DsxGraph* g, int device, char** err) {
#ifdef DSX_CUDA_GRAPHS
  try {
    auto index = static_cast<c10::DeviceIndex>(device);
    auto side = c10::cuda::getStreamFromPool(false, index);
    // Everything queued so far (the warm-up, the static inputs' copies) done first.
    c10::cuda::device_synchronize();
    g->previous = c10::cuda::getCurrentCUDAStream(index);
    c10::cuda::setCurrentCUDAStream(side);
    g->graph.capture_begin();
    return 0;
  } catch (const std::exception& e) {
    restore(g);
    return fail(err, e.what());
  }
#else
  (void)g;
  (void)device;
  return fail(err, "built without CUDA graphs (feature cuda-graphs)");
#endif
}

// Ends the capture and instantiates the graph; the previous stream is current again.
int dsx_graph_capture_end(DsxGraph* g, char** err) {
#ifdef DSX_CUDA_GRAPHS
  try {
    g->graph.capture_end();
    restore(g);
    return 0;
  } catch (const std::exception& e) {
    restore(g);
    return fail(err, e.what());
  }
#else
  (void)g;
  return fail(err, "built without CUDA graphs (feature cuda-graphs)");
#endif
}

// Replays the captured work on the current stream.
int dsx_graph_replay(DsxGraph* g, char** err) {
#ifdef DSX_CUDA_GRAPHS
  try {
    g->graph.replay();
    return 0;
  } catch (const std::exception& e) {
    return fail(err, e.what());
  }
#else
  (void)g;
  return fail(err, "built without CUDA graphs (feature cuda-graphs)");
#endif
}

}  // extern "C"
