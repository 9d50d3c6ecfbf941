#include "muscle_deformation/support/bundled_scene.hpp"

namespace muscle_deformation {

BundledScene loadBundledScene(const std::string& package_dir, const std::vector<std::string>& selection) {
  const SceneDescription description = loadSceneDescription(package_dir + "/config/scenes/right_hip_thigh.yaml");
  const UriResolver resolve = makeUriResolver({{"muscle_deformation", package_dir}}, package_dir);
  const Skeleton skeleton = Skeleton::fromUrdfFile(resolveScenePath(description, description.urdf_file, resolve));
  BundledScene bundled;
  bundled.scene = loadScene(description, skeleton, resolve, selection);
  bundled.gait = loadJointTrajectoryCsv(package_dir + "/data/gait/gait_1cycle.csv");
  return bundled;
}

Pose poseFor(const BundledScene& bundled, const JointValues& joints) {
  return poseFromLinkPoses(bundled.scene, bundled.scene.skeleton.linkPoses(joints));
}

Pose gaitPose(const BundledScene& bundled, std::size_t frame) { return poseFor(bundled, bundled.gait.frames.at(frame)); }

std::vector<std::size_t> fiveGaitFrames(const BundledScene& bundled) {
  return evenlySpacedFrames(bundled.gait.frames.size(), 5);
}

}  // namespace muscle_deformation
