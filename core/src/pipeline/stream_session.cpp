#include "muscle_deformation/core/pipeline/stream_session.hpp"

#include "pose_stream.hpp"

#include "muscle_deformation/core/base/median.hpp"
#include "muscle_deformation/core/base/stopwatch.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <stdexcept>

namespace muscle_deformation {

namespace {

// Median wall time (ms) of warm one-sweep solves without surfaces or metrics: every bone moved 1 mm and back, so that
// each solve carries the particles, searches the contacts and sweeps as a frame of a stream does. The pipeline is
// reset afterwards: the stream's first pose starts cold.
double oneSweepSolveMs(DeformationPipeline& pipeline, const FrameStopping& stream_stopping) {
  FrameStopping one = FrameStopping::of(StoppingSettings::afterIterations(1));
  one.sweeps.limits = stream_stopping.sweeps.limits;  // the caller's thread cap, time limit and cancellation
  const BoneTransforms rest(pipeline.bones().size(), Eigen::Isometry3d::Identity());
  BoneTransforms moved = rest;
  for (Eigen::Isometry3d& transform : moved) transform.translate(Eigen::Vector3d(1e-3, 0, 0));
  pipeline.solve(rest, StartMode::cold, one, false, false);
  std::vector<double> times;
  for (int k = 0; k < ResolutionFit::kTimedSolves; ++k) {
    const auto start = std::chrono::steady_clock::now();
    pipeline.solve(k % 2 == 0 ? moved : rest, StartMode::warm, one, false, false);
    times.push_back(millisecondsSince(start));
  }
  pipeline.reset();
  return upperMedian(std::move(times));
}

}  // namespace

std::string validate(const StreamSessionSettings& settings) {
  if (const std::string problem = validate(settings.poses); !problem.empty()) return problem;
  if (settings.auto_resolution && settings.stopping.sweeps.rule != StoppingRule::time_budget)
    return "auto_resolution fits the model to the frame's time budget: it needs stopping_rule time_budget";
  return validate(settings.stopping);
}

std::string ResolutionFit::describe() const {
  if (models.empty()) return "auto_resolution: no model was built";
  const auto solve = [](const Model& model) {
    char text[128];
    std::snprintf(text, sizeof text, "at %d particles per fibre (%ld particles) %.1f ms", model.particles_per_fibre,
                  model.particles, model.solve_ms);
    return std::string(text);
  };
  char budget[64];
  std::snprintf(budget, sizeof budget, "%.1f ms", budget_ms);
  std::string text = "auto_resolution: a one-sweep solve of the stream's model (median of " +
                     std::to_string(kTimedSolves) + ") " + solve(models.front());
  if (!changed())
    return text + (fits() ? ", within the " + std::string(budget) + " budget: the stream keeps it"
                          : ", over the " + std::string(budget) + " budget, and no coarser model is built below " +
                                std::to_string(kCoarsestParticlesPerFibre) + " particles per fibre");
  text += ", over the " + std::string(budget) + " budget";
  for (std::size_t k = 1; k < models.size(); ++k) text += "; " + solve(models[k]);
  text += ". The stream uses " + std::to_string(models.back().particles_per_fibre) + " particles per fibre";
  if (!fits())
    text += ", still over the budget at the coarsest model it builds (" + std::to_string(kCoarsestParticlesPerFibre) +
            "): fewer muscles in the scene would be lighter still";
  return text + "; single poses (~deform_pose) keep " + std::to_string(models.front().particles_per_fibre) +
         ". docs/BENCHMARKS.md, \"Speed against error\", gives the error each resolution costs.";
}

StreamSession::StreamSession(std::vector<MuscleDescription> descriptions, std::vector<Muscle> muscles,
                             std::vector<Bone> bones, const PipelineSettings& pipeline,
                             const StreamSessionSettings& settings, const BoneFields& bone_fields)
    : settings_(settings) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("stream settings: " + problem);
  if (settings_.auto_resolution)
    buildFittedPipeline(descriptions, muscles, bones, pipeline, bone_fields);
  else
    pipeline_ = std::make_unique<DeformationPipeline>(std::move(descriptions), std::move(muscles), std::move(bones),
                                                      pipeline, bone_fields);
  poses_ = std::make_unique<PoseStream>(boneRestCentroids(pipeline_->bones()), settings_.poses);
}

void StreamSession::buildFittedPipeline(const std::vector<MuscleDescription>& descriptions,
                                        const std::vector<Muscle>& muscles, const std::vector<Bone>& bones,
                                        const PipelineSettings& pipeline, const BoneFields& bone_fields) {
  ResolutionFit fit;
  fit.budget_ms = settings_.stopping.sweeps.time_budget_ms;
  const int configured = pipeline.simulation.model.particles_per_fibre;
  BoneFields fields = bone_fields;
  for (int particles_per_fibre = configured;;) {
    PipelineSettings coarser = pipeline;
    coarser.simulation.model.particles_per_fibre = particles_per_fibre;
    const double scale = static_cast<double>(particles_per_fibre) / configured;
    std::vector<Muscle> scaled = muscles;
    for (Muscle& muscle : scaled)
      if (muscle.particles_per_fibre > 0)
        muscle.particles_per_fibre = std::max(2, static_cast<int>(std::lround(muscle.particles_per_fibre * scale)));
    pipeline_.reset();  // the previous model's memory before the next is built
    pipeline_ = std::make_unique<DeformationPipeline>(descriptions, std::move(scaled), bones, coarser, fields);
    fields = pipeline_->boneFields();  // built once, shared by every model after
    const double solve_ms = oneSweepSolveMs(*pipeline_, settings_.stopping);
    fit.models.push_back({particles_per_fibre, static_cast<long>(pipeline_->system().particleCount()), solve_ms});
    if (solve_ms <= fit.budget_ms || particles_per_fibre <= ResolutionFit::kCoarsestParticlesPerFibre ||
        static_cast<int>(fit.models.size()) >= ResolutionFit::kMostModels)
      break;
    // A solve's time grows about as its particles do: aim a tenth under the budget, one step coarser at least.
    const int aimed = static_cast<int>(std::floor(0.9 * particles_per_fibre * fit.budget_ms / solve_ms));
    particles_per_fibre = std::clamp(aimed, ResolutionFit::kCoarsestParticlesPerFibre, particles_per_fibre - 1);
  }
  resolution_fit_ = std::move(fit);
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
