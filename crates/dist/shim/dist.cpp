// depthsense-dist: a C ABI over PyTorch's own distributed engine (c10d) in the
// libtorch that tch links: TCPStore rendezvous, ProcessGroupGloo (CPU) and,
// when built with DSD_NCCL, ProcessGroupNCCL (CUDA); all-reduce, broadcast,
// barrier, and an autograd-aware all-reduce (sum forward, sum of gradients
// backward) for SyncBatchNorm.
//
// Errors: functions return 0 / non-null on success; on failure the message is
// kept per thread and read with dsd_last_error(). A failed collective appends
// which peer stopped, found from per-rank heartbeats kept in the TCPStore.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <torch/csrc/autograd/custom_function.h>
#include <torch/csrc/distributed/c10d/PrefixStore.hpp>
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#include <torch/csrc/distributed/c10d/TCPStore.hpp>
#ifdef DSD_NCCL
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#endif

namespace {

using Ms = std::chrono::milliseconds;

thread_local std::string g_last_error;

constexpr Ms kHeartbeat{250};
const char* kHbPrefix = "hb/";
const char* kJoinPrefix = "joined/";

struct Group {
  // Key namespace in the store ("depthsense/<restart>/"): torchrun's agent store outlives
  // worker restarts.
  std::string ns;
  int rank = 0;
  int world = 1;
  std::string host;
  int port = 0;
  Ms timeout{0};
  std::string backend_name;
  c10::intrusive_ptr<c10d::TCPStore> store;
  c10::intrusive_ptr<c10d::TCPStore> hb_store;
  c10::intrusive_ptr<c10d::Backend> backend;
  std::thread hb;
  std::mutex m;
  std::condition_variable cv;
  bool stop = false;
  int device = -1;
};

c10::intrusive_ptr<c10d::TCPStore> client(const Group& g, Ms timeout) {
  c10d::TCPStoreOptions o;
  o.port = static_cast<std::uint16_t>(g.port);
  o.isServer = false;
  o.waitWorkers = false;
  o.timeout = timeout;
  return c10::make_intrusive<c10d::TCPStore>(g.host, o);
}

std::string key(const Group& g, const char* prefix, int rank) {
  return g.ns + prefix + std::to_string(rank);
}

void heartbeat_loop(Group* g) {
  std::int64_t beat = 0;
  std::unique_lock<std::mutex> lk(g->m);
  while (!g->stop) {
    try {
      std::string v = std::to_string(++beat);
      g->hb_store->set(
          key(*g, kHbPrefix, g->rank),
          std::vector<uint8_t>(v.begin(), v.end()));
    } catch (...) {
      // The store host is gone; a collective will report it.
    }
    g->cv.wait_for(lk, kHeartbeat, [g] { return g->stop; });
  }
}

std::string read_beat(const Group& g, c10d::Store& s, int r) {
  auto k = key(g, kHbPrefix, r);
  if (!s.check({k})) {
    return "";
  }
  auto v = s.get(k);
  return std::string(v.begin(), v.end());
}

// Which peer stopped: heartbeats that do not advance over ~8 beats.
std::string diagnose(Group* g) {
  std::ostringstream out;
  try {
    auto s = client(*g, Ms(3000));
    std::vector<std::string> a(g->world), b(g->world);
    for (int r = 0; r < g->world; ++r) {
      a[r] = read_beat(*g, *s, r);
    }
    std::this_thread::sleep_for(kHeartbeat * 8);
    for (int r = 0; r < g->world; ++r) {
      b[r] = read_beat(*g, *s, r);
    }
    std::vector<int> dead;
    for (int r = 0; r < g->world; ++r) {
      if (r != g->rank && a[r] == b[r]) {
        dead.push_back(r);
      }
    }
    if (dead.empty()) {
      out << "every peer still beats (heartbeats advance): a peer is slow, "
             "hung in a collective, or failed its own step";
    } else {
      out << (dead.size() == 1 ? "rank " : "ranks ");
      for (size_t i = 0; i < dead.size(); ++i) {
        out << (i ? ", " : "") << dead[i];
      }
      out << (dead.size() == 1 ? " has" : " have")
          << " stopped (no heartbeat for "
          << (kHeartbeat * 8).count() / 1000.0
          << " s): it exited, was killed or hangs";
    }
  } catch (const std::exception& e) {
    if (g->rank == 0) {
      out << "the rendezvous store on this rank is unreachable";
    } else {
      out << "rank 0 (host of the rendezvous store at " << g->host << ":"
          << g->port << ") is unreachable: it exited or was killed";
    }
  }
  return out.str();
}

std::string first_line(const std::string& s) {
  auto p = s.find('\n');
  return p == std::string::npos ? s : s.substr(0, p);
}

void wait_all(
    Group* g,
    std::vector<c10::intrusive_ptr<c10d::Work>>& works,
    const char* what) {
  try {
    for (auto& w : works) {
      if (!w->wait(g->timeout)) {
        throw std::runtime_error("timed out");
      }
    }
  } catch (const std::exception& e) {
    std::ostringstream msg;
    msg << what << " on rank " << g->rank << " of " << g->world << " ("
        << g->backend_name << ", timeout " << g->timeout.count() / 1000.0
        << " s) failed: " << first_line(e.what()) << "; " << diagnose(g);
    throw std::runtime_error(msg.str());
  }
}

void check_tensors(const std::vector<at::Tensor>& ts) {
  for (const auto& t : ts) {
    if (!t.defined()) {
      throw std::runtime_error("undefined tensor given to a collective");
    }
    if (!t.is_contiguous()) {
      throw std::runtime_error("collectives need contiguous tensors");
    }
  }
}

void allreduce_inplace(Group* g, std::vector<at::Tensor>& ts, bool average) {
  check_tensors(ts);
  std::vector<c10::intrusive_ptr<c10d::Work>> works;
  works.reserve(ts.size());
  for (auto& t : ts) {
    std::vector<at::Tensor> one{t};
    c10d::AllreduceOptions o;
    o.reduceOp = c10d::ReduceOp::SUM;
    o.timeout = g->timeout;
    works.push_back(g->backend->allreduce(one, o));
  }
  wait_all(g, works, "all-reduce");
  if (average && g->world > 1) {
    at::NoGradGuard ng;
    for (auto& t : ts) {
      t.div_(static_cast<double>(g->world));
    }
  }
}

// Autograd-aware all-reduce: y = Σ_ranks x forward, dx = Σ_ranks dy backward.
struct AllReduceSum : public torch::autograd::Function<AllReduceSum> {
  static at::Tensor forward(
      torch::autograd::AutogradContext* ctx,
      const at::Tensor& x,
      int64_t group) {
    ctx->saved_data["group"] = group;
    auto y = x.detach().clone(at::MemoryFormat::Contiguous);
    std::vector<at::Tensor> ts{y};
    allreduce_inplace(reinterpret_cast<Group*>(group), ts, false);
    return y;
  }
  static torch::autograd::variable_list backward(
      torch::autograd::AutogradContext* ctx,
      torch::autograd::variable_list grads) {
    auto* g = reinterpret_cast<Group*>(ctx->saved_data["group"].toInt());
    auto dy = grads[0].detach().clone(at::MemoryFormat::Contiguous);
    std::vector<at::Tensor> ts{dy};
    allreduce_inplace(g, ts, false);
    return {dy, at::Tensor()};
  }
};

std::vector<at::Tensor> tensors_of(void** ts, int n) {
  std::vector<at::Tensor> out;
  out.reserve(n);
  for (int i = 0; i < n; ++i) {
    out.push_back(*reinterpret_cast<at::Tensor*>(ts[i]));
  }
  return out;
}

template <typename F>
int guarded(F f) {
  try {
    f();
    return 0;
  } catch (const std::exception& e) {
    g_last_error = e.what();
  } catch (...) {
    g_last_error = "unknown C++ exception";
  }
  return -1;
}

void wait_joined(Group* g) {
  std::string k = key(*g, kJoinPrefix, g->rank);
  g->store->set(k, std::vector<uint8_t>{'1'});
  std::vector<std::string> keys;
  for (int r = 0; r < g->world; ++r) {
    keys.push_back(key(*g, kJoinPrefix, r));
  }
  auto deadline = std::chrono::steady_clock::now() + g->timeout;
  while (true) {
    std::vector<int> missing;
    for (int r = 0; r < g->world; ++r) {
      if (!g->store->check({keys[r]})) {
        missing.push_back(r);
      }
    }
    if (missing.empty()) {
      return;
    }
    if (std::chrono::steady_clock::now() > deadline) {
      std::ostringstream msg;
      msg << "rendezvous at MASTER_ADDR=" << g->host
          << " MASTER_PORT=" << g->port << ": "
          << (missing.size() == 1 ? "rank " : "ranks ");
      for (size_t i = 0; i < missing.size(); ++i) {
        msg << (i ? ", " : "") << missing[i];
      }
      msg << " of WORLD_SIZE=" << g->world << " did not join within "
          << g->timeout.count() / 1000.0
          << " s (were all processes started with the same MASTER_ADDR, "
             "MASTER_PORT and WORLD_SIZE?)";
      throw std::runtime_error(msg.str());
    }
    std::this_thread::sleep_for(Ms(20));
  }
}

bool is_loopback(const std::string& h) {
  return h == "localhost" || h == "::1" || h.rfind("127.", 0) == 0;
}

} // namespace

