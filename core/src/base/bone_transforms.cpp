#include "muscle_deformation/core/base/bone_transforms.hpp"

#include <algorithm>
#include <cmath>

namespace muscle_deformation {

BoneTransforms boneTransformsOf(const std::vector<Bone>& bones, const Pose& pose) {
  BoneTransforms transforms;
  transforms.reserve(bones.size());
  for (const Bone& bone : bones) transforms.push_back(pose.transformOf(bone.name));
  return transforms;
}

BoneMotion largestBoneMotion(const BoneTransforms& from, const BoneTransforms& to,
                             const std::vector<Eigen::Vector3d>& rest_centroids) {
  BoneMotion motion;
  const std::size_t count = std::min({from.size(), to.size(), rest_centroids.size()});
  for (std::size_t i = 0; i < count; ++i) {
    motion.translation_m =
        std::max(motion.translation_m, (to[i] * rest_centroids[i] - from[i] * rest_centroids[i]).norm());
    const Eigen::AngleAxisd turn(to[i].linear() * from[i].linear().transpose());
    motion.rotation_rad = std::max(motion.rotation_rad, std::abs(turn.angle()));
  }
  return motion;
}

std::vector<Eigen::Vector3d> boneRestCentroids(const std::vector<Bone>& bones) {
  std::vector<Eigen::Vector3d> centroids;
  centroids.reserve(bones.size());
  for (const Bone& bone : bones) {
    const Vertices& v = bone.surface.vertices;
    centroids.push_back(v.cols() ? Eigen::Vector3d(v.rowwise().mean()) : Eigen::Vector3d::Zero());
  }
  return centroids;
}

}  // namespace muscle_deformation
