// Muscle surfaces that follow the particles (thesis 4.4.4, GRAPP 3.2).
//
// The triangle surface of a muscle has no springs of its own: each surface vertex is tied to particles once, at
// rest (precompute), and every frame its position is recomputed from the current particle positions (update).
// Three ways of tying a vertex to particles are offered as a setting:
//   nearest_average  the thesis baseline: the vertex is rigidly pre-transformed like its N closest particles, then
//                    moved by their average displacement since their own pre-transform;
//   mean_value       mean value coordinates (Ju, Schaefer, Warren 2005) of the vertex with respect to a closed
//                    triangle cage whose corners are boundary particles (the GRAPP 2014 method);
//   embedded         barycentric coordinates of the vertex in a Delaunay tetrahedron of the muscle's particles
//                    (SOFA-style embedding), extrapolated from a nearby tetrahedron for vertices outside.
// mean_value and embedded make every vertex a fixed affine combination of particles (weights sum to 1), so any
// affine motion of the particles (rigid motion, uniform scaling) moves the surface by exactly that motion.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/surfaces/surface_cage.hpp"

#include <Eigen/Sparse>

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

enum class SkinningMethod { nearest_average, mean_value, embedded };

std::string toString(SkinningMethod method);
SkinningMethod skinningMethodFromString(const std::string& name);  // throws std::invalid_argument

struct SkinningSettings {
  SkinningMethod method = SkinningMethod::nearest_average;  // chosen by measurement, see docs/surface_skinning.md
  int nearest_particles = 8;                           // nearest_average: N (thesis tried 3 and 8)
  CageKind cage = CageKind::convex_hull;               // mean_value; measured better than fibre_tube (docs)
  int embedded_candidate_particles = 8;                // embedded: tetrahedra around this many nearest particles
                                                       // are searched for the one containing the vertex
};

// What the precompute found; for judging how well-behaved the coordinates are.
struct SkinningDiagnostics {
  int cage_vertices = 0;          // mean_value: particles that are cage corners
  int cage_triangles = 0;
  CageKind cage_kind = CageKind::fibre_tube;  // the cage actually built (after a fallback)
  int tetrahedra = 0;             // embedded
  int vertices_outside = 0;       // outside the cage (mean_value) / outside every tetrahedron (embedded)
  int vertices_on_cage = 0;       // mean_value: on a cage triangle, given that triangle's barycentric coordinates
  double max_abs_weight_sum = 0;  // max over vertices of sum |w|; 1 means a convex combination, larger means
                                  // extrapolation with negative weights (amplifies particle noise by this factor)
  double max_rest_residual_m = 0; // max |vertex - sum w p_rest|: how exactly the coordinates reproduce the rest surface
  double precompute_ms = 0;
};

// The skin of one muscle.
class MuscleSkin {
 public:
  using Weights = Eigen::SparseMatrix<double, Eigen::RowMajor, std::int32_t>;

  // Precompute at rest from the system's rest particles and the muscle's closed rest surface. Throws SkinningError.
  MuscleSkin(const MassSpringSystem& system, int muscle, const TriangleMesh& rest_surface,
             const SkinningSettings& settings);

  // Deformed surface vertices from the current positions of all particles of the system. `bone_transforms` (indexed
  // by Bone::id, as for rigidPretransform) is read by nearest_average only; the other methods accept an empty list.
  // Allocates nothing when `surface` already has 3 x vertexCount() entries.
  void update(const Eigen::Matrix3Xd& particle_positions, const BoneTransforms& bone_transforms,
              Vertices& surface) const;

  // The part of update() that follows the particles: sum_j w_j x_j for every vertex, from `particle_values` (all
  // particles of the system, e.g. a displacement), without the bone offsets.
  void linearPart(const Eigen::Matrix3Xd& particle_values, Vertices& out) const;

  SkinningMethod method() const { return method_; }
  int muscle() const { return muscle_; }
  Eigen::Index particleBegin() const { return particle_begin_; }  // the weights' column 0 is this particle
  Eigen::Index vertexCount() const { return weights_.rows(); }
  const Triangles& triangles() const { return triangles_; }
  // Rows: surface vertices; columns: the muscle's particles (muscle-local index, particle - muscle_begin[muscle]).
  // Every row sums to 1 for mean_value and embedded; nearest_average holds 1/N on the N closest particles.
  const Weights& weights() const { return weights_; }
  const ParticleCage& cage() const { return cage_; }  // mean_value only (empty otherwise)
  const SkinningDiagnostics& diagnostics() const { return diagnostics_; }

 private:
  void precomputeMeanValue(const Eigen::Matrix3Xd& rest_particles, const Vertices& rest_vertices,
                           const MassSpringSystem& system, CageKind cage_kind);
  void precomputeEmbedded(const Eigen::Matrix3Xd& rest_particles, const Vertices& rest_vertices, int candidates);
  void precomputeNearestAverage(const Eigen::Matrix3Xd& rest_particles, const Vertices& rest_vertices,
                                const MassSpringSystem& system, int nearest);

  SkinningMethod method_;
  int muscle_ = 0;
  Eigen::Index particle_begin_ = 0, particle_count_ = 0;
  Triangles triangles_;
  Weights weights_;
  ParticleCage cage_;
  SkinningDiagnostics diagnostics_;
  // nearest_average: vertex = sum_j w_j x_j + sum_b R_b g_b over the bones b its particles blend; the translations of
  // the bones cancel between the vertex's pre-transform and its particles' pre-transforms (see the .cpp).
  std::vector<std::int32_t> rotation_begin_;     // per vertex, into the two arrays below; size vertices + 1
  std::vector<std::int32_t> rotation_bone_;      // bone id, kNoBone for particles that follow no bone
  std::vector<Eigen::Vector3d> rotation_offset_;  // g_b, metres
};

// Skins of all muscles of a system, in muscle order.
class SurfaceSkinning {
 public:
  // `muscles` are the muscles the system was built from (same order). Throws SkinningError.
  SurfaceSkinning(const MassSpringSystem& system, const std::vector<Muscle>& muscles, const SkinningSettings& settings);

  // Per frame: fills surfaces[m] for every muscle; no allocation once `surfaces` has been filled before. The muscles
  // are shared out over `threads` (each fills its own surface: the result does not depend on it).
  void update(const Eigen::Matrix3Xd& particle_positions, const BoneTransforms& bone_transforms,
              std::vector<Vertices>& surfaces, int threads = 1) const;

  const std::vector<MuscleSkin>& muscles() const { return skins_; }
  const SkinningSettings& settings() const { return settings_; }

 private:
  SkinningSettings settings_;
  std::vector<MuscleSkin> skins_;
};

}  // namespace muscle_deformation
