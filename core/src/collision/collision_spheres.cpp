// Pre-processing for collision handling: sphere radii of muscle particles and sphere sets approximating bones.
#include "muscle_deformation/core/collision/collision_spheres.hpp"
#include "muscle_deformation/core/collision/point_index.hpp"

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

RestOverlapSummary clearRestOverlaps(MassSpringSystem& system, const std::vector<SphereSet>& bone_spheres_rest) {
  RestOverlapSummary summary;
  const int muscle_count = system.muscleCount();
  // Sphere sets of every muscle at rest, with the particle behind each sphere.
  std::vector<SphereSet> muscle_spheres(static_cast<std::size_t>(muscle_count));
  std::vector<std::vector<std::int32_t>> particle_of(static_cast<std::size_t>(muscle_count));
  auto gather = [&] {
    for (int m = 0; m < muscle_count; ++m) {
      auto& particles = particle_of[static_cast<std::size_t>(m)];
      particles.clear();
      for (std::int32_t p = system.muscle_begin[static_cast<std::size_t>(m)]; p < system.muscle_begin[static_cast<std::size_t>(m) + 1]; ++p)
        if (system.radius[p] > 0) particles.push_back(p);
      SphereSet& spheres = muscle_spheres[static_cast<std::size_t>(m)];
      spheres.resize(static_cast<Eigen::Index>(particles.size()));
      for (std::size_t k = 0; k < particles.size(); ++k) {
        spheres.centre.col(static_cast<Eigen::Index>(k)) = system.rest_position.col(particles[k]);
        spheres.radius[static_cast<Eigen::Index>(k)] = system.radius[particles[k]];
      }
    }
  };
  gather();
  CollisionSettings settings;
  std::unique_ptr<BroadPhase> broad = makeBroadPhase(settings);
  std::vector<SpherePair> pairs;

  // Bones first: a muscle sphere may only reach a bone sphere's surface. Radii only shrink, so one pass per pair
  // list suffices, and shrinking for bones never creates a muscle-muscle overlap.
  const int bone_count = static_cast<int>(bone_spheres_rest.size());
  for (int b = 0; b < bone_count; ++b) broad->update(muscle_count + b, bone_spheres_rest[static_cast<std::size_t>(b)], true);
  for (int m = 0; m < muscle_count; ++m) {
    if (muscle_spheres[static_cast<std::size_t>(m)].size() == 0) continue;
    broad->update(m, muscle_spheres[static_cast<std::size_t>(m)], true);
    for (int b = 0; b < bone_count; ++b) {
      const SphereSet& bone = bone_spheres_rest[static_cast<std::size_t>(b)];
      if (bone.size() == 0) continue;
      broad->findPairs(m, muscle_count + b, pairs);
      for (const SpherePair& pair : pairs) {
        const std::int32_t particle = particle_of[static_cast<std::size_t>(m)][static_cast<std::size_t>(pair.first)];
        const double distance = (system.rest_position.col(particle) - bone.centre.col(pair.second)).norm();
        const double allowed = distance - bone.radius[pair.second];
        if (system.radius[particle] <= allowed) continue;  // already shrunk by an earlier pair
        if (allowed <= 0) {
          if (system.radius[particle] > 0) ++summary.spheres_removed;
          system.radius[particle] = 0;
        } else {
          system.radius[particle] = allowed;
        }
        ++summary.muscle_bone_pairs;
      }
    }
  }

  // Then muscle against muscle, deepest relative overlap first, both radii scaled so the pair just touches.
  gather();
  for (int m = 0; m < muscle_count; ++m) broad->update(m, muscle_spheres[static_cast<std::size_t>(m)], true);
  struct Overlap {
    std::int32_t i, j;
    double depth;
  };
  std::vector<Overlap> overlaps;
  for (int a = 0; a < muscle_count; ++a)
    for (int b = a + 1; b < muscle_count; ++b) {
      if (muscle_spheres[static_cast<std::size_t>(a)].size() == 0 || muscle_spheres[static_cast<std::size_t>(b)].size() == 0)
        continue;
      broad->findPairs(a, b, pairs);
      for (const SpherePair& pair : pairs) {
        const std::int32_t i = particle_of[static_cast<std::size_t>(a)][static_cast<std::size_t>(pair.first)];
        const std::int32_t j = particle_of[static_cast<std::size_t>(b)][static_cast<std::size_t>(pair.second)];
        const double distance = (system.rest_position.col(i) - system.rest_position.col(j)).norm();
        overlaps.push_back({i, j, (system.radius[i] + system.radius[j] - distance) / (system.radius[i] + system.radius[j])});
      }
    }
  std::sort(overlaps.begin(), overlaps.end(), [](const Overlap& x, const Overlap& y) { return x.depth > y.depth; });
  for (const Overlap& overlap : overlaps) {
    const double distance = (system.rest_position.col(overlap.i) - system.rest_position.col(overlap.j)).norm();
    const double sum = system.radius[overlap.i] + system.radius[overlap.j];
    if (sum <= distance) continue;
    const double scale = distance / sum;
    system.radius[overlap.i] *= scale;
    system.radius[overlap.j] *= scale;
    ++summary.muscle_muscle_pairs;
  }
  return summary;
}

