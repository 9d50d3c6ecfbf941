// Specifications of the joint-trajectory CSV loader (gait tables for ROS-free replay).
#include "muscle_deformation/core/scene/joint_trajectory.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;

namespace {

std::string writeTemporary(const std::string& name, const std::string& text) {
  const std::string path = (std::filesystem::temp_directory_path() / name).string();
  std::ofstream(path) << text;
  return path;
}

std::string loadError(const std::string& text) {
  const std::string path = writeTemporary("md_joint_trajectory_test.csv", text);
  return md::testing::errorMessageOf<md::SceneError>([&] { md::loadJointTrajectoryCsv(path); });
}

}  // namespace

TEST(JointTrajectory, ReadsHeaderRowsAndSkipsComments) {
  const std::string path = writeTemporary("md_joint_trajectory_ok.csv",
                                          "# a comment\n"
                                          "time_s, hip, knee\n"
                                          "0.0, 0.1, -0.2\n"
                                          "\n"
                                          "0.5, 0.3, -0.4\n");
  const md::JointTrajectory trajectory = md::loadJointTrajectoryCsv(path);
  ASSERT_EQ(trajectory.joint_names, (std::vector<std::string>{"hip", "knee"}));
  ASSERT_EQ(trajectory.frames.size(), 2u);
  EXPECT_DOUBLE_EQ(trajectory.times_s[1], 0.5);
  EXPECT_DOUBLE_EQ(trajectory.frames[0].at("knee"), -0.2);
  EXPECT_DOUBLE_EQ(trajectory.frames[1].at("hip"), 0.3);
}

TEST(JointTrajectory, ErrorsNameTheFileAndLine) {
  EXPECT_CONTAINS(loadError("hip,knee\n0,1\n"), "md_joint_trajectory_test.csv:1: the header must start with time_s");
  EXPECT_CONTAINS(loadError("time_s,hip,hip\n"), ":1: joint hip appears twice");
  EXPECT_CONTAINS(loadError("time_s,hip\n0,1\n1,2,3\n"), ":3: expected 2 columns, found 3");
  EXPECT_CONTAINS(loadError("time_s,hip\n0,abc\n"), ":2: column 2 ('abc') is not a finite number");
  EXPECT_CONTAINS(loadError("time_s,hip\n0,nan\n"), "is not a finite number");
  EXPECT_CONTAINS(loadError("time_s,hip\n0,1\n0,2\n"), ":3: time_s does not increase");
  EXPECT_CONTAINS(loadError("time_s,hip\n"), "no frames after the header");
  EXPECT_CONTAINS(loadError("# only a comment\n"), "no header line");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([] { md::loadJointTrajectoryCsv("/nonexistent/gait.csv"); }),
                  "/nonexistent/gait.csv: cannot open");
}

TEST(JointTrajectory, EvenlySpacedFramesIncludeBothEnds) {
  EXPECT_EQ(md::evenlySpacedFrames(73, 5), (std::vector<std::size_t>{0, 18, 36, 54, 72}));
  EXPECT_EQ(md::evenlySpacedFrames(3, 5), (std::vector<std::size_t>{0, 1, 2}));
  EXPECT_EQ(md::evenlySpacedFrames(10, 1), (std::vector<std::size_t>{0}));
  EXPECT_TRUE(md::evenlySpacedFrames(0, 5).empty());
}

TEST(JointTrajectory, BundledGaitTableMatchesTheBag) {
  // tools/scene/bag_to_csv.py wrote it from data/bags/gait_1cycle.bag: 73 frames at 60 Hz.
  const md::JointTrajectory gait = md::loadJointTrajectoryCsv(std::string(MD_PACKAGE_DIR) + "/data/gait/gait_1cycle.csv");
  ASSERT_EQ(gait.frames.size(), 73u);
  EXPECT_NEAR(gait.times_s.back() - gait.times_s.front(), 72.0 / 60.0, 1e-6);
  EXPECT_EQ(gait.frames[0].count("hip_flexion_r"), 1u);
  EXPECT_EQ(gait.frames[0].count("knee_angle_r"), 1u);
}
