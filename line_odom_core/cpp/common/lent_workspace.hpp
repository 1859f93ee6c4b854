// Work buffers kept per thread between calls (a full-resolution frame needs a few MB, which freshly allocated would
// cost page faults on every frame) and lent to one call as a local: a local's buffers the compiler keeps in
// registers, a thread_local's it reloads. They go back when the call returns, by any path.
#pragma once

#include <utility>

namespace line_odom {

template <typename Workspace>
class LentWorkspace {
 public:
  LentWorkspace() : ws_(std::move(kept())) {}
  ~LentWorkspace() { kept() = std::move(ws_); }
  LentWorkspace(const LentWorkspace&) = delete;
  LentWorkspace& operator=(const LentWorkspace&) = delete;

  Workspace& operator*() { return ws_; }

 private:
  static Workspace& kept() {
    thread_local Workspace workspace;
    return workspace;
  }
  Workspace ws_;
};

}  // namespace line_odom
