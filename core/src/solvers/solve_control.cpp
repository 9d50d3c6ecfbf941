#include "muscle_deformation/core/solvers/solve_control.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>

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

SpringMetrics measureSprings(const SpringSet& springs, const Eigen::Matrix3Xd& position) {
  SpringMetrics metrics;
  if (springs.size() == 0) return metrics;
  double deviation = 0, rest_sum = 0, strain_sum = 0;
  StrainHistogram histogram;
  for (std::size_t s = 0; s < springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    const double rest = springs.rest_length[e];
    const double length = (position.col(springs.second[s]) - position.col(springs.first[s])).norm();
    const double change = std::abs(length - rest);
    const double strain = change / rest;
    deviation += change;
    rest_sum += rest;
    strain_sum += strain;
    metrics.max_strain = std::max(metrics.max_strain, strain);
    histogram.add(strain);
  }
  metrics.deviation_ratio = deviation / rest_sum;
  metrics.mean_strain = strain_sum / static_cast<double>(springs.size());
  metrics.strain_p99 = std::min(histogram.quantileUpperBound(0.99), metrics.max_strain);
  return metrics;
}

void recordSpringMetrics(const SpringSet& springs, const Eigen::Matrix3Xd& position, SolveStats& stats) {
  const SpringMetrics metrics = measureSprings(springs, position);
  stats.spring_deviation_ratio = metrics.deviation_ratio;
  stats.mean_strain = metrics.mean_strain;
  stats.max_strain = metrics.max_strain;
  stats.strain_p99 = metrics.strain_p99;
}

}  // namespace muscle_deformation
