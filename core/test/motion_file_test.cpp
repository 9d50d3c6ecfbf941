// Specifications of the OpenSim / SIMM motion file reader, on the two bundled walking trials (data/opensim/).
#include "muscle_deformation/core/scene/motion_file.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;

namespace {

const std::string kOneCycle = std::string(MD_PACKAGE_DIR) + "/data/opensim/subject01_walk1_ik_1cycle.mot";
const std::string kThreeCycles = std::string(MD_PACKAGE_DIR) + "/data/opensim/subject01_walk1_ik_3cycles.mot";

std::string writeTemporary(const std::string& text) {
  const std::string path = (std::filesystem::temp_directory_path() / "md_motion_file_test.mot").string();
  std::ofstream(path) << text;
  return path;
}

std::string loadError(const std::string& text) {
  const std::string path = writeTemporary(text);
  return md::testing::errorMessageOf<md::SceneError>([&] { md::loadMotionFile(path); });
}

}  // namespace

TEST(MotionFile, ReadsTheSimmHeaderOfTheOneCycleTrial) {
  const md::MotionTable motion = md::loadMotionFile(kOneCycle);
  ASSERT_EQ(motion.rowCount(), 73u);
  ASSERT_EQ(motion.column_names.size(), 23u);
  EXPECT_EQ(motion.column_names.front(), "pelvis_tilt");
  EXPECT_DOUBLE_EQ(motion.times_s.front(), 0.4);
  EXPECT_DOUBLE_EQ(motion.times_s.back(), 1.6);
  EXPECT_DOUBLE_EQ(motion.value(0, "knee_angle_r"), -55.15907196);
  EXPECT_DOUBLE_EQ(motion.value(72, "hip_flexion_r"), 16.73503228);
}

TEST(MotionFile, TakesDegreesWhenTheHeaderDoesNotSay) {
  const md::MotionTable motion = md::loadMotionFile(kOneCycle);
  EXPECT_TRUE(motion.angles_in_degrees);
  EXPECT_FALSE(motion.angle_unit_stated);
}

TEST(MotionFile, ReadsTheOpenSimHeaderOfTheThreeCycleTrial) {
  const md::MotionTable motion = md::loadMotionFile(kThreeCycles);
  ASSERT_EQ(motion.rowCount(), 211u);
  ASSERT_EQ(motion.column_names.size(), 23u);
  EXPECT_TRUE(motion.angles_in_degrees);
  EXPECT_TRUE(motion.angle_unit_stated);
  EXPECT_DOUBLE_EQ(motion.times_s.front(), 0.5);
  EXPECT_DOUBLE_EQ(motion.times_s.back(), 4.0);
  EXPECT_DOUBLE_EQ(motion.value(0, "knee_angle_r"), -19.85408256);
  EXPECT_DOUBLE_EQ(motion.value(210, "knee_angle_r"), -69.1698705);
}

TEST(MotionFile, ReadsInDegreesNo) {
  const md::MotionTable motion =
      md::loadMotionFile(writeTemporary("inDegrees=no\nendheader\ntime\tknee\n0\t-0.5\n0.1\t-0.6\n"));
  EXPECT_FALSE(motion.angles_in_degrees);
  EXPECT_TRUE(motion.angle_unit_stated);
  EXPECT_DOUBLE_EQ(motion.value(1, "knee"), -0.6);
}

TEST(MotionFile, AnUnknownColumnIsAnErrorNamingTheFile) {
  const md::MotionTable motion = md::loadMotionFile(kOneCycle);
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>([&] { motion.columnIndex("knee_angle"); }),
                  "subject01_walk1_ik_1cycle.mot: no column 'knee_angle'");
}

TEST(MotionFile, ErrorsNameTheFileAndLine) {
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([] { md::loadMotionFile("/nonexistent/walk.mot"); }),
                  "/nonexistent/walk.mot: cannot open");
  EXPECT_CONTAINS(loadError("time\tknee\n0\t1\n"), "md_motion_file_test.mot: no endheader line");
  EXPECT_CONTAINS(loadError("endheader\nknee\ttime\n0\t1\n"), "md_motion_file_test.mot:2: the column line must start");
  EXPECT_CONTAINS(loadError("endheader\ntime\tknee\n0\t1\n0.1\t2\t3\n"), ":4: expected 2 fields, found 3");
  EXPECT_CONTAINS(loadError("endheader\ntime\tknee\n0\tx\n"), ":3: field 2 ('x') is not a finite number");
  EXPECT_CONTAINS(loadError("endheader\ntime\tknee\n0\t1\n0\t2\n"), ":4: time does not increase");
  EXPECT_CONTAINS(loadError("endheader\ntime\tknee\n"), "no rows after the column line");
  EXPECT_CONTAINS(loadError("nRows=3\nendheader\ntime\tknee\n0\t1\n"), ":1: the header states 3 rows, the table has 1");
  EXPECT_CONTAINS(loadError("datacolumns 3\nendheader\ntime\tknee\n0\t1\n"), ":1: the header states 3 columns");
  EXPECT_CONTAINS(loadError("inDegrees=maybe\nendheader\ntime\tknee\n0\t1\n"), ":1: inDegrees must be yes or no");
}
