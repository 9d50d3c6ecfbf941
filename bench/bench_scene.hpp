// The bundled scene (config/scenes/right_hip_thigh.yaml) and its gait (data/gait/gait_1cycle.csv) for the benchmarks
// that measure on real anatomy.
#pragma once

#include "muscle_deformation/core/scene/joint_trajectory.hpp"
#include "muscle_deformation/core/model/model.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <string>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace bench {

struct BundledScene {
  muscle_deformation::Scene scene;
  muscle_deformation::JointTrajectory gait;  // the 1-cycle gait bag's joint positions, 60 Hz
};

// Loads the selected muscles (names or tags; the paper's 13 thigh muscles are the tag `thigh13`) with every bone.
inline BundledScene loadBundledScene(const std::vector<std::string>& selection = {"thigh13"}) {
  namespace md = muscle_deformation;
  const std::string package = MD_PACKAGE_DIR;
  const md::SceneDescription description = md::loadSceneDescription(package + "/config/scenes/right_hip_thigh.yaml");
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description.urdf_file, package));
  BundledScene bundled;
  bundled.scene =
      md::loadScene(description, skeleton, md::makeUriResolver({{"muscle_deformation", package}}, package), package,
                    selection);
  bundled.gait = md::loadJointTrajectoryCsv(package + "/data/gait/gait_1cycle.csv");
  return bundled;
}

// The bones' pose for any joint positions (joints left out stay at 0).
inline muscle_deformation::Pose poseFor(const BundledScene& bundled, const muscle_deformation::JointValues& joints) {
  return muscle_deformation::poseFromLinkPoses(bundled.scene, bundled.scene.skeleton.linkPoses(joints));
}

// The bones' pose at a frame of the gait.
inline muscle_deformation::Pose gaitPose(const BundledScene& bundled, std::size_t frame) {
  return poseFor(bundled, bundled.gait.frames.at(frame));
}

// The five gait frames the paper-style averages use: spread evenly over the cycle, both ends included.
inline std::vector<std::size_t> fiveGaitFrames(const BundledScene& bundled) {
  return muscle_deformation::evenlySpacedFrames(bundled.gait.frames.size(), 5);
}

}  // namespace bench
