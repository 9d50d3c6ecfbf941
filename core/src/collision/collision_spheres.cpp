// Pre-processing for collision handling: sphere radii of muscle particles and sphere sets approximating bones.
#include "muscle_deformation/core/collision/collision_spheres.hpp"
#include "muscle_deformation/core/base/point_index.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>

namespace muscle_deformation {

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
