#include "muscle_deformation/core/model/collision_radii.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>

namespace muscle_deformation {

std::vector<MuscleRadiiSummary> assignCollisionRadii(MassSpringSystem& system, const std::vector<Muscle>& muscles) {
  const int muscle_count = system.muscleCount();
  if (static_cast<int>(muscles.size()) != muscle_count)
    throw std::invalid_argument("assignCollisionRadii: " + std::to_string(muscles.size()) + " muscles given, the system has " +
                                std::to_string(muscle_count));
  const Eigen::Index n = system.particleCount();
  system.radius = Eigen::VectorXd::Zero(n);
  std::vector<MuscleRadiiSummary> summaries(static_cast<std::size_t>(muscle_count));
  std::vector<std::pair<std::int32_t, double>> near;

  for (int m = 0; m < muscle_count; ++m) {
    MuscleRadiiSummary& summary = summaries[static_cast<std::size_t>(m)];
    summary.name = system.muscle_name[static_cast<std::size_t>(m)];
    std::vector<std::int32_t> boundary;  // particle index of each boundary particle of this muscle
    for (std::int32_t p = system.muscle_begin[static_cast<std::size_t>(m)]; p < system.muscle_begin[static_cast<std::size_t>(m) + 1]; ++p)
      if (system.is_boundary[static_cast<std::size_t>(p)]) boundary.push_back(p);
    summary.boundary_particles = static_cast<int>(boundary.size());
    if (boundary.empty()) continue;

    Eigen::Matrix3Xd centres(3, static_cast<Eigen::Index>(boundary.size()));
    for (std::size_t k = 0; k < boundary.size(); ++k) centres.col(static_cast<Eigen::Index>(k)) = system.rest_position.col(boundary[k]);
    const PointIndex index(centres);

    // Mean distance from each particle to the surface vertices that chose it as their closest particle.
    Eigen::VectorXd distance_sum = Eigen::VectorXd::Zero(centres.cols());
    Eigen::VectorXi vertex_count = Eigen::VectorXi::Zero(centres.cols());
    const Vertices& vertices = muscles[static_cast<std::size_t>(m)].surface.vertices;
    for (Eigen::Index v = 0; v < vertices.cols(); ++v) {
      const auto [k, d] = index.nearest(vertices.col(v));
      distance_sum[k] += d;
      ++vertex_count[k];
    }
    Eigen::VectorXd radius(centres.cols());
    for (Eigen::Index k = 0; k < centres.cols(); ++k) {
      if (vertex_count[k] > 0) {
        radius[k] = distance_sum[k] / vertex_count[k];
        continue;
      }
      ++summary.particles_without_vertex;
      radius[k] = 0.0;
      if (centres.cols() > 1) {
        index.nearest(centres.col(k), 2, near);  // the first is the particle itself (or a coincident one)
        radius[k] = 0.5 * near.back().second;
      }
    }
    summary.mean_radius_before_m = radius.mean();

    // Overlapping pairs of this muscle's spheres, deepest relative overlap first.
    struct Overlap {
      std::int32_t i, j;
      double ratio;  // distance / (r_i + r_j), < 1
    };
    std::vector<Overlap> overlaps;
    const double r_max = radius.maxCoeff();
    for (Eigen::Index i = 0; i < centres.cols(); ++i) {
      index.within(centres.col(i), radius[i] + r_max, near);
      for (const auto& [j, d] : near) {
        if (j <= i) continue;
        const double reach = radius[i] + radius[j];
        if (d < reach) overlaps.push_back({static_cast<std::int32_t>(i), j, d / reach});
      }
    }
    std::sort(overlaps.begin(), overlaps.end(), [](const Overlap& a, const Overlap& b) {
      return a.ratio != b.ratio ? a.ratio < b.ratio : (a.i != b.i ? a.i < b.i : a.j < b.j);
    });
    for (const Overlap& o : overlaps) {
      const double d = (centres.col(o.i) - centres.col(o.j)).norm();
      const double reach = radius[o.i] + radius[o.j];
      if (d >= reach) continue;  // already separated by an earlier reduction
      // Scale both so they just touch; the factor is rounded down a hair so rounding cannot leave a sliver overlap.
      const double scale = (d / reach) * (1.0 - 1e-12);
      radius[o.i] *= scale;
      radius[o.j] *= scale;
      ++summary.reduced_pairs;
    }
    summary.mean_radius_m = radius.mean();
    for (std::size_t k = 0; k < boundary.size(); ++k) system.radius[boundary[k]] = radius[static_cast<Eigen::Index>(k)];
  }
  return summaries;
}

}  // namespace muscle_deformation
