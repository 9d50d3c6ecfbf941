#include "muscle_deformation/core/pipeline/stream_session.hpp"

#include "pose_stream.hpp"

#include <exception>
#include <stdexcept>

namespace muscle_deformation {

std::string validate(const StreamSessionSettings& settings) {
  if (const std::string problem = validate(settings.poses); !problem.empty()) return problem;
  return validate(settings.stopping);
}

StreamSession::StreamSession(std::vector<MuscleDescription> descriptions, std::vector<Muscle> muscles,
                             std::vector<Bone> bones, const PipelineSettings& pipeline,
                             const StreamSessionSettings& settings, const BoneFields& bone_fields)
    : settings_(settings) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("stream settings: " + problem);
  pipeline_ = std::make_unique<DeformationPipeline>(std::move(descriptions), std::move(muscles), std::move(bones),
                                                    pipeline, bone_fields);
  poses_ = std::make_unique<PoseStream>(boneRestCentroids(pipeline_->bones()), settings_.poses);
}

StreamSession::~StreamSession() = default;

void StreamSession::restart() {
  poses_->reset();
  pipeline_->reset();
  last_frame_unfinished_ = false;
}

void StreamSession::continueFrom(double stamp_s, const BoneTransforms& transforms, const Eigen::Matrix3Xd& position) {
  pipeline_->continueFrom(transforms, position);
  last_stamp_s_ = stamp_s;
  poses_->reset();
  poses_->accept(stamp_s, transforms);
  last_frame_unfinished_ = false;
}

StreamStep StreamSession::offer(double stamp_s, const BoneTransforms& transforms, const FrameWants& wants) {
  if (transforms.size() != pipeline_->bones().size())
    throw std::invalid_argument("pose has " + std::to_string(transforms.size()) + " bone transforms for " +
                                std::to_string(pipeline_->bones().size()) + " bones");
  ++counters_.offered;
  const StreamDecision decision = poses_->decide(stamp_s, transforms);
  StreamStep step;
  step.reason = decision.reason;
  step.elapsed_s = decision.elapsed_s;
  step.stamp_s = stamp_s;
  if (decision.start == StreamStart::unchanged) {
    poses_->received(stamp_s, transforms);
    if (wantsRefinement()) return refine(wants);
    ++counters_.unchanged;
    step.outcome = StreamOutcome::unchanged;
    return step;
  }
  step.cold = decision.start == StreamStart::cold;
  // A cold start of a stream that solved before: a discontinuity, or the recovery from a failed or diverged frame.
  step.restarted = step.cold && (poses_->hasPrevious() || recovering_) && settings_.poses.warm_start;
  if (step.cold) pipeline_->reset();
  return solveFrame(stamp_s, transforms, step.cold ? StartMode::cold : StartMode::warm, decision.elapsed_s, wants,
                    step);
}

StreamStep StreamSession::solveFrame(double stamp_s, const BoneTransforms& transforms, StartMode start,
                                     double elapsed_s, const FrameWants& wants, StreamStep step) {
  try {
    // The tissue drag relaxes over the time the stamps say passed since the previous solved pose (poses dropped while
    // the caller was busy included).
    FrameStopping stopping = settings_.stopping;
    if (wants.late) stopping.catch_up_sweeps = 0;
    const FrameResult& frame = pipeline_->solve(transforms, start, stopping, wants.surfaces, wants.metrics, elapsed_s);
    step.outcome = StreamOutcome::solved;
    step.frame = &frame;
    ++counters_.solved;
    if (step.restarted) ++counters_.resets;
    count(frame);
    best_residual_ = frame.stats.solver.residual;  // a new frame: its refinement starts over
    stalled_refinements_ = 0;
    last_stamp_s_ = stamp_s;
    if (frame.stats.finite && !frame.stats.solver.diverged) {
      poses_->accept(stamp_s, transforms);
      recovering_ = false;
    } else {
      poses_->reset();  // never warm-start from a broken state
      recovering_ = true;
    }
  } catch (const std::exception& e) {
    failed(step, e);
  }
  return step;
}

void StreamSession::count(const FrameResult& frame) {
  if (!frame.stats.finite) ++counters_.non_finite;
  counters_.divergence_recoveries += static_cast<std::uint32_t>(frame.stats.solver.divergence_recoveries);
  if (frame.stats.solver.diverged) ++counters_.diverged;
  // A frame is unfinished when its solver measures a residual and the residual is above the tolerance; a solver
  // without one (Verlet, local/global) leaves nothing to judge it by.
  last_frame_unfinished_ = settings_.refine_unfinished_frames && frame.stats.finite && !frame.stats.solver.diverged &&
                           frame.stats.solver.residual >= 0 && !frame.stats.solver.converged;
}

void StreamSession::failed(StreamStep& step, const std::exception& error) {
  // A solve that threw leaves nothing to continue from: the next pose starts cold, counted as a recovery.
  ++counters_.failed;
  restart();
  recovering_ = true;
  step.outcome = StreamOutcome::failed;
  step.frame = nullptr;
  step.reason = error.what();
}

bool StreamSession::wantsRefinement() const { return last_frame_unfinished_ && poses_->hasPrevious(); }

StreamStep StreamSession::refine(const FrameWants& wants) {
  StreamStep step;
  step.stamp_s = last_stamp_s_;
  if (!wantsRefinement()) {
    step.outcome = StreamOutcome::unchanged;
    step.reason = "no bone moved";
    return step;
  }
  step.reason = "no bone moved; the last frame had not met its residual criterion";
  try {
    const FrameResult& frame = pipeline_->refine(settings_.stopping, wants.surfaces, wants.metrics);
    step.outcome = StreamOutcome::refined;
    step.frame = &frame;
    ++counters_.refined;
    count(frame);
    // A frame whose residual has stopped falling (contacts and the tissue drag can hold it just above the tolerance)
    // is left as it is: refining it on would keep a core busy for good while the skeleton holds still. Falling slowly
    // is not stopping: the gain is counted against the lowest residual of the frame so far.
    if (frame.stats.solver.residual < (1.0 - kMinRefinementGain) * best_residual_) {
      best_residual_ = frame.stats.solver.residual;
      stalled_refinements_ = 0;
    } else if (++stalled_refinements_ >= kStalledRefinementsToStop) {
      last_frame_unfinished_ = false;
    }
    if (!frame.stats.finite || frame.stats.solver.diverged) {
      poses_->reset();
      recovering_ = true;
    }
  } catch (const std::exception& e) {
    failed(step, e);
  }
  return step;
}

}  // namespace muscle_deformation
