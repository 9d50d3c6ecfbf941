// Private to the stream session (stream_session.cpp), which owns the one PoseStream of a stream. How a stream of
// skeleton poses is started: warm from the previous result moved with the bones (valid for any motion
// of a rigid skeleton, however far), cold only at a real discontinuity, and not solved at all when no bone moved.
//
// A discontinuity is time going back (a looping bag, a restarted recording) or a bone moving faster than a skeleton
// can: a teleport. Distance alone is no such sign: when the solver falls behind and poses in between are dropped, the
// bones of two solved frames are far apart although the motion was smooth.
#pragma once

#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

enum class StreamStart { warm, cold, unchanged };

struct StreamDecision {
  StreamStart start = StreamStart::cold;
  std::string reason;     // why a pose starts cold or is skipped (empty for a warm start)
  BoneMotion motion;      // since the last pose received (solved or skipped as unchanged)
  double elapsed_s = 0;   // time since the last pose solved: what the tissue had to relax in
  double since_received_s = 0;  // time since the last pose received: what a bone's speed is measured over
};

class PoseStream {
 public:
  PoseStream(std::vector<Eigen::Vector3d> bone_rest_centroids, PoseStreamSettings settings);

  // What to do with the pose at `time_s` (seconds, any epoch) with these bone transforms. A jump is judged against
  // the last pose received, solved or not, with both stamps: a stream that held still (poses skipped as unchanged)
  // and then jumps has jumped in one frame, not over the whole hold. No bone moved since the last pose solved: the
  // pose is unchanged. Const: call received() for every pose decided on, then accept() once it has been solved, or
  // reset() if its solve failed.
  StreamDecision decide(double time_s, const BoneTransforms& transforms) const;
  // The pose was taken in (solved or skipped): the next jump is measured from it.
  void received(double time_s, const BoneTransforms& transforms);
  // The pose was solved; its result is what the next warm start moves.
  void accept(double time_s, const BoneTransforms& transforms);
  // Forget the previous poses: the next one starts cold.
  void reset() { has_previous_ = has_received_ = false; }
  bool hasPrevious() const { return has_previous_; }
  const PoseStreamSettings& settings() const { return settings_; }

 private:
  std::vector<Eigen::Vector3d> centroids_;
  PoseStreamSettings settings_;
  bool has_previous_ = false;  // a pose was solved since the last reset
  double previous_time_s_ = 0;
  BoneTransforms previous_transforms_;
  bool has_received_ = false;
  double received_time_s_ = 0;
  BoneTransforms received_transforms_;
};

}  // namespace muscle_deformation
