// Turning fibre polylines into particles (GRAPP 2014 section 3.1).
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <cstdint>
#include <vector>

namespace muscle_deformation {

struct FibreSamples {
  Eigen::Matrix3Xd position = Eigen::Matrix3Xd(3, 0);
  std::vector<std::int32_t> fibre_of;   // index into the input fibre list
  std::vector<std::int32_t> sample_of;  // 0 = fibre start
  std::vector<int> skipped_fibres;      // fibres too short to sample (length below min_fibre_length_m)
};

// N particles per fibre: the first exactly at the fibre start; the fibre is cut into N-1 equal arc-length
// intervals and particle i (1..N-1) is placed at a uniformly random arc length inside interval i. Randomising breaks
// up the clusters that equal spacing produces when fibres have similar lengths (the particles stand for the surface
// in collision detection). Deterministic for a given seed. Repeated points and zero-length segments are harmless.
FibreSamples sampleFibres(const std::vector<Polyline>& fibres, int particles_per_fibre, std::uint32_t seed,
                          double min_fibre_length_m = 1e-6);

// Point at arc length s (metres from the start, clamped to [0, length]) along a polyline.
Eigen::Vector3d pointAtArcLength(const Polyline& line, double s);

}  // namespace muscle_deformation
