// What the benchmarks that drive the core's DeformationPipeline and StreamSession share. A benchmark that plays poses
// as the node's /joint_states stream does offers them to a StreamSession (the core's stream protocol: warm, cold at a
// discontinuity, not solved again when no bone moved, reset after a failed frame), stamped at the bundled gait's rate.
#pragma once

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"

#include <cstddef>
#include <stdexcept>
#include <string>

namespace bench {

constexpr double kGaitRateHz = 60.0;  // the bundled gait's recording rate

// The stamp of the `played`-th pose of a stream played at the gait's rate (counting on across loops of the gait).
inline double streamStamp(std::size_t played) { return static_cast<double>(played) / kGaitRateHz; }

// The frame of a step that solved or refined a pose; nullptr for a pose the stream did not solve again (no bone
// moved). A failed solve (an exception of the core, which the session turns into a `failed` step) ends the benchmark
// as the exception itself did before the session caught it.
inline const muscle_deformation::FrameResult* frameOf(const muscle_deformation::StreamStep& step) {
  if (step.outcome == muscle_deformation::StreamOutcome::failed)
    throw std::runtime_error("a stream frame failed: " + step.reason);
  return step.frame;
}

// The same for a step that must have solved (a pose the benchmark knows moved).
inline const muscle_deformation::FrameResult& solvedFrame(const muscle_deformation::StreamStep& step) {
  const muscle_deformation::FrameResult* frame = frameOf(step);
  if (!frame) throw std::logic_error("the stream did not solve a pose it was offered: " + step.reason);
  return *frame;
}

// Pipeline settings that build the particles and their collision stage only (no surface skinning or metrics), as a
// benchmark that measures the particles needs.
inline muscle_deformation::PipelineSettings particlesOnly(muscle_deformation::PipelineSettings settings) {
  settings.skin_surfaces = false;
  settings.measure_fidelity = false;
  return settings;
}

inline muscle_deformation::PipelineSettings particlesOnly(const muscle_deformation::SimulationSettings& simulation,
                                                          int threads = 0) {
  muscle_deformation::PipelineSettings settings;
  settings.simulation = simulation;
  settings.threads = threads;
  return particlesOnly(settings);
}

}  // namespace bench
