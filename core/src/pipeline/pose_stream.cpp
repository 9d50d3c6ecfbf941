#include "pose_stream.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace muscle_deformation {

std::string validate(const PoseStreamSettings& settings) {
  if (!(settings.max_bone_speed_m_per_s > 0)) return "max_bone_speed_m_per_s must be > 0";
  if (!(settings.max_bone_angular_speed_rad_per_s > 0)) return "max_bone_angular_speed_rad_per_s must be > 0";
  if (!(settings.unchanged_translation_m >= 0) || !(settings.unchanged_rotation_rad >= 0))
    return "the unchanged-pose thresholds must be >= 0";
  return "";
}

PoseStream::PoseStream(std::vector<Eigen::Vector3d> bone_rest_centroids, PoseStreamSettings settings)
    : centroids_(std::move(bone_rest_centroids)), settings_(settings) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("pose stream settings: " + problem);
}

StreamDecision PoseStream::decide(double time_s, const BoneTransforms& transforms) const {
  StreamDecision decision;
  if (!has_previous_) {
    decision.reason = "first pose of the stream";
    return decision;
  }
  const BoneTransforms& reference = has_received_ ? received_transforms_ : previous_transforms_;
  const double reference_time_s = has_received_ ? received_time_s_ : previous_time_s_;
  decision.motion = largestBoneMotion(reference, transforms, centroids_);
  decision.elapsed_s = time_s - previous_time_s_;
  decision.since_received_s = time_s - reference_time_s;
  const BoneMotion since_solved = largestBoneMotion(previous_transforms_, transforms, centroids_);
  const bool moved = since_solved.translation_m > settings_.unchanged_translation_m ||
                     since_solved.rotation_rad > settings_.unchanged_rotation_rad;
  const double moved_m = decision.motion.translation_m, turned_rad = decision.motion.rotation_rad;
  const double dt = decision.since_received_s;
  std::ostringstream why;
  if (dt < 0 || decision.elapsed_s < 0) {
    why << "time went back by " << -std::min(dt, decision.elapsed_s) << " s";
  } else if (!moved) {
    decision.start = StreamStart::unchanged;
    decision.reason = "no bone moved";
    return decision;
  } else if (dt == 0) {
    why << "the bones moved (" << moved_m << " m, " << turned_rad << " rad) with no time passing";
  } else if (moved_m > settings_.max_bone_speed_m_per_s * dt || turned_rad > settings_.max_bone_angular_speed_rad_per_s * dt) {
    why << "a bone moved " << moved_m << " m and turned " << turned_rad << " rad in " << dt << " s, faster than "
        << settings_.max_bone_speed_m_per_s << " m/s or " << settings_.max_bone_angular_speed_rad_per_s << " rad/s";
  } else {
    decision.start = settings_.warm_start ? StreamStart::warm : StreamStart::cold;
    if (!settings_.warm_start) decision.reason = "warm starts are off";
    return decision;
  }
  decision.start = StreamStart::cold;
  decision.reason = why.str();
  return decision;
}

void PoseStream::received(double time_s, const BoneTransforms& transforms) {
  has_received_ = true;
  received_time_s_ = time_s;
  received_transforms_ = transforms;
}

void PoseStream::accept(double time_s, const BoneTransforms& transforms) {
  has_previous_ = true;
  previous_time_s_ = time_s;
  previous_transforms_ = transforms;
  received(time_s, transforms);
}

}  // namespace muscle_deformation
