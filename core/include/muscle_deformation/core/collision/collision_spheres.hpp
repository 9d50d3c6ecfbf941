// Pre-processing for collision handling: sphere radii of muscle particles and sphere sets approximating bones.
#pragma once

#include "muscle_deformation/core/collision/collision_broad_phase.hpp"
#include "muscle_deformation/core/collision/collision_settings.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/base/anatomy.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

struct RestOverlapSummary {
  int muscle_muscle_pairs = 0;  // sphere pairs of different muscles overlapping at rest, shrunk to touching
  int muscle_bone_pairs = 0;    // muscle spheres overlapping a bone sphere at rest, shrunk to touching it
  int spheres_removed = 0;      // muscle particles whose centre lies inside a bone sphere: radius 0, no collision
};

// The rest pose must be free of contacts, or the solver deforms muscles that nothing has moved. Real anatomy is
// packed tight (neighbouring muscles touch, registered bones graze muscles), so the radii from
// assignCollisionRadii can overlap spheres of other muscles and of bones at rest. This shrinks them until they
// just touch: both spheres of a muscle-muscle pair by the same factor (as within a muscle), a muscle sphere against
// a (fixed) bone sphere on its own. Bone spheres are in the rest frame (as boneSpheresOneRing gives them).
RestOverlapSummary clearRestOverlaps(MassSpringSystem& system, const std::vector<SphereSet>& bone_spheres_rest);

// The seeds' one-ring heuristic (thesis 4.3): vertices are visited in index order; a vertex allowed by `rule` becomes
// a root and it and its ring are marked. Its sphere is centred at the root moved inward (against the area-weighted
// vertex normal) by the longest edge L at the root, radius L sqrt(2) (touches the far end of that edge when it lies
// in the tangent plane). Centres are in the bone's rest frame (the mesh's frame).
SphereSet boneSpheresOneRing(const TriangleMesh& surface,
                              OneRingRule rule = OneRingRule::disjoint_triangle_fans);

}  // namespace muscle_deformation
