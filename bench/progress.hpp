// A progress line per finished configuration of a long benchmark: what finished, time so far, and the time left
// estimated from the share of the (caller-estimated) work done.
#pragma once

#include <chrono>
#include <cstdio>
#include <string>

namespace bench {

class Progress {
 public:
  // `total_work` in any unit proportional to run time (e.g. particles x iterations).
  Progress(std::string name, double total_work)
      : name_(std::move(name)), total_work_(total_work), start_(std::chrono::steady_clock::now()) {}

  void finished(const std::string& what, double work) {
    done_work_ += work;
    ++done_count_;
    const double elapsed_s = elapsedSeconds();
    const double left_s = done_work_ > 0 ? elapsed_s * (total_work_ - done_work_) / done_work_ : 0.0;
    std::printf("[%s] %d done: %s; elapsed %.0f s, about %.0f s left\n", name_.c_str(), done_count_, what.c_str(),
                elapsed_s, left_s > 0 ? left_s : 0.0);
    std::fflush(stdout);
  }

  double elapsedSeconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::string name_;
  double total_work_;
  double done_work_ = 0;
  int done_count_ = 0;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace bench
