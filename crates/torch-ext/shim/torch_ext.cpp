// libtorch 2.11 calls that tch 0.24 makes only through deprecated overloads, each of which logs a
// deprecation warning per call (found on the first GPU run: > 800 warning lines in 6 minutes).
// `tensor` handles are tch's: an `at::Tensor*` allocated with `new`, freed by tch with `delete`.
#include <ATen/autocast_mode.h>
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <cstring>
#include <exception>

extern "C" {

// `t` copied into pinned (page-locked) host memory for the current accelerator — without the
// deprecated `device` argument of `Tensor::pin_memory(device)`. On error: nullptr and a
// malloc'ed message in *err (freed by the caller with free()).
at::Tensor* dsx_pin_memory(const at::Tensor* t, char** err) {
  try {
    return new at::Tensor(t->pin_memory());
  } catch (const std::exception& e) {
    *err = strdup(e.what());
    return nullptr;
  }
}

// CUDA autocast through the device-typed API (at::autocast::is_enabled / set_enabled, which
// tch::autocast calls, are deprecated). `dtype` is a c10::ScalarType value.
bool dsx_autocast_cuda_enabled() { return at::autocast::is_autocast_enabled(at::kCUDA); }

void dsx_autocast_cuda_set(bool enabled, int8_t dtype) {
  at::autocast::set_autocast_dtype(at::kCUDA, static_cast<at::ScalarType>(dtype));
  at::autocast::set_autocast_enabled(at::kCUDA, enabled);
}

int8_t dsx_autocast_cuda_dtype() {
  return static_cast<int8_t>(at::autocast::get_autocast_dtype(at::kCUDA));
}

int dsx_autocast_increment_nesting() { return at::autocast::increment_nesting(); }

int dsx_autocast_decrement_nesting() { return at::autocast::decrement_nesting(); }

void dsx_autocast_clear_cache() { at::autocast::clear_cache(); }

}  // extern "C"
