// Starts the frames of a recorded gait the way the node's stream starts poses (PoseStream): warm from the previous
// solved frame unless time went back or a bone moved faster than the node's limits, then cold. The benchmarks that
// stream the gait decide through it, so that they measure what the node would do. Unlike the node they solve an
// unchanged pose too (they time solves), warm.
#pragma once

#include "muscle_deformation/core/model/model.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/pose_stream.hpp"
#include "muscle_deformation/core/pipeline/simulation.hpp"

#include <cstddef>
#include <vector>

namespace bench {

class GaitStream {
 public:
  static constexpr double kGaitRateHz = 60.0;  // the bundled gait's recording rate
  static constexpr double kFrameIntervalS = 1.0 / kGaitRateHz;

  GaitStream(const std::vector<muscle_deformation::Bone>& bones, const muscle_deformation::PoseStreamSettings& settings)
      : stream_(muscle_deformation::boneRestCentroids(bones), settings) {}

  // How the `frame`-th pose played (counting on across loops of the gait) starts.
  muscle_deformation::StartMode start(std::size_t frame, const muscle_deformation::BoneTransforms& transforms) const {
    using muscle_deformation::StartMode;
    const bool cold = stream_.decide(timeOf(frame), transforms).start == muscle_deformation::StreamStart::cold;
    return cold ? StartMode::cold : StartMode::warm;
  }
  // The `frame`-th pose was solved (or its solved state was put in place): the next warm start moves it.
  void solved(std::size_t frame, const muscle_deformation::BoneTransforms& transforms) {
    stream_.accept(timeOf(frame), transforms);
  }

 private:
  static double timeOf(std::size_t frame) { return static_cast<double>(frame) / kGaitRateHz; }
  muscle_deformation::PoseStream stream_;
};

}  // namespace bench
