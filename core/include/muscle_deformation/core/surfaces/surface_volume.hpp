// Muscle surfaces that keep their rest volume: the volume constraint of position-based dynamics (Müller et al. 2007;
// the 2019 PBD thesis, section 5.2.4) applied to each skinned muscle surface after every solve.
//
// Muscle tissue is nearly incompressible, but neither the springs nor the skinning conserve the enclosed volume: a
// muscle that shortens should bulge and does not. The constraint C = V(surface) - V_rest is projected in the PBD way,
//   delta p_i = -C w_i grad_i V / sum_j w_j |grad_j V|^2,   grad_i V = 1/6 sum over the triangles (i, j, k) of p_j x p_k,
// with each vertex weighted by its share of the surface (w_i = 1 / |grad_i V|), which moves every vertex the same
// distance along its normal (outwards when volume was lost). Along fixed normals the enclosed volume is a cubic in
// that distance, so the distance that restores the rest volume is solved for exactly (the PBD projection repeated to
// convergence). Vertices the move would put into a bone (its distance field) keep their place instead (w_i = 0) and
// the others make up the volume.
#pragma once

#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

struct SurfaceVolumeSettings {
  bool keep_volume = true;            // project every skinned surface to its rest volume
  int max_rounds = 4;                 // per muscle and frame: a round solves again once vertices were held by a bone
  double tolerance_fraction = 1e-4;   // a surface within this fraction of its rest volume (0.01 %) is left as it is
};

std::string validate(const SurfaceVolumeSettings& settings);

// What the projection did to one muscle's surface in one frame.
struct SurfaceVolumeCorrection {
  double volume_error_before_pct = 0;  // the skinned surface's own (signed), before the projection
  double volume_error_after_pct = 0;   // signed, after
  double max_offset_m = 0;             // the largest distance a vertex was moved
  double mean_offset_m = 0;            // over all vertices of the muscle
  int vertices_held_by_bone = 0;       // vertices the move would have put into a bone, left in place
};

class SurfaceVolumeConstraint {
 public:
  // One entry per muscle: its triangles (as the skinned surfaces use them) and its closed rest surface vertices, whose
  // enclosed volume is kept (whatever the winding). `bone_fields` (one per bone id, none null; may be empty: then no
  // vertex is held) keep vertices out of bones. Throws std::invalid_argument on a surface that encloses no volume.
  SurfaceVolumeConstraint(const std::vector<Triangles>& triangles, const std::vector<Vertices>& rest_vertices,
                          BoneFields bone_fields, SurfaceVolumeSettings settings);

  // Projects surfaces[m] of every muscle to its rest volume. `bone_transforms` place the bones (indexed like the
  // fields; missing ones stay at rest). Returns one correction per muscle. `threads` share the muscles out; the result
  // does not depend on it.
  std::vector<SurfaceVolumeCorrection> apply(std::vector<Vertices>& surfaces, const BoneTransforms& bone_transforms,
                                             int threads = 1) const;

  double restVolume(int muscle) const { return rest_volume_[static_cast<std::size_t>(muscle)]; }
  const SurfaceVolumeSettings& settings() const { return settings_; }

 private:
  SurfaceVolumeCorrection project(int muscle, Vertices& surface, const std::vector<Eigen::Isometry3d>& to_bone_rest,
                                  const std::vector<AlignedBox>& bone_reach) const;

  std::vector<Triangles> triangles_;
  std::vector<double> rest_volume_;  // positive
  std::vector<double> winding_;      // +1 when the triangles wind outwards, -1 otherwise
  BoneFields bone_fields_;
  double unchecked_travel_m_ = 0;  // a quarter voxel of the finest field: shorter moves are not checked
  SurfaceVolumeSettings settings_;
};

}  // namespace muscle_deformation
