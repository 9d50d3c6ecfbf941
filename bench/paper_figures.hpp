// The GRAPP 2014 paper's Table 1 (Janak & Kohout, "Deformable muscle models for motion simulation"; seed text in
// ../shared/seeds/janak_kohout2014_grapp_deformable_muscles.txt) and its bone sphere counts, for the benchmarks
// that put our times beside the paper's. The paper gives seconds per 500 iterations, averaged over five poses,
// 13 thigh muscles x 64 fibres, 26-cubic springs, one Core2Duo E6300 core (2006).
#pragma once

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/base/geometry.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace bench {

struct PaperTableColumn {
  int particles_per_fibre;
  double mss_ms, muscle_cd_ms, bone_cd_ms, total_ms;  // per iteration
};

// Table 1, converted from seconds per 500 iterations to milliseconds per iteration.
inline std::array<PaperTableColumn, 4> paperTable1() {
  constexpr double iterations = 500, ms_per_s = 1000;
  const auto column = [&](int per_fibre, double mss_s, double muscle_s, double bone_s, double total_s) {
    const double to_ms = ms_per_s / iterations;
    return PaperTableColumn{per_fibre, mss_s * to_ms, muscle_s * to_ms, bone_s * to_ms, total_s * to_ms};
  };
  return {column(20, 18.66, 8.15, 30.03, 56.84), column(40, 39.97, 13.50, 37.43, 90.9),
          column(60, 60.53, 24.00, 56.03, 140.56), column(80, 80.70, 29.53, 67.10, 177.33)};
}

// The paper's bone sphere sets (section 4): pelvis, femur, tibia.
inline std::array<int, 3> paperBoneSphereCounts() { return {8527, 1568, 1709}; }

// `count` spheres on a bone surface placed like the one-ring heuristic: surface points drawn uniformly by area
// (seeded), centre moved inward by L along the face normal, radius L sqrt(2). L is chosen so the spheres' surface
// caps (radius L) cover the area about twice: N pi L^2 = 2 A. Lets a synthetic bone carry the paper's sphere count.
inline muscle_deformation::SphereSet boneSpheresOfCount(const muscle_deformation::TriangleMesh& mesh, int count,
                                                        std::uint32_t seed) {
  std::vector<double> cumulative_area;
  double area = 0;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t)), b = mesh.vertices.col(mesh.triangles(1, t)),
                          c = mesh.vertices.col(mesh.triangles(2, t));
    area += 0.5 * (b - a).cross(c - a).norm();
    cumulative_area.push_back(area);
  }
  const double depth = std::sqrt(2.0 * area / (M_PI * count));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  muscle_deformation::SphereSet spheres;
  spheres.resize(count);
  for (int k = 0; k < count; ++k) {
    const auto t = static_cast<Eigen::Index>(
        std::lower_bound(cumulative_area.begin(), cumulative_area.end(), unit(rng) * area) - cumulative_area.begin());
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t)), b = mesh.vertices.col(mesh.triangles(1, t)),
                          c = mesh.vertices.col(mesh.triangles(2, t));
    double u = unit(rng), v = unit(rng);
    if (u + v > 1) u = 1 - u, v = 1 - v;
    const Eigen::Vector3d point = a + u * (b - a) + v * (c - a);
    const Eigen::Vector3d normal = (b - a).cross(c - a).normalized();
    spheres.centre.col(k) = point - depth * normal;
    spheres.radius[k] = depth * std::sqrt(2.0);
  }
  return spheres;
}

// The paper's sphere counts on the synthetic scene's bones, in the scene's bone order (pelvis, femur, tibia, ...),
// with the seeds collision_bench has always used so its numbers stay comparable.
inline std::vector<muscle_deformation::SphereSet> paperCountBoneSpheres(const std::vector<muscle_deformation::Bone>& bones) {
  const std::array<int, 3> counts = paperBoneSphereCounts();
  std::vector<muscle_deformation::SphereSet> spheres;
  for (std::size_t b = 0; b < bones.size(); ++b)
    spheres.push_back(boneSpheresOfCount(bones[b].surface, counts[b % counts.size()], 17u + static_cast<std::uint32_t>(b)));
  return spheres;
}

}  // namespace bench