extern "C" {

const char* dsd_last_error() {
  return g_last_error.c_str();
}

int dsd_has_nccl() {
#ifdef DSD_NCCL
  return 1;
#else
  return 0;
#endif
}

// backend: 0 = Gloo, 1 = NCCL. is_server: this rank hosts the TCPStore (rank 0,
// unless torchrun's agent already does). ns: key namespace. Returns NULL on error.
void* dsd_init(
    const char* host,
    int port,
    int rank,
    int world,
    long long timeout_ms,
    int backend,
    int device,
    int is_server,
    const char* ns) {
  auto* g = new Group();
  g->ns = ns;
  g->rank = rank;
  g->world = world;
  g->host = host;
  g->port = port;
  g->timeout = Ms(timeout_ms);
  g->device = device;
  int rc = guarded([&] {
    c10d::TCPStoreOptions o;
    o.port = static_cast<std::uint16_t>(port);
    o.isServer = is_server != 0;
    o.numWorkers = world;
    o.waitWorkers = false;
    o.timeout = g->timeout;
    try {
      g->store = c10::make_intrusive<c10d::TCPStore>(g->host, o);
    } catch (const std::exception& e) {
      std::ostringstream msg;
      msg << "rendezvous: rank " << rank << " of WORLD_SIZE=" << world
          << (is_server ? " cannot host" : " cannot reach")
          << " the TCPStore at MASTER_ADDR=" << g->host
          << " MASTER_PORT=" << port << " within "
          << g->timeout.count() / 1000.0 << " s: " << first_line(e.what());
      if (!is_server) {
        msg << " (is rank 0 (or torchrun's agent) running, and MASTER_ADDR/MASTER_PORT "
               "right?)";
      } else {
        msg << " (is MASTER_PORT free?)";
      }
      throw std::runtime_error(msg.str());
    }
    wait_joined(g);
    g->hb_store = client(*g, Ms(3000));
    g->hb = std::thread(heartbeat_loop, g);
    auto prefixed =
        c10::make_intrusive<c10d::PrefixStore>(g->ns + "pg", g->store);
    if (backend == 1) {
#ifdef DSD_NCCL
      auto opts = c10d::ProcessGroupNCCL::Options::create();
      opts->timeout = g->timeout;
      g->backend =
          c10::make_intrusive<c10d::ProcessGroupNCCL>(prefixed, rank, world, opts);
      g->backend_name = "nccl";
#else
      throw std::runtime_error(
          "this build has no NCCL backend (build depthsense with "
          "`--features nccl` against a CUDA libtorch)");
#endif
    } else {
      auto opts = c10d::ProcessGroupGloo::Options::create(g->timeout);
      const char* ifname = std::getenv("GLOO_SOCKET_IFNAME");
      if (ifname && *ifname) {
        std::string names(ifname);
        size_t start = 0;
        while (start <= names.size()) {
          size_t end = names.find(',', start);
          if (end == std::string::npos) {
            end = names.size();
          }
          if (end > start) {
            opts->devices.push_back(
                c10d::ProcessGroupGloo::createDeviceForInterface(
                    names.substr(start, end - start)));
          }
          start = end + 1;
        }
      } else if (is_loopback(g->host)) {
        opts->devices.push_back(
            c10d::ProcessGroupGloo::createDeviceForHostname("127.0.0.1"));
      } else {
        opts->devices.push_back(
            c10d::ProcessGroupGloo::createDefaultDevice());
      }
      opts->threads = 2;
      try {
        g->backend = c10::make_intrusive<c10d::ProcessGroupGloo>(
            prefixed, rank, world, opts);
      } catch (const std::exception& e) {
        std::ostringstream msg;
        msg << "Gloo connection of rank " << rank << " of " << world
            << " failed: " << first_line(e.what()) << "; " << diagnose(g);
        throw std::runtime_error(msg.str());
      }
      g->backend_name = "gloo";
    }
  });
  if (rc != 0) {
    if (g->hb.joinable()) {
      {
        std::lock_guard<std::mutex> lk(g->m);
        g->stop = true;
      }
      g->cv.notify_all();
      g->hb.join();
    }
    delete g;
    return nullptr;
  }
  return g;
}

// A bare TCPStore server, as torchrun's agent hosts one (tests, launchers).
void* dsd_store_host(const char* host, int port, long long timeout_ms) {
  c10::intrusive_ptr<c10d::TCPStore>* out = nullptr;
  guarded([&] {
    c10d::TCPStoreOptions o;
    o.port = static_cast<std::uint16_t>(port);
    o.isServer = true;
    o.waitWorkers = false;
    o.timeout = Ms(timeout_ms);
    out = new c10::intrusive_ptr<c10d::TCPStore>(
        c10::make_intrusive<c10d::TCPStore>(host, o));
  });
  return out;
}

void dsd_store_free(void* p) {
  delete static_cast<c10::intrusive_ptr<c10d::TCPStore>*>(p);
}

void dsd_free(void* p) {
  auto* g = static_cast<Group*>(p);
  if (!g) {
    return;
  }
  {
    std::lock_guard<std::mutex> lk(g->m);
    g->stop = true;
  }
  g->cv.notify_all();
  if (g->hb.joinable()) {
    g->hb.join();
  }
  try {
    g->backend.reset();
    g->hb_store.reset();
    g->store.reset();
  } catch (...) {
  }
  delete g;
}

const char* dsd_backend_name(void* p) {
  return static_cast<Group*>(p)->backend_name.c_str();
}

int dsd_allreduce(void* p, void** ts, int n, int average) {
  return guarded([&] {
    auto v = tensors_of(ts, n);
    allreduce_inplace(static_cast<Group*>(p), v, average != 0);
  });
}

int dsd_broadcast(void* p, void** ts, int n, int root) {
  return guarded([&] {
    auto* g = static_cast<Group*>(p);
    auto v = tensors_of(ts, n);
    check_tensors(v);
    std::vector<c10::intrusive_ptr<c10d::Work>> works;
    for (auto& t : v) {
      std::vector<at::Tensor> one{t};
      c10d::BroadcastOptions o;
      o.rootRank = root;
      o.timeout = g->timeout;
      works.push_back(g->backend->broadcast(one, o));
    }
    wait_all(g, works, "broadcast");
  });
}

int dsd_barrier(void* p) {
  return guarded([&] {
    auto* g = static_cast<Group*>(p);
    c10d::BarrierOptions o;
    o.timeout = g->timeout;
    if (g->backend_name == "nccl" && g->device >= 0) {
      o.device_ids = {g->device};
    }
    std::vector<c10::intrusive_ptr<c10d::Work>> works{g->backend->barrier(o)};
    wait_all(g, works, "barrier");
  });
}

// Σ over ranks of `t`, differentiable (backward all-reduces the gradient).
// Returns a new tensor handle owned by the caller, NULL on error.
void* dsd_allreduce_autograd(void* p, void* t) {
  at::Tensor out;
  int rc = guarded([&] {
    out = AllReduceSum::apply(
        *reinterpret_cast<at::Tensor*>(t), reinterpret_cast<int64_t>(p));
  });
  if (rc != 0) {
    return nullptr;
  }
  return new at::Tensor(std::move(out));
}

} // extern "C"
