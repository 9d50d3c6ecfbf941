// PoseStream: warm for any smooth motion however far apart two solved poses are, cold only at a discontinuity.
#include "../src/pipeline/pose_stream.hpp"

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

TEST(PoseStream, UnchangedPoseIsSkippedAndTimeCountsFromTheLastSolvedPoseButSpeedFromTheLastReceived) {
  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  EXPECT_EQ(stream.decide(1.0, boneAt(0)).start, StreamStart::unchanged);
  stream.received(1.0, boneAt(0));  // skipped, not accepted
  // The tissue had the whole interval since the last solved pose; the bone's speed is measured since the last pose
  // received: 1 m in 1 s.
  const StreamDecision decision = stream.decide(2.0, boneAt(1.0));
  EXPECT_NEAR(decision.elapsed_s, 2.0, 1e-12);
  EXPECT_NEAR(decision.since_received_s, 1.0, 1e-12);
  EXPECT_NEAR(decision.motion.translation_m, 1.0, 1e-12);
  EXPECT_EQ(decision.start, StreamStart::warm) << decision.reason;
}

TEST(PoseStream, UnchangedIsJudgedAgainstTheLastPoseSolvedNotTheLastReceived) {
  // Poses creeping below the unchanged threshold each time still add up to a motion since the last solved pose.
  PoseStreamSettings settings;
  settings.unchanged_translation_m = 1e-3;
  PoseStream stream = streamOfOneBone(settings);
  stream.accept(0.0, boneAt(0));
  EXPECT_EQ(stream.decide(0.1, boneAt(0.0008)).start, StreamStart::unchanged);
  stream.received(0.1, boneAt(0.0008));
  const StreamDecision decision = stream.decide(0.2, boneAt(0.0016));  // 0.8 mm since received, 1.6 mm since solved
  EXPECT_EQ(decision.start, StreamStart::warm) << decision.reason;
  EXPECT_NEAR(decision.motion.translation_m, 0.0008, 1e-12);
}

TEST(PoseStream, AOneFrameJumpAfterAHoldStartsColdAlthoughTheHoldWasLong) {
  // The skeleton holds still for 0.5 s (every pose received and skipped as unchanged), then turns 1.5 rad in one
  // 60 Hz frame: 90 rad/s, a teleport. Measured over the whole hold it would look like 2.9 rad/s, a warm start.
  const double frame_s = 1.0 / 60.0;
  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  double time_s = 0;
  for (int frame = 1; frame <= 30; ++frame) {
    time_s = frame * frame_s;
    ASSERT_EQ(stream.decide(time_s, boneAt(0)).start, StreamStart::unchanged) << "frame " << frame;
    stream.received(time_s, boneAt(0));
  }
  ASSERT_NEAR(time_s, 0.5, 1e-12);
  const StreamDecision jump = stream.decide(time_s + frame_s, boneAt(0, 1.5));
  EXPECT_EQ(jump.start, StreamStart::cold);
  EXPECT_NE(jump.reason.find("faster than"), std::string::npos) << jump.reason;
  EXPECT_NEAR(jump.since_received_s, frame_s, 1e-12);
  EXPECT_NEAR(jump.elapsed_s, 0.5 + frame_s, 1e-12);

  // A stream told of no pose in between measures the speed over the whole hold (as every hold was judged before
  // received()): the same jump then looks warm.
  PoseStream untold = streamOfOneBone();
  untold.accept(0.0, boneAt(0));
  EXPECT_EQ(untold.decide(time_s + frame_s, boneAt(0, 1.5)).start, StreamStart::warm);
}

TEST(PoseStream, TimeGoingBackIsJudgedAgainstTheLastPoseReceivedToo) {
  PoseStream stream = streamOfOneBone();
  stream.accept(1.0, boneAt(0));
  stream.received(5.0, boneAt(0));  // skipped as unchanged
  const StreamDecision decision = stream.decide(3.0, boneAt(0.001));
  EXPECT_EQ(decision.start, StreamStart::cold);
  EXPECT_NE(decision.reason.find("time went back"), std::string::npos) << decision.reason;
}

TEST(PoseStream, AcceptingAPoseAlsoRecordsItAsReceived) {
  PoseStream stream = streamOfOneBone();
  stream.accept(0.0, boneAt(0));
  stream.received(0.5, boneAt(0));
  stream.accept(1.0, boneAt(0.1));
  const StreamDecision decision = stream.decide(1.5, boneAt(0.2));
  EXPECT_NEAR(decision.since_received_s, 0.5, 1e-12);
  EXPECT_NEAR(decision.elapsed_s, 0.5, 1e-12);
  EXPECT_NEAR(decision.motion.translation_m, 0.1, 1e-12);
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
