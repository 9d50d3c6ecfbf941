// The upper median (the element at size / 2 in sorted order) of a non-empty list: what every stage's median means, so
// that even counts do not average two values and the figures repeat across stages.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

namespace muscle_deformation {

// `values` must not be empty (callers decide what an empty list means).
inline double upperMedian(std::vector<double> values) {
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace muscle_deformation
