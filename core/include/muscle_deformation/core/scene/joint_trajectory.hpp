// A recorded skeleton motion as a table of joint positions (data/gait/*.csv, written by tools/scene/bag_to_csv.py
// from the gait bags), so ROS-free programs can replay the gait the node sees.
#pragma once

#include "muscle_deformation/core/scene/scene.hpp"

#include <cstddef>
#include <string>
#include <vector>

namespace muscle_deformation {

struct JointTrajectory {
  std::vector<std::string> joint_names;
  std::vector<double> times_s;     // one per frame, strictly increasing
  std::vector<JointValues> frames;  // joint positions (rad or m) of each frame
};

// Reads a CSV: '#' lines are comments; the first other line is the header `time_s,<joint>,...`; then one row per
// frame. Throws SceneError naming the file and line for a missing file, a malformed header, a row with the wrong
// number of columns, a value that is not a finite number, or times that do not increase.
JointTrajectory loadJointTrajectoryCsv(const std::string& path);

// `count` frame indices spread evenly over the trajectory, first and last frame included (count >= 2), e.g. the five
// gait poses the paper averages over. Fewer if the trajectory has fewer frames.
std::vector<std::size_t> evenlySpacedFrames(std::size_t frame_count, std::size_t count);

}  // namespace muscle_deformation
