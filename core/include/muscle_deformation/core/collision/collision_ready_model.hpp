// The model a solve with collisions runs on: the mass-spring system with the collision stage's bone proxies, made
// consistent at rest. It sits above the model builder and the collision proxies, which it combines.
#pragma once

#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/collision/collision_settings.hpp"
#include "muscle_deformation/core/collision/collision_spheres.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"

#include <memory>
#include <vector>

namespace muscle_deformation {

// The model a collision-aware solve runs on, final when returned: the system with its collision radii shrunk so that
// the rest pose is free of contacts (clearRestOverlaps), and each bone's proxy in its rest frame: its sphere set
// (boneSpheresOneRing) or its signed distance field, as `collision.bone_proxy` says. With fields only muscle-muscle
// overlaps are cleared: the field keeps each particle no deeper than it lies at rest instead of shrinking anything.
// `prebuilt_fields` (one per bone, built with collision.bone_field) are used instead of building them again.
// Build solvers after it, never before: they precompute from the radii.
struct CollisionReadyModel {
  MassSpringSystem system;
  std::vector<SphereSet> bone_spheres;  // per bone, in the order of `bones` (sphere proxy; empty with fields)
  std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields;  // per bone (field proxy; empty with spheres)
  RestOverlapSummary rest_overlaps;
};
CollisionReadyModel buildCollisionReadyModel(const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                             const ModelSettings& settings, const CollisionSettings& collision,
                                             ModelBuildReport* report = nullptr, const BoneFields& prebuilt_fields = {});

}  // namespace muscle_deformation
