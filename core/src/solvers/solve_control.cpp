#include "muscle_deformation/core/solvers/solve_control.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace muscle_deformation {
namespace {

// Strain histogram for a percentile in one pass without sorting: the bin of a positive double is its exponent and its
// four leading mantissa bits (bits 48-63 of its IEEE 754 pattern, monotone in the value), so every octave is cut into
// 16 bins. Strains from 2^-40 to 2^40 have bins of their own; smaller ones share the first, larger ones the last.
class StrainHistogram {
 public:
  void add(double strain) {
    std::size_t bin = 0;
    if (strain > 0) {
      const std::uint64_t key = bitsOf(strain) >> 48;
      bin = key <= kFirstKey ? 0 : std::min<std::uint64_t>(key - kFirstKey, kBins - 1);
    }
    ++counts_[bin];
    ++total_;
  }
  // Counts are whole numbers: merging per-thread histograms gives the same histogram in any order.
  void merge(const StrainHistogram& other) {
    for (std::size_t bin = 0; bin < kBins; ++bin) counts_[bin] += other.counts_[bin];
    total_ += other.total_;
  }
  // Upper edge of the bin holding the given quantile (clamped to the largest value seen by the caller).
  double quantileUpperBound(double quantile) const {
    const auto wanted = static_cast<std::uint64_t>(std::ceil(quantile * static_cast<double>(total_)));
    std::uint64_t seen = 0;
    for (std::size_t bin = 0; bin < kBins; ++bin) {
      seen += counts_[bin];
      if (seen >= wanted && seen > 0) return valueOf((kFirstKey + bin + 1) << 48);
    }
    return std::numeric_limits<double>::infinity();
  }

 private:
  static std::uint64_t bitsOf(double value) {
    std::uint64_t bits;
    std::memcpy(&bits, &value, sizeof bits);
    return bits;
  }
  static double valueOf(std::uint64_t bits) {
    double value;
    std::memcpy(&value, &bits, sizeof value);
    return value;
  }
  static constexpr std::size_t kBins = 80 * 16;
  static inline const std::uint64_t kFirstKey = bitsOf(std::ldexp(1.0, -40)) >> 48;
  std::array<std::uint32_t, kBins> counts_{};
  std::uint64_t total_ = 0;
};

}  // namespace

std::string validate(const StoppingSettings& stopping) {
  if (stopping.max_iterations < 0) return "max_iterations must be >= 0";
  if (!(stopping.displacement_tolerance_m >= 0) || !(stopping.residual_tolerance >= 0) ||
      !(stopping.time_budget_ms >= 0) || !std::isfinite(stopping.displacement_tolerance_m) ||
      !std::isfinite(stopping.residual_tolerance) || !std::isfinite(stopping.time_budget_ms))
    return "tolerances and the time budget must be finite and non-negative";
  return {};
}

StoppingSettings afterTimeSpent(StoppingSettings stopping, double spent_ms) {
  spent_ms = std::max(0.0, spent_ms);
  stopping.time_budget_ms = std::max(0.0, stopping.time_budget_ms - spent_ms);
  if (stopping.limits.wall_time_limit_ms > 0)
    stopping.limits.wall_time_limit_ms =
        std::max(stopping.limits.wall_time_limit_ms - spent_ms, std::numeric_limits<double>::min());
  return stopping;
}

SpringMetrics measureSprings(const SpringSet& springs, const Eigen::Matrix3Xd& position, int threads) {
  SpringMetrics metrics;
  if (springs.size() == 0) return metrics;
  // Every frame measures all its springs (a third of a million in the bundled scene, a fifth of a sweep's time when
  // serial): the threads share fixed chunks, whose sums are added in chunk order, so the figures do not depend on the
  // thread count.
  constexpr std::size_t kChunk = 4096;
  const std::size_t chunks = (springs.size() + kChunk - 1) / kChunk;
  std::vector<double> deviation(chunks, 0.0), rest_sum(chunks, 0.0), strain_sum(chunks, 0.0), max_strain(chunks, 0.0);
  const int thread_count = std::max(1, std::min<int>(threads, static_cast<int>(chunks)));
  std::vector<StrainHistogram> histograms(static_cast<std::size_t>(thread_count));
#pragma omp parallel num_threads(thread_count)
  {
#ifdef _OPENMP
    StrainHistogram& histogram = histograms[static_cast<std::size_t>(omp_get_thread_num())];
#else
    StrainHistogram& histogram = histograms.front();
#endif
#pragma omp for schedule(static)
    for (std::size_t chunk = 0; chunk < chunks; ++chunk) {
      const std::size_t end = std::min(springs.size(), (chunk + 1) * kChunk);
      for (std::size_t s = chunk * kChunk; s < end; ++s) {
        const auto e = static_cast<Eigen::Index>(s);
        // Against the segmented shape: a pre-tensioned belly's springs rest shorter than they are at rest.
        const double rest = segmentedLength(springs, e);
        const double length = (position.col(springs.second[s]) - position.col(springs.first[s])).norm();
        const double change = std::abs(length - rest);
        const double strain = change / rest;
        deviation[chunk] += change;
        rest_sum[chunk] += rest;
        strain_sum[chunk] += strain;
        max_strain[chunk] = std::max(max_strain[chunk], strain);
        histogram.add(strain);
      }
    }
  }
  double deviation_total = 0, rest_total = 0, strain_total = 0;
  for (std::size_t chunk = 0; chunk < chunks; ++chunk) {
    deviation_total += deviation[chunk];
    rest_total += rest_sum[chunk];
    strain_total += strain_sum[chunk];
    metrics.max_strain = std::max(metrics.max_strain, max_strain[chunk]);
  }
  StrainHistogram histogram;
  for (const StrainHistogram& part : histograms) histogram.merge(part);
  metrics.deviation_ratio = deviation_total / rest_total;
  metrics.mean_strain = strain_total / static_cast<double>(springs.size());
  metrics.strain_p99 = std::min(histogram.quantileUpperBound(0.99), metrics.max_strain);
  return metrics;
}

void recordSpringMetrics(const SpringSet& springs, const Eigen::Matrix3Xd& position, SolveStats& stats, int threads) {
  const SpringMetrics metrics = measureSprings(springs, position, threads);
  stats.spring_deviation_ratio = metrics.deviation_ratio;
  stats.mean_strain = metrics.mean_strain;
  stats.max_strain = metrics.max_strain;
  stats.strain_p99 = metrics.strain_p99;
}

}  // namespace muscle_deformation
