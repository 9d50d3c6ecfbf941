// What the machine a benchmark runs on can do at most, measured in the same run: memory bandwidth (a STREAM-like
// triad a = b + s c over arrays far larger than the caches, on the given number of threads) and floating-point rate (a
// loop of independent multiply-adds per thread, compiled with the same flags as the code it is set beside). A
// kernel's time over max(bytes / bandwidth, flops / rate) says how far it is from the floor this machine sets.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <thread>
#include <vector>

namespace bench {

struct MachineFloor {
  int threads = 1;
  double bandwidth_gbs = 0;  // 10^9 bytes per second, STREAM's counting: 24 bytes per triad element
  double gflops = 0;         // 10^9 double-precision operations per second (a multiply-add counts two)

  // The least time (ms) `bytes` and `flops` can take on this machine.
  double floorMilliseconds(double bytes, double flops) const {
    return 1e3 * std::max(bytes / (bandwidth_gbs * 1e9), flops / (gflops * 1e9));
  }
};

namespace detail {

template <typename Work>
double bestSecondsOnThreads(int threads, int repetitions, Work&& work) {
  double best = 1e300;
  for (int r = 0; r < repetitions; ++r) {
    const auto start = std::chrono::steady_clock::now();
    std::vector<std::thread> workers;
    for (int t = 0; t < threads; ++t) workers.emplace_back([&work, t, threads] { work(t, threads); });
    for (std::thread& worker : workers) worker.join();
    best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  return best;
}

// Keeps a result the compiler would otherwise drop with the loop that made it.
inline void keep(double value) {
  static volatile double sink;
  sink = value;
  (void)sink;  // a volatile store is already kept; this only tells the compiler the variable is meant
}

}  // namespace detail

// Best of five: 3 arrays of 2^25 doubles (256 MiB each, far beyond any cache), each thread its own contiguous slice,
// first touched by the thread that uses it.
inline MachineFloor measureMachineFloor(int threads) {
  threads = std::max(1, threads);
  MachineFloor floor;
  floor.threads = threads;
  constexpr std::size_t kElements = std::size_t{1} << 25;
  std::vector<double> a(kElements), b(kElements), c(kElements);
  const auto slice = [](int t, int count, std::size_t& begin, std::size_t& end) {
    begin = kElements * static_cast<std::size_t>(t) / static_cast<std::size_t>(count);
    end = kElements * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(count);
  };
  detail::bestSecondsOnThreads(threads, 1, [&](int t, int count) {
    std::size_t begin, end;
    slice(t, count, begin, end);
    for (std::size_t i = begin; i < end; ++i) {
      a[i] = 0.0;
      b[i] = 1.0;
      c[i] = 2.0;
    }
  });
  const double triad_s = detail::bestSecondsOnThreads(threads, 5, [&](int t, int count) {
    std::size_t begin, end;
    slice(t, count, begin, end);
    const double scalar = 3.0;
    double* __restrict out = a.data();
    const double* __restrict left = b.data();
    const double* __restrict right = c.data();
    for (std::size_t i = begin; i < end; ++i) out[i] = left[i] + scalar * right[i];
  });
  detail::keep(a[kElements / 2]);
  floor.bandwidth_gbs = 3.0 * sizeof(double) * static_cast<double>(kElements) / triad_s / 1e9;

  // 16 independent chains per thread (enough to cover the multiply-add latency on any current core), 2 flops a step.
  constexpr int kChains = 16;
  constexpr long kSteps = 20'000'000;
  const double fma_s = detail::bestSecondsOnThreads(threads, 3, [&](int, int) {
    double chain[kChains];
    for (int k = 0; k < kChains; ++k) chain[k] = 1.0 + 1e-3 * k;
    const double multiply = 0.999999, add = 1e-7;
    for (long step = 0; step < kSteps; ++step)
      for (int k = 0; k < kChains; ++k) chain[k] = chain[k] * multiply + add;
    double sum = 0;
    for (int k = 0; k < kChains; ++k) sum += chain[k];
    detail::keep(sum);
  });
  floor.gflops = 2.0 * kChains * static_cast<double>(kSteps) * threads / fma_s / 1e9;
  return floor;
}

}  // namespace bench
