// A fixed set of worker threads that runs the independent parts of one frame's work (the rows and column blocks of
// the line fit) next to the calling thread. The threads live as long as the pool, so their thread-local work
// buffers (lent_workspace.hpp) are allocated once, not per frame. Tasks are taken in index order from a shared
// counter; which thread runs a task never changes what it computes, so results do not depend on the thread count.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace line_odom {

class WorkerPool {
 public:
  // threads >= 1: the calling thread plus threads - 1 workers.
  explicit WorkerPool(int threads);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  int threads() const { return static_cast<int>(workers_.size()) + 1; }

  // Runs task(0) ... task(count - 1) on the workers and the calling thread and returns when all have finished.
  // The first exception a task throws is rethrown here (the other tasks still run). Calls from several threads
  // take turns; a task must not call run itself.
  void run(int count, const std::function<void(int)>& task);

 private:
  void work();
  void drain();

  std::vector<std::thread> workers_;
  std::mutex run_mutex_;  // one run at a time
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(int)>* task_ = nullptr;
  int count_ = 0;
  int next_ = 0;
  int unfinished_ = 0;
  std::uint64_t generation_ = 0;
  bool stopping_ = false;
  std::exception_ptr error_;
};

// True when `pool` can run tasks beside the calling thread (null or a single thread: it cannot).
inline bool has_workers(const WorkerPool* pool) { return pool != nullptr && pool->threads() > 1; }

}  // namespace line_odom
