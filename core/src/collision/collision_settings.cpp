#include "muscle_deformation/core/collision/collision_settings.hpp"

#include <cmath>

namespace muscle_deformation {

const char* toString(BroadPhaseKind kind) {
  switch (kind) {
    case BroadPhaseKind::octree:
      return "octree";
    case BroadPhaseKind::hash_grid:
      return "hash_grid";
  }
  return "unknown";
}

const char* toString(BoneProxyKind kind) {
  switch (kind) {
    case BoneProxyKind::one_ring_spheres:
      return "one_ring_spheres";
    case BoneProxyKind::distance_field:
      return "distance_field";
  }
  return "unknown";
}

std::string validate(const CollisionSettings& settings) {
  if (settings.octree_max_depth < 0) return "octree_max_depth must be >= 0";
  if (settings.octree_min_primitives < 1) return "octree_min_primitives must be >= 1";
  if (!(settings.hash_cell_scale > 0.0) || !std::isfinite(settings.hash_cell_scale))
    return "hash_cell_scale must be a positive number";
  if (!(settings.bone_reach_margin_m >= 0.0) || !std::isfinite(settings.bone_reach_margin_m))
    return "bone_reach_margin_m must be >= 0 (metres)";
  if (settings.bone_proxy == BoneProxyKind::distance_field)
    if (std::string problem = validate(settings.bone_field); !problem.empty()) return problem;
  return {};
}

}  // namespace muscle_deformation
