// Wall-clock milliseconds since construction: the per-stage times of FrameStats::ms.
#pragma once

#include <chrono>

namespace line_odom {

class Stopwatch {
 public:
  Stopwatch() : start_(std::chrono::steady_clock::now()) {}
  double ms() const {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace line_odom
