// Surface skinning: precompute per muscle at rest, then a cheap per-frame update from the particle positions.
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include "muscle_deformation/core/model/spring_layout.hpp"

#include "muscle_deformation/core/base/point_index.hpp"

#include <Eigen/LU>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>

namespace muscle_deformation {

std::string toString(SkinningMethod method) {
  switch (method) {
    case SkinningMethod::nearest_average: return "nearest_average";
    case SkinningMethod::mean_value: return "mean_value";
    case SkinningMethod::embedded: return "embedded";
  }
  return "unknown";
}

SkinningMethod skinningMethodFromString(const std::string& name) {
  for (SkinningMethod method : {SkinningMethod::nearest_average, SkinningMethod::mean_value, SkinningMethod::embedded})
    if (toString(method) == name) return method;
  throw std::invalid_argument("unknown skinning method '" + name +
                              "' (expected nearest_average, mean_value or embedded)");
}

namespace {

using Triplets = std::vector<Eigen::Triplet<double, std::int32_t>>;


}  // namespace

MuscleSkin::MuscleSkin(const MassSpringSystem& system, int muscle, const TriangleMesh& rest_surface,
                       const SkinningSettings& settings)
    : method_(settings.method), muscle_(muscle) {
  const auto start = std::chrono::steady_clock::now();
  if (muscle < 0 || muscle + 1 >= static_cast<int>(system.muscle_begin.size()))
    throw SkinningError("skinning: no muscle " + std::to_string(muscle) + " in the system");
  const std::string label = "muscle '" + system.muscle_name[muscle] + "'";
  const SurfaceTopologyReport topology = checkSurfaceTopology(rest_surface);
  if (!topology.closedManifold())
    throw SkinningError(label + ": surface is not a closed 2-manifold (" + topology.describe() +
                        "); skinning and volume need a closed surface");
  particle_begin_ = system.muscle_begin[muscle];
  // The surface follows the muscle's fibre particles only: a tendon's bone anchors (after them in the muscle's range)
  // sit on the bone, up to tens of centimetres from the belly, and a Delaunay tetrahedralisation or a cage over them
  // spans that gap.
  particle_count_ = 0;
  for (Eigen::Index i = particle_begin_; i < system.muscle_begin[muscle + 1]; ++i) {
    if (system.fibre_of[static_cast<std::size_t>(i)] == kTendonAnchor) break;
    ++particle_count_;
  }
  if (particle_count_ < 4) throw SkinningError(label + ": fewer than 4 fibre particles");
  triangles_ = rest_surface.triangles;
  const Eigen::Matrix3Xd rest_particles = system.rest_position.middleCols(particle_begin_, particle_count_);
  switch (method_) {
    case SkinningMethod::mean_value: precomputeMeanValue(rest_particles, rest_surface.vertices, system, settings.cage); break;
    case SkinningMethod::embedded:
      precomputeEmbedded(rest_particles, rest_surface.vertices, std::max(1, settings.embedded_candidate_particles));
      break;
    case SkinningMethod::nearest_average:
      if (settings.nearest_particles < 1) throw SkinningError(label + ": nearest_particles must be at least 1");
      precomputeNearestAverage(rest_particles, rest_surface.vertices, system, settings.nearest_particles);
      break;
  }
  // How exactly the weights give back the rest surface from the rest particles (nearest_average adds its bone terms).
  Vertices rest_again;
  update(system.rest_position, BoneTransforms(), rest_again);
  diagnostics_.max_rest_residual_m = (rest_again - rest_surface.vertices).colwise().norm().maxCoeff();
  for (Eigen::Index v = 0; v < weights_.rows(); ++v)
    diagnostics_.max_abs_weight_sum = std::max(diagnostics_.max_abs_weight_sum, weights_.row(v).cwiseAbs().sum());
  diagnostics_.precompute_ms = millisecondsSince(start);
}

void MuscleSkin::precomputeMeanValue(const Eigen::Matrix3Xd& rest_particles, const Vertices& rest_vertices,
                                     const MassSpringSystem& system, CageKind cage_kind) {
  cage_ = buildParticleCage(system, muscle_, cage_kind);
  diagnostics_.cage_kind = cage_.kind;
  diagnostics_.cage_vertices = static_cast<int>(cage_.mesh.vertexCount());
  diagnostics_.cage_triangles = static_cast<int>(cage_.mesh.triangleCount());
  // Winding number of the cage around a vertex tells inside from outside (for the diagnostics only): the solid angle
  // each triangle subtends, summed, over 4 pi.
  auto insideCage = [&](const Eigen::Vector3d& x) {
    double solid_angle = 0;
    for (Eigen::Index t = 0; t < cage_.mesh.triangleCount(); ++t) {
      const Eigen::Vector3d a = cage_.mesh.vertices.col(cage_.mesh.triangles(0, t)) - x;
      const Eigen::Vector3d b = cage_.mesh.vertices.col(cage_.mesh.triangles(1, t)) - x;
      const Eigen::Vector3d c = cage_.mesh.vertices.col(cage_.mesh.triangles(2, t)) - x;
      const double la = a.norm(), lb = b.norm(), lc = c.norm();
      solid_angle += 2 * std::atan2(a.dot(b.cross(c)), la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb);
    }
    return solid_angle > 2 * 3.14159265358979323846;
  };
  Triplets triplets;
  triplets.reserve(static_cast<std::size_t>(rest_vertices.cols() * cage_.mesh.vertexCount()));
  for (Eigen::Index v = 0; v < rest_vertices.cols(); ++v) {
    bool on_cage = false;
    const Eigen::VectorXd w = meanValueCoordinates(cage_.mesh, rest_vertices.col(v), &on_cage);
    if (!w.allFinite())
      throw SkinningError("muscle '" + system.muscle_name[muscle_] + "': mean value coordinates of surface vertex " +
                          std::to_string(v) + " are not finite");
    diagnostics_.vertices_on_cage += on_cage;
    if (!on_cage && !insideCage(rest_vertices.col(v))) diagnostics_.vertices_outside += 1;
    for (Eigen::Index k = 0; k < w.size(); ++k)
      if (w[k] != 0) triplets.emplace_back(static_cast<std::int32_t>(v), cage_.particle[k], w[k]);
  }
  (void)rest_particles;
  weights_.resize(rest_vertices.cols(), particle_count_);
  weights_.setFromTriplets(triplets.begin(), triplets.end());
  weights_.makeCompressed();
}

void MuscleSkin::precomputeEmbedded(const Eigen::Matrix3Xd& rest_particles, const Vertices& rest_vertices,
                                    int candidates) {
  std::vector<Eigen::Vector4i> tetrahedra;
  try {
    tetrahedra = delaunayTetrahedra(rest_particles);
  } catch (const std::runtime_error& error) {
    throw SkinningError("muscle " + std::to_string(muscle_) + ": embedding: " + error.what());
  }
  diagnostics_.tetrahedra = static_cast<int>(tetrahedra.size());
  // Tetrahedra around each particle, and for each tetrahedron the map from a point to its barycentric coordinates
  // (rows 1..3; the first coordinate is 1 minus their sum). Flat slivers (Qt output on cospherical grids) are left
  // out: extrapolating from them would give huge weights.
  std::vector<std::vector<int>> around(static_cast<std::size_t>(rest_particles.cols()));
  std::vector<Eigen::Matrix3d> to_barycentric(tetrahedra.size());
  std::vector<std::uint8_t> usable(tetrahedra.size(), 0);
  for (std::size_t t = 0; t < tetrahedra.size(); ++t) {
    const Eigen::Vector4i& c = tetrahedra[t];
    Eigen::Matrix3d edges;
    edges << rest_particles.col(c[1]) - rest_particles.col(c[0]), rest_particles.col(c[2]) - rest_particles.col(c[0]),
        rest_particles.col(c[3]) - rest_particles.col(c[0]);
    const double longest = edges.colwise().norm().maxCoeff();
    if (!(std::abs(edges.determinant()) > 1e-9 * longest * longest * longest)) continue;
    usable[t] = 1;
    to_barycentric[t] = edges.inverse();
    for (int k = 0; k < 4; ++k) around[c[k]].push_back(static_cast<int>(t));
  }
  const PointIndex index(rest_particles);
  std::vector<std::pair<std::int32_t, double>> nearest;
  std::vector<int> visited;
  Triplets triplets;
  triplets.reserve(static_cast<std::size_t>(rest_vertices.cols()) * 4);
  for (Eigen::Index v = 0; v < rest_vertices.cols(); ++v) {
    const Eigen::Vector3d x = rest_vertices.col(v);
    // The tetrahedron the vertex is least outside of: the largest smallest coordinate. Inside a tetrahedron that is
    // >= 0 (the containing one); outside, it picks the one needing the mildest extrapolation.
    index.nearest(x, candidates, nearest);
    visited.clear();
    int best = -1;
    double best_smallest = -std::numeric_limits<double>::infinity();
    Eigen::Vector4d best_coordinates = Eigen::Vector4d::Zero();
    for (const auto& [particle, distance] : nearest) {
      (void)distance;
      for (int t : around[particle]) {
        if (std::find(visited.begin(), visited.end(), t) != visited.end()) continue;
        visited.push_back(t);
        const Eigen::Vector3d local = to_barycentric[t] * (x - rest_particles.col(tetrahedra[t][0]));
        const Eigen::Vector4d coordinates(1 - local.sum(), local.x(), local.y(), local.z());
        if (coordinates.minCoeff() > best_smallest) {
          best_smallest = coordinates.minCoeff();
          best = t;
          best_coordinates = coordinates;
        }
      }
    }
    if (best < 0)
      throw SkinningError("muscle " + std::to_string(muscle_) + ": no usable tetrahedron near surface vertex " +
                          std::to_string(v));
    if (best_smallest < -1e-9) diagnostics_.vertices_outside += 1;
    for (int k = 0; k < 4; ++k) triplets.emplace_back(static_cast<std::int32_t>(v), tetrahedra[best][k], best_coordinates[k]);
  }
  weights_.resize(rest_vertices.cols(), particle_count_);
  weights_.setFromTriplets(triplets.begin(), triplets.end());
  weights_.makeCompressed();
}

void MuscleSkin::precomputeNearestAverage(const Eigen::Matrix3Xd& rest_particles, const Vertices& rest_vertices,
                                          const MassSpringSystem& system, int nearest_count) {
  // Thesis 4.4.4. With the vertex's N particles P, each pre-transformed by its bone blend B_p(r) = sum w (R r + t):
  //   vertex = mean_p B_p(v_rest) + mean_p (x_p - B_p(r_p)).
  // Collecting the blend weights per bone b (alpha_b = mean_p w_pb, beta_b = mean_p w_pb r_p) the translations t_b
  // cancel and vertex = mean_p x_p + sum_b R_b (alpha_b v_rest - beta_b): one sparse product plus a few rotations.
  const PointIndex index(rest_particles);
  std::vector<std::pair<std::int32_t, double>> nearest;
  Triplets triplets;
  rotation_begin_.assign(1, 0);
  rotation_bone_.clear();
  rotation_offset_.clear();
  for (Eigen::Index v = 0; v < rest_vertices.cols(); ++v) {
    index.nearest(rest_vertices.col(v), nearest_count, nearest);
    const double share = 1.0 / static_cast<double>(nearest.size());
    std::map<std::int32_t, std::pair<double, Eigen::Vector3d>> per_bone;  // bone -> (alpha, beta)
    for (const auto& [local, distance] : nearest) {
      (void)distance;
      triplets.emplace_back(static_cast<std::int32_t>(v), local, share);
      const Eigen::Index i = particle_begin_ + local;
      double weight_sum = 0;
      for (int k = 0; k < MassSpringSystem::kBlendBones; ++k)
        if (system.blend_bone(k, i) != kNoBone) weight_sum += system.blend_weight(k, i);
      auto accumulate = [&](std::int32_t bone, double weight) {
        auto& entry = per_bone.try_emplace(bone, 0.0, Eigen::Vector3d::Zero()).first->second;
        entry.first += share * weight;
        entry.second += share * weight * rest_particles.col(local);
      };
      if (!(weight_sum > 0)) {
        accumulate(kNoBone, 1.0);  // follows no bone: its pre-transform is the identity
        continue;
      }
      for (int k = 0; k < MassSpringSystem::kBlendBones; ++k)
        if (system.blend_bone(k, i) != kNoBone) accumulate(system.blend_bone(k, i), system.blend_weight(k, i) / weight_sum);
    }
    for (const auto& [bone, sums] : per_bone) {
      rotation_bone_.push_back(bone);
      rotation_offset_.push_back(sums.first * rest_vertices.col(v) - sums.second);
    }
    rotation_begin_.push_back(static_cast<std::int32_t>(rotation_bone_.size()));
  }
  weights_.resize(rest_vertices.cols(), particle_count_);
  weights_.setFromTriplets(triplets.begin(), triplets.end());
  weights_.makeCompressed();
}

void MuscleSkin::update(const Eigen::Matrix3Xd& particle_positions, const BoneTransforms& bone_transforms,
                        Vertices& surface) const {
  linearPart(particle_positions, surface);
  if (method_ != SkinningMethod::nearest_average) return;
  const Eigen::Index vertices = weights_.rows();
  for (Eigen::Index v = 0; v < vertices; ++v)
    for (std::int32_t k = rotation_begin_[v]; k < rotation_begin_[v + 1]; ++k) {
      const std::int32_t bone = rotation_bone_[k];
      // A missing transform (e.g. at precompute, or a bone the caller did not pose) means the bone is at rest.
      if (bone == kNoBone || bone >= static_cast<std::int32_t>(bone_transforms.size()))
        surface.col(v) += rotation_offset_[k];
      else
        surface.col(v) += bone_transforms[bone].linear() * rotation_offset_[k];
    }
}

void MuscleSkin::linearPart(const Eigen::Matrix3Xd& particle_positions, Vertices& surface) const {
  if (particle_positions.cols() < particle_begin_ + particle_count_)
    throw std::invalid_argument("skinning update: " + std::to_string(particle_positions.cols()) +
                                " particle positions, the muscle needs " +
                                std::to_string(particle_begin_ + particle_count_));
  const Eigen::Index vertices = weights_.rows();
  if (surface.cols() != vertices) surface.resize(3, vertices);
  // One sparse matrix-vector product per coordinate, written out so it reads the particles in place.
  const std::int32_t* row_begin = weights_.outerIndexPtr();
  const std::int32_t* column = weights_.innerIndexPtr();
  const double* weight = weights_.valuePtr();
  const double* particles = particle_positions.data() + 3 * particle_begin_;
  for (Eigen::Index v = 0; v < vertices; ++v) {
    double x = 0, y = 0, z = 0;
    for (std::int32_t k = row_begin[v]; k < row_begin[v + 1]; ++k) {
      const double* p = particles + 3 * static_cast<Eigen::Index>(column[k]);
      x += weight[k] * p[0];
      y += weight[k] * p[1];
      z += weight[k] * p[2];
    }
    surface(0, v) = x;
    surface(1, v) = y;
    surface(2, v) = z;
  }
}

SurfaceSkinning::SurfaceSkinning(const MassSpringSystem& system, const std::vector<Muscle>& muscles,
                                 const SkinningSettings& settings)
    : settings_(settings) {
  if (static_cast<int>(muscles.size()) != system.muscleCount())
    throw SkinningError("skinning: " + std::to_string(muscles.size()) + " muscle surfaces for a system of " +
                        std::to_string(system.muscleCount()) + " muscles");
  skins_.reserve(muscles.size());
  for (int m = 0; m < system.muscleCount(); ++m) {
    if (muscles[m].name != system.muscle_name[m])
      throw SkinningError("skinning: muscle " + std::to_string(m) + " is '" + muscles[m].name + "' but the system has '" +
                          system.muscle_name[m] + "' there");
    skins_.emplace_back(system, m, muscles[m].surface, settings);
  }
}

void SurfaceSkinning::update(const Eigen::Matrix3Xd& particle_positions, const BoneTransforms& bone_transforms,
                             std::vector<Vertices>& surfaces, int threads) const {
  if (surfaces.size() != skins_.size()) surfaces.resize(skins_.size());
  const int muscles = static_cast<int>(skins_.size());
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(dynamic)
  for (int m = 0; m < muscles; ++m)
    skins_[static_cast<std::size_t>(m)].update(particle_positions, bone_transforms, surfaces[static_cast<std::size_t>(m)]);
}

}  // namespace muscle_deformation
