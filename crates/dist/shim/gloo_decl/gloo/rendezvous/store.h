// Minimal stand-in for <gloo/rendezvous/store.h> (see ../algorithm.h): the
// interface c10d's inline GlooStore adapter overrides. The shim never creates
// a GlooStore itself (ProcessGroupGloo does, inside libtorch).
#pragma once
#include <chrono>
#include <string>
#include <vector>
namespace gloo {
namespace rendezvous {
class Store {
 public:
  virtual ~Store() = default;
  virtual void set(const std::string& key, const std::vector<char>& data) = 0;
  virtual std::vector<char> get(const std::string& key) = 0;
  virtual void wait(const std::vector<std::string>& keys) = 0;
  virtual void wait(
      const std::vector<std::string>& keys,
      const std::chrono::milliseconds& timeout) = 0;
};
} // namespace rendezvous
} // namespace gloo
