// Moving particles with the bones before the soft-body solve (thesis 4.2, GRAPP 3.1).
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/model/model.hpp"

#include <Eigen/Geometry>

#include <vector>

namespace muscle_deformation {

using BoneTransforms = std::vector<Eigen::Isometry3d>;  // indexed by Bone::id

// Transforms of `bones` in `pose` (bones the pose does not mention stay at identity).
BoneTransforms boneTransformsOf(const std::vector<Bone>& bones, const Pose& pose);

// Cold start: every particle moved by the distance-weighted blend of its nearest bones' transforms (fixed particles
// exactly with their bone); previous = current, i.e. the solve starts at rest.
void rigidPretransform(const MassSpringSystem& system, const BoneTransforms& transforms, ParticleState& state);

// Warm start from the previous result: the fixed (attached) particles go exactly to their bones; each free particle
// keeps its previous shape but moves with the blend of its bones' motion since the previous pose
// (new * previous^-1), so that only the change of shape is left to the solver, not the bones' travel. Velocities are
// zeroed (previous = current): the old velocities belong to the old pose.
void warmStart(const MassSpringSystem& system, const BoneTransforms& previous_transforms,
               const BoneTransforms& transforms, ParticleState& state);

// Only the fixed (attached) particles follow their bones; free particles keep the previous result and velocity.
void moveAttachments(const MassSpringSystem& system, const BoneTransforms& transforms, ParticleState& state);

// How far the bones moved between two poses: the largest travel of a bone's rest centroid (m) and the largest angle
// a bone turned (rad), over all bones. Decides whether a new pose needs a solve at all (the node skips a pose no
// bone moved in) or a cold restart (a bone jumped).
struct BoneMotion {
  double translation_m = 0;
  double rotation_rad = 0;
};
BoneMotion largestBoneMotion(const BoneTransforms& from, const BoneTransforms& to,
                             const std::vector<Eigen::Vector3d>& rest_centroids);

// Mean of each bone's rest surface vertices (origin for a bone without vertices), by bone index.
std::vector<Eigen::Vector3d> boneRestCentroids(const std::vector<Bone>& bones);

// State at rest: positions = rest positions, zero velocity.
ParticleState restState(const MassSpringSystem& system);

}  // namespace muscle_deformation
