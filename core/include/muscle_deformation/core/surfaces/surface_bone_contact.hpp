// Skinned muscle surfaces kept out of the bones: the contact of the skin with the bone.
//
// The skinning places every surface vertex from the particles near it. The solver keeps the particles out of the bones,
// but a vertex between particles can still lie inside a bone, most where a muscle wraps round one: in hip flexion the
// iliacus and psoas slide over the pelvic brim, and their skinned surfaces cut into it by millimetres while their
// particles stay out. After the skinning, every vertex inside a bone (its distance field) is moved out along the
// field's gradient to the bone's surface plus a clearance, as a particle in contact would be. The volume constraint
// that follows (surface_volume.hpp) never moves a vertex into a bone, so the surface the user sees stays out.
#pragma once

#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include <vector>

namespace muscle_deformation {

// What the contact did to one muscle's surface in one frame.
struct SurfaceBoneCorrection {
  int vertices_moved = 0;               // vertices that were inside a bone
  double max_depth_before_m = 0;        // the deepest of them, as skinned (the skinning's own depth in bone)
  double max_move_m = 0;                // the longest move
};

class SurfaceBoneContact {
 public:
  // A vertex is moved to this far outside the bone: a quarter of the finest 1 mm voxel, so that the field read
  // afterwards (interpolated between voxels) says outside.
  static constexpr double kClearanceM = 0.00025;
  // Steps along the gradient a deep vertex may take (the field is re-read after each): enough for the bundled data's
  // deepest skinned vertices (about 10 mm inside).
  static constexpr int kMaxSteps = 4;

  // `vertex_counts[m]`: muscle m's surface vertices; `bone_fields`: one per bone id, none null.
  SurfaceBoneContact(std::vector<Eigen::Index> vertex_counts, BoneFields bone_fields);

  // Moves every vertex of surfaces[m] that lies inside a bone placed by `bone_transforms` (indexed like the fields;
  // missing ones stay at rest) out to kClearanceM outside it. Returns one correction per muscle. Remembers what it
  // read of the fields (FieldReadCache), so a frame reads only vertices that may have come close to a bone; one
  // instance serves one frame at a time. `threads` share the muscles out; the result does not depend on it.
  std::vector<SurfaceBoneCorrection> apply(std::vector<Vertices>& surfaces, const BoneTransforms& bone_transforms,
                                           int threads = 1) const;

 private:
  BoneFields bone_fields_;
  mutable std::vector<std::vector<FieldReadCache>> reads_;  // [muscle][bone]
};

}  // namespace muscle_deformation
