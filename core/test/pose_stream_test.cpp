// PoseStream: warm for any smooth motion however far apart two solved poses are, cold only at a discontinuity.
#include "muscle_deformation/core/pipeline/pose_stream.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;

namespace {

// One bone whose rest centroid is at the origin, moved along x by `x_m` and turned about z by `angle_rad`.
BoneTransforms boneAt(double x_m, double angle_rad = 0) {
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  transform.translate(Eigen::Vector3d(x_m, 0, 0));
  transform.rotate(Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::UnitZ()));
  return {transform};
}

PoseStream streamOfOneBone(PoseStreamSettings settings = {}) {
  return PoseStream({Eigen::Vector3d::Zero()}, settings);
}

}  // namespace

TEST(PoseStream, FirstPoseStartsCold) {
  const PoseStream stream = streamOfOneBone();
  EXPECT_EQ(stream.decide(0.0, boneAt(0)).start, StreamStart::cold);
}

TEST(PoseStream, StaysWarmWhenFramesInBetweenWereDropped) {
  // A gait at 60 Hz solved only every 10th frame: the thigh moved 0.1 m between solved frames, twice the old
  // 0.05 m jump threshold, at an ordinary 0.6 m/s.
  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  const StreamDecision decision = stream.decide(10.0 / 60.0, boneAt(0.1, 0.4));
  EXPECT_EQ(decision.start, StreamStart::warm) << decision.reason;
  EXPECT_NEAR(decision.motion.translation_m, 0.1, 1e-12);
  EXPECT_NEAR(decision.elapsed_s, 10.0 / 60.0, 1e-12);
}

TEST(PoseStream, ATeleportStartsColdAndSaysWhy) {
  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  const StreamDecision moved = stream.decide(1.0 / 60.0, boneAt(1.0));  // 60 m/s
  EXPECT_EQ(moved.start, StreamStart::cold);
  EXPECT_NE(moved.reason.find("faster than"), std::string::npos) << moved.reason;
  const StreamDecision turned = stream.decide(1.0 / 60.0, boneAt(0.0, 1.5));  // 90 rad/s
  EXPECT_EQ(turned.start, StreamStart::cold) << turned.reason;
}

TEST(PoseStream, TimeGoingBackStartsCold) {
  PoseStream stream = streamOfOneBone();
  stream.accept(5.0, boneAt(0));
  const StreamDecision decision = stream.decide(1.0, boneAt(0.001));
  EXPECT_EQ(decision.start, StreamStart::cold);
  EXPECT_NE(decision.reason.find("time went back"), std::string::npos) << decision.reason;
}

TEST(PoseStream, MotionWithoutTimePassingStartsCold) {
  PoseStream stream = streamOfOneBone();
  stream.accept(1.0, boneAt(0));
  EXPECT_EQ(stream.decide(1.0, boneAt(0.01)).start, StreamStart::cold);
}

TEST(PoseStream, UnchangedPoseIsSkippedAndTimeCountsFromTheLastSolvedPose) {
  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  EXPECT_EQ(stream.decide(1.0, boneAt(0)).start, StreamStart::unchanged);
  // Skipped poses are not accepted: the next motion's speed is measured over the whole interval.
  EXPECT_NEAR(stream.decide(2.0, boneAt(1.0)).elapsed_s, 2.0, 1e-12);
  EXPECT_EQ(stream.decide(2.0, boneAt(1.0)).start, StreamStart::warm);
}

TEST(PoseStream, ResetAndDisabledWarmStartsGiveColdStarts) {
  PoseStreamSettings settings;
  settings.warm_start = false;
  PoseStream cold_only = streamOfOneBone(settings);
  cold_only.accept(0.0, boneAt(0));
  EXPECT_EQ(cold_only.decide(0.1, boneAt(0.01)).start, StreamStart::cold);

  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  stream.reset();
  EXPECT_EQ(stream.decide(0.1, boneAt(0.01)).start, StreamStart::cold);
}

TEST(PoseStream, RefusesNonPositiveSpeedLimits) {
  PoseStreamSettings settings;
  settings.max_bone_speed_m_per_s = 0;
  EXPECT_THROW(streamOfOneBone(settings), std::invalid_argument);
}
