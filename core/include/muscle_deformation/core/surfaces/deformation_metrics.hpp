// Fidelity of a deformed scene: muscle volume kept, muscle surface and particles inside bones, fibre length change.
//
// Volume and penetration are measured on the skinned muscle surfaces (what users see), penetration also on the
// particles (what the solver keeps out of the bones, whatever the collision stage's bone proxy); the figures read
// each bone's signed distance field (the bone itself, to a fraction of a voxel; the exact ray-parity test below took
// 35 ms a frame for the bundled scene), independent of which proxy the collision stage uses.
#pragma once

#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/base/inside_test.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/base/point_index.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace muscle_deformation {

// Input unusable for measuring (open muscle or bone surface, mismatched sizes); the message names the object.
class MetricsError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};


struct MuscleMetrics {
  std::string name;
  double rest_volume_m3 = 0;
  double volume_m3 = 0;
  double volume_error_pct = 0;          // (volume - rest) / rest * 100, signed
  int vertices_inside_bone = 0;         // surface vertices inside any bone
  double max_inside_bone_depth_m = 0;   // largest distance from such a vertex to that bone's surface
  std::string deepest_bone;             // the bone of that vertex ("" when none)
  // The muscle's particles whose centre lies inside a bone, by the bone's field: what the solver is asked to keep out
  // of the bones. A free particle counts in any bone; a fixed particle in any bone but the one it is fixed to (it is
  // the muscle's attachment there: where it lies in that bone is the attachment, not a penetration); a tendon's bone
  // anchor is the bone's own point and never counts.
  int particles_inside_bone = 0;
  double max_particle_inside_bone_depth_m = 0;  // the deepest such particle's distance to that bone's surface
  std::string deepest_particle_bone;            // its bone ("" when none)
  int fibres = 0;
  double fibre_length_change_mean_pct = 0;  // mean over fibres of (length / rest length - 1) * 100
  double fibre_length_change_min_pct = 0;   // range over fibres
  double fibre_length_change_max_pct = 0;
};

struct SceneMetrics {
  std::vector<MuscleMetrics> muscles;
  double volume_error_mean_pct = 0;    // mean over muscles of |volume error|
  double volume_error_max_pct = 0;     // max over muscles of |volume error|
  int vertices_inside_bone = 0;        // all muscles
  double max_inside_bone_depth_m = 0;  // all muscles
  int particles_inside_bone = 0;                // all muscles
  double max_particle_inside_bone_depth_m = 0;  // all muscles
  double compute_ms = 0;
};

class DeformationMetrics {
 public:
  // `muscles` are the muscles the system was built from (same order), with closed rest surfaces; `bones` the scene's
  // bones at rest (closed surfaces). `bone_fields` (per bone, e.g. the collision stage's) are built here when not
  // given. Throws MetricsError naming the open surface.
  DeformationMetrics(const std::vector<Bone>& bones, const std::vector<Muscle>& muscles, const MassSpringSystem& system,
                     std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields = {});

  // Per solve: surfaces[m] are muscle m's deformed surface vertices (e.g. from SurfaceSkinning::update), positions
  // the particles, transforms the bones' pose (indexed by Bone::id; missing bones stay at rest). Remembers what it
  // read of the bone fields, so that the next frame reads only points that may have come close to a bone (exact for
  // any motion); one instance measures one frame at a time. `threads` share the muscles' surfaces out; the figures do
  // not depend on it.
  SceneMetrics measure(const std::vector<Vertices>& surfaces, const Eigen::Matrix3Xd& particle_positions,
                       const BoneTransforms& bone_transforms, int threads = 1) const;

  // The particles' part of measure() alone (no surfaces needed): per muscle, its particles inside a bone and the
  // deepest (MuscleMetrics::particles_inside_bone); the other figures stay 0. Shares measure()'s memory of reads.
  SceneMetrics measureParticles(const Eigen::Matrix3Xd& particle_positions, const BoneTransforms& bone_transforms,
                                int threads = 1) const;

  // Pieces, usable alone.
  // Rest volume of muscle m (positive whatever its winding).
  double restVolume(int muscle) const { return rest_volume_[muscle]; }
  // Length of every fibre now over its length at rest, all muscles in particle order (as fibrePolylines).
  Eigen::VectorXd fibreLengthRatios(const Eigen::Matrix3Xd& particle_positions) const;
  // Distance field of bone b at rest; to test a posed bone, map the point back with the inverse bone transform.
  const BoneDistanceField& boneField(int bone) const { return *bone_fields_[static_cast<std::size_t>(bone)]; }
  const std::vector<std::shared_ptr<const BoneDistanceField>>& boneFields() const { return bone_fields_; }

 private:
  std::vector<std::string> bone_names_;
  std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields_;
  std::vector<std::string> muscle_names_;
  std::vector<Triangles> muscle_triangles_;
  std::vector<double> rest_volume_;
  std::vector<double> volume_sign_;  // -1 for muscles whose triangles wind inwards
  // Fibres: particle ranges [first, end) (tendon anchors belong to none), the muscle of each, rest lengths.
  std::vector<std::pair<Eigen::Index, Eigen::Index>> fibre_range_;
  Eigen::Index particle_count_ = 0;
  // Per muscle, its particles as ranges [first, end) of consecutive indices; tendons' bone anchors belong to none (not
  // measured: they are the bones' own points).
  std::vector<std::vector<std::pair<Eigen::Index, Eigen::Index>>> muscle_particle_runs_;
  std::vector<int> particle_own_bone_;  // the bone a fixed particle is fixed to (not measured against it), else -1
  // What the last frames' reads proved (FieldReadCache): [muscle][bone] about each surface vertex, [bone] about each
  // particle.
  mutable std::vector<std::vector<FieldReadCache>> vertex_reads_;
  mutable std::vector<FieldReadCache> particle_reads_;
  std::vector<int> fibre_muscle_;
  Eigen::VectorXd fibre_rest_length_;
};

}  // namespace muscle_deformation
