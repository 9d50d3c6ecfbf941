// The bundled scene (config/scenes/right_hip_thigh.yaml) and its gait (data/gait/gait_1cycle.csv), loaded as the
// benchmarks and tests that measure on real anatomy use them.
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/scene/joint_trajectory.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <cstddef>
#include <string>
#include <vector>

namespace muscle_deformation {

struct BundledScene {
  Scene scene;
  JointTrajectory gait;  // the 1-cycle gait bag's joint positions, 60 Hz
};

// Loads the selected muscles (names or tags; the paper's 13 thigh muscles are the tag `thigh13`; empty = all) with
// every bone, from the checkout or installed package at `package_dir`.
BundledScene loadBundledScene(const std::string& package_dir, const std::vector<std::string>& selection = {"thigh13"});

// The bones' pose for any joint positions (joints left out stay at 0).
Pose poseFor(const BundledScene& bundled, const JointValues& joints);

// The bones' pose at a frame of the gait.
Pose gaitPose(const BundledScene& bundled, std::size_t frame);

// The five gait frames the paper-style averages use: spread evenly over the cycle, both ends included.
std::vector<std::size_t> fiveGaitFrames(const BundledScene& bundled);

}  // namespace muscle_deformation