SphereSet boneSpheresOneRing(const TriangleMesh& surface, OneRingRule rule) {
  const Eigen::Index n = surface.vertexCount();
  // Vertex-to-vertex edges, compressed rows; each undirected edge appears once per triangle side, deduplicated.
  std::vector<std::vector<std::int32_t>> ring(static_cast<std::size_t>(n));
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t)
    for (int e = 0; e < 3; ++e) {
      const int a = surface.triangles(e, t), b = surface.triangles((e + 1) % 3, t);
      if (a < 0 || b < 0 || a >= n || b >= n)
        throw std::invalid_argument("boneSpheresOneRing: triangle " + std::to_string(t) + " has a vertex index out of range");
      if (a == b) continue;
      ring[static_cast<std::size_t>(a)].push_back(b);
      ring[static_cast<std::size_t>(b)].push_back(a);
    }
  for (auto& r : ring) {
    std::sort(r.begin(), r.end());
    r.erase(std::unique(r.begin(), r.end()), r.end());
  }
  const Vertices normals = vertexNormals(surface);

  std::vector<std::uint8_t> used(static_cast<std::size_t>(n), 0);
  std::vector<Eigen::Vector3d> centres;
  std::vector<double> radii;
  for (Eigen::Index v = 0; v < n; ++v) {
    const auto& neighbours = ring[static_cast<std::size_t>(v)];
    if (used[static_cast<std::size_t>(v)] || neighbours.empty()) continue;
    if (rule == OneRingRule::disjoint_vertex_rings &&
        std::any_of(neighbours.begin(), neighbours.end(), [&](std::int32_t w) { return used[static_cast<std::size_t>(w)] != 0; }))
      continue;
    used[static_cast<std::size_t>(v)] = 1;
    double longest = 0.0;
    for (const std::int32_t w : neighbours) {
      used[static_cast<std::size_t>(w)] = 1;
      longest = std::max(longest, (surface.vertices.col(w) - surface.vertices.col(v)).norm());
    }
    if (!(longest > 0.0)) continue;  // all neighbours coincide with the root: no extent to cover
    centres.push_back(surface.vertices.col(v) - normals.col(v) * longest);
    radii.push_back(longest * std::sqrt(2.0));
  }
  SphereSet spheres;
  spheres.resize(static_cast<Eigen::Index>(centres.size()));
  for (std::size_t k = 0; k < centres.size(); ++k) {
    spheres.centre.col(static_cast<Eigen::Index>(k)) = centres[k];
    spheres.radius[static_cast<Eigen::Index>(k)] = radii[k];
  }
  return spheres;
}

}  // namespace muscle_deformation
