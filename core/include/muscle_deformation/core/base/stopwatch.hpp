// Wall time since a start, in milliseconds: what every stage's timing statistics and time limits read.
#pragma once

#include <chrono>

namespace muscle_deformation {

inline double millisecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace muscle_deformation
