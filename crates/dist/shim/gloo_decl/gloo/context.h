// Minimal stand-in for <gloo/context.h> (see algorithm.h): the one member an
// inline function of ProcessGroupGloo.hpp (setTimeout) names.
#pragma once
#include <chrono>
namespace gloo {
class Context {
 public:
  void setTimeout(std::chrono::milliseconds timeout);
};
} // namespace gloo
