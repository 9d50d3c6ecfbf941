// The anatomy the product deforms: rigid bones, muscles with fibres, and a skeleton pose.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <Eigen/Geometry>

#include <map>
#include <string>
#include <vector>

namespace muscle_deformation {

struct Bone {
  int id = -1;           // index in the scene's bone list
  std::string name;      // URDF link name, e.g. "femur_r"
  TriangleMesh surface;  // rest pose, metres, in the scene (fixed) frame
};

struct Muscle {
  std::string name;               // e.g. "rectus_femoris"
  TriangleMesh surface;           // closed, 2-manifold, rest pose, scene frame
  std::vector<Polyline> fibres;   // origin to insertion, rest pose, scene frame
  // The bones (Bone::name) the muscle is attached to: its particles are fixed to these only, and collide with any
  // other bone. Both empty: the muscle is attached to whichever bone its particles are near (synthetic set-ups).
  std::string origin_bone, insertion_bone;
};

// Rigid transform of every bone from its rest placement to the current one (scene frame).
// Bones missing from the map stay at rest.
struct Pose {
  std::map<std::string, Eigen::Isometry3d> bone_transforms;

  Eigen::Isometry3d transformOf(const std::string& bone) const {
    auto it = bone_transforms.find(bone);
    return it == bone_transforms.end() ? Eigen::Isometry3d::Identity() : it->second;
  }
};

}  // namespace muscle_deformation
