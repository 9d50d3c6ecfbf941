// Where the bones of a pose are: one rigid transform per bone from its rest placement, and how far bones moved between
// two poses. Shared vocabulary of every stage (the model's pre-transform, the collision stage, the surfaces, the
// pipeline's stream decisions).
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"

#include <Eigen/Geometry>

#include <vector>

namespace muscle_deformation {

using BoneTransforms = std::vector<Eigen::Isometry3d>;  // indexed by Bone::id

// Transforms of `bones` in `pose` (bones the pose does not mention stay at identity).
BoneTransforms boneTransformsOf(const std::vector<Bone>& bones, const Pose& pose);

// How far the bones moved between two poses: the largest travel of a bone's rest centroid (m) and the largest angle
// a bone turned (rad), over all bones. Decides whether a new pose needs a solve at all (the stream skips a pose no
// bone moved in) or a cold restart (a bone jumped).
struct BoneMotion {
  double translation_m = 0;
  double rotation_rad = 0;
};
BoneMotion largestBoneMotion(const BoneTransforms& from, const BoneTransforms& to,
                             const std::vector<Eigen::Vector3d>& rest_centroids);

// Mean of each bone's rest surface vertices (origin for a bone without vertices), by bone index.
std::vector<Eigen::Vector3d> boneRestCentroids(const std::vector<Bone>& bones);

}  // namespace muscle_deformation
