#include "muscle_deformation/node/scene_startup.hpp"

#include <ros/package.h>

#include <map>
#include <stdexcept>

namespace muscle_deformation::node {

std::string packageRoot() {
  const std::string root = ros::package::getPath("muscle_deformation");
  if (root.empty())
    throw std::runtime_error("cannot find the package muscle_deformation (source devel/setup.bash of the workspace)");
  return root;
}

UriResolver rosUriResolver(const std::string& package_root) {
  return [package_root](const std::string& uri) {
    std::map<std::string, std::string> roots{{"muscle_deformation", package_root}};
    const std::string prefix = "package://";
    if (uri.rfind(prefix, 0) == 0) {
      const std::string package = uri.substr(prefix.size(), uri.find('/', prefix.size()) - prefix.size());
      if (!roots.count(package)) {
        const std::string path = ros::package::getPath(package);
        if (!path.empty()) roots[package] = path;
      }
    }
    return makeUriResolver(roots, package_root)(uri);
  };
}

std::string describeSkeletonMismatch(const SceneDescription& scene, const Skeleton& robot_description,
                                     const UriResolver& resolve) {
  try {
    const Skeleton scene_skeleton = Skeleton::fromUrdfFile(resolveScenePath(scene, scene.urdf_file, resolve));
    const std::string differences = describeLinkDifferences(scene_skeleton, robot_description);
    if (differences.empty()) return {};
    return "the scene " + scene.path + " was made for another skeleton than " + robot_description.source() + " (" +
           differences + "); the node uses " + robot_description.source();
  } catch (const std::exception& e) {
    return "cannot compare " + robot_description.source() + " with the scene's urdf: " + e.what();
  }
}

void requireFixedFrameAtSceneFrame(const Scene& scene, const std::string& scene_frame, const std::string& fixed_frame) {
  const auto fixed = scene.rest_link_poses.find(fixed_frame);
  if (fixed == scene.rest_link_poses.end()) return;
  constexpr double kCoincident = 1e-6;  // m, and rad in the rotation's entries
  if ((fixed->second.matrix() - Eigen::Matrix4d::Identity()).cwiseAbs().maxCoeff() <= kCoincident) return;
  throw std::runtime_error("fixed_frame '" + fixed_frame + "' does not coincide with the scene's frame '" + scene_frame +
                           "' at the URDF's zero configuration, so the bones would be moved by the offset between "
                           "them; set fixed_frame to '" + scene_frame + "' (gait_playback.launch fixed_frame:=" +
                           scene_frame + ")");
}

}  // namespace muscle_deformation::node
