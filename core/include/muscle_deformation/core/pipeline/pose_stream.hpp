// How a stream of skeleton poses is started: warm from the previous result moved with the bones (valid for any motion
// of a rigid skeleton, however far), cold only at a real discontinuity, and not solved at all when no bone moved.
//
// A discontinuity is time going back (a looping bag, a restarted recording) or a bone moving faster than a skeleton
// can: a teleport. Distance alone is no such sign: when the solver falls behind and poses in between are dropped, the
// bones of two solved frames are far apart although the motion was smooth.
#pragma once

#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

struct PoseStreamSettings {
  bool warm_start = true;  // false: every pose is solved cold
  // A bone centre moving faster than this between two poses is a teleport (m/s). The fastest human limb segments
  // reach a few m/s (a sprinter's foot about 20 m/s at most); the thigh and pelvis stay well below 10 m/s.
  double max_bone_speed_m_per_s = 20.0;
  // Same for rotation (rad/s); the fastest joint motions (a throwing arm) reach about 50 rad/s, the hip and knee less.
  double max_bone_angular_speed_rad_per_s = 50.0;
  double unchanged_translation_m = 1e-7;  // no bone moved more than this (and turned less than the next): skip
  double unchanged_rotation_rad = 1e-7;
};

// Checks the settings; returns a message naming the problem, or an empty string.
std::string validate(const PoseStreamSettings& settings);

enum class StreamStart { warm, cold, unchanged };

struct StreamDecision {
  StreamStart start = StreamStart::cold;
  std::string reason;  // why a pose starts cold or is skipped (empty for a warm start)
  BoneMotion motion;   // since the previous accepted pose
  double elapsed_s = 0;  // time since the previous accepted pose
};

class PoseStream {
 public:
  PoseStream(std::vector<Eigen::Vector3d> bone_rest_centroids, PoseStreamSettings settings);

  // What to do with the pose at `time_s` (seconds, any epoch) with these bone transforms. Const: call accept() once
  // the pose has been solved, or reset() if its solve failed.
  StreamDecision decide(double time_s, const BoneTransforms& transforms) const;
  // The pose was solved; its result is what the next warm start moves.
  void accept(double time_s, const BoneTransforms& transforms);
  // Forget the previous pose: the next one starts cold.
  void reset() { has_previous_ = false; }
  bool hasPrevious() const { return has_previous_; }
  const PoseStreamSettings& settings() const { return settings_; }

 private:
  std::vector<Eigen::Vector3d> centroids_;
  PoseStreamSettings settings_;
  bool has_previous_ = false;
  double previous_time_s_ = 0;
  BoneTransforms previous_transforms_;
};

}  // namespace muscle_deformation
