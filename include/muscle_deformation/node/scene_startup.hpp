// What the node checks and resolves while it starts, before the model is built: where the package lives, how the
// scene's URIs become files, and whether the scene fits the skeleton and the fixed frame it is given.
#pragma once

#include "muscle_deformation/core/scene/scene.hpp"

#include <string>

namespace muscle_deformation::node {

// The package's folder; throws std::runtime_error saying how to make it findable.
std::string packageRoot();

// package:// URIs of any ROS package, file:// and paths relative to the package root.
UriResolver rosUriResolver(const std::string& package_root);

// robot_description is what the node runs on; a scene made for another skeleton usually still names links that
// robot_description has, so the link sets are compared with the scene's own `urdf:` file and a warning says how they
// differ (empty: they do not, or the comparison was impossible, which is said too).
std::string describeSkeletonMismatch(const SceneDescription& scene, const Skeleton& robot_description,
                                     const UriResolver& resolve);

// Bones are looked up in the fixed frame while the scene's surfaces are given in the scene's own frame: at rest the two
// must coincide, or every bone would be moved by the offset between them. Throws std::runtime_error saying what to set.
// A fixed frame that is not a link of the skeleton (a frame above it in tf) cannot be checked here.
void requireFixedFrameAtSceneFrame(const Scene& scene, const std::string& scene_frame, const std::string& fixed_frame);

}  // namespace muscle_deformation::node
