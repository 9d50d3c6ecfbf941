#include "muscle_deformation/core/pipeline/single_pose_session.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace muscle_deformation {

std::string validate(const SinglePoseSettings& settings) {
  if (settings.max_iterations < 1) return "max_iterations must be >= 1";
  if (settings.lbfgs_history < 0) return "lbfgs_history must be >= 0";
  if (!(settings.residual_tolerance >= 0) || !std::isfinite(settings.residual_tolerance))
    return "residual_tolerance must be a finite number >= 0";
  if (!(settings.warm_max_translation_m >= 0) || !(settings.warm_max_rotation_rad >= 0))
    return "the warm-start distances must be >= 0";
  return {};
}

SinglePoseSession::SinglePoseSession(const SceneDescription& description, const Scene& scene,
                                     std::vector<std::string> default_selection, const PipelineSettings& pipeline,
                                     SinglePoseSettings settings, BoneFields bone_fields)
    : description_(description),
      scene_(scene),
      default_selection_(std::move(default_selection)),
      pipeline_settings_(pipeline),
      settings_(settings),
      bone_fields_(std::move(bone_fields)) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("single-pose settings: " + problem);
  pipeline_settings_.simulation.solver_kind = settings_.solver_kind;
  pipeline_settings_.simulation.local_global.lbfgs_history = settings_.lbfgs_history;
  bone_centres_ = boneRestCentroids(scene_.bones);
}

SinglePoseSession::~SinglePoseSession() = default;

DeformationPipeline& SinglePoseSession::pipelineFor(const SinglePoseRequest& request) {
  // Muscles: the request's selection, else the session's; always from the scene already in memory.
  const std::vector<std::string>& selection = request.muscles.empty() ? default_selection_ : request.muscles;
  std::vector<MuscleDescription> selected;
  try {
    selected = selectMuscles(description_, selection);
  } catch (const std::exception& e) {
    throw std::invalid_argument(std::string("muscles: ") + e.what());
  }
  std::vector<std::size_t> indices;
  for (const MuscleDescription& m : selected) {
    const auto loaded = std::find_if(scene_.muscle_descriptions.begin(), scene_.muscle_descriptions.end(),
                                     [&](const MuscleDescription& d) { return d.name == m.name; });
    if (loaded == scene_.muscle_descriptions.end())
      throw std::invalid_argument("muscles: '" + m.name + "' is in the scene but not loaded (the node's ~muscles "
                                  "selection); single poses simulate loaded muscles only");
    indices.push_back(static_cast<std::size_t>(loaded - scene_.muscle_descriptions.begin()));
  }
  if (indices.empty()) throw std::invalid_argument("muscles: the selection names no muscle");
  std::ostringstream key;
  for (std::size_t index : indices) key << index << ',';
  if (!pipeline_ || pipeline_key_ != key.str()) {
    pipeline_.reset();
    has_previous_ = false;
    std::vector<MuscleDescription> descriptions;
    std::vector<Muscle> muscles;
    for (std::size_t index : indices) {
      descriptions.push_back(scene_.muscle_descriptions[index]);
      muscles.push_back(scene_.muscles[index]);
    }
    // The stream's bone fields serve here too: building them is most of a pipeline's set-up.
    pipeline_ = std::make_unique<DeformationPipeline>(std::move(descriptions), std::move(muscles), scene_.bones,
                                                      pipeline_settings_, bone_fields_);
    pipeline_key_ = key.str();
  }
  return *pipeline_;
}

FrameStopping SinglePoseSession::stoppingFor(const SinglePoseRequest& request) const {
  FrameStopping stopping;
  StoppingSettings& sweeps = stopping.sweeps;
  // A displacement tolerance in the request makes the solve stop when it is met; the residual rule needs a solver that
  // measures the residual; otherwise the iteration count.
  if (request.displacement_tolerance_m > 0)
    sweeps.rule = StoppingRule::displacement;
  else if (settings_.rule == StoppingRule::force_residual && measuresForceResidual(settings_.solver_kind))
    sweeps.rule = StoppingRule::force_residual;
  else
    sweeps.rule = StoppingRule::iterations;
  sweeps.max_iterations = request.max_iterations > 0 ? request.max_iterations : settings_.max_iterations;
  if (request.displacement_tolerance_m > 0) sweeps.displacement_tolerance_m = request.displacement_tolerance_m;
  sweeps.residual_tolerance = settings_.residual_tolerance;
  sweeps.limits = settings_.limits;
  if (request.time_budget_ms > 0)
    sweeps.limits.wall_time_limit_ms = settings_.limits.wall_time_limit_ms > 0
                                           ? std::min(request.time_budget_ms, settings_.limits.wall_time_limit_ms)
                                           : request.time_budget_ms;
  return stopping;
}

std::string SinglePoseSession::coldReason(const SinglePoseRequest& request, const BoneTransforms& transforms) const {
  if (!has_previous_) return "there is no previous answer on these muscles";
  if (previous_caller_ != request.caller)
    return "the previous call came from another client (" + previous_caller_ + ")";
  const BoneMotion motion = largestBoneMotion(previous_transforms_, transforms, bone_centres_);
  if (motion.translation_m <= settings_.warm_max_translation_m && motion.rotation_rad <= settings_.warm_max_rotation_rad)
    return {};
  std::ostringstream why;
  why << "a bone moved " << motion.translation_m << " m and turned " << motion.rotation_rad
      << " rad since the previous call (service_warm_max_translation_m " << settings_.warm_max_translation_m
      << ", service_warm_max_rotation_rad " << settings_.warm_max_rotation_rad << ")";
  return why.str();
}

SinglePoseReply SinglePoseSession::solve(const SinglePoseRequest& request) {
  if (request.max_iterations < 0)
    throw std::invalid_argument("max_iterations is " + std::to_string(request.max_iterations) +
                                "; it must be >= 0 (0 = the default)");
  if (!(request.displacement_tolerance_m >= 0) || !std::isfinite(request.displacement_tolerance_m))
    throw std::invalid_argument("displacement_tolerance_m is " + std::to_string(request.displacement_tolerance_m) +
                                "; it must be a finite number >= 0 (0 = the default)");
  if (!(request.time_budget_ms >= 0) || !std::isfinite(request.time_budget_ms))
    throw std::invalid_argument("time_budget_ms is " + std::to_string(request.time_budget_ms) +
                                "; it must be a finite number >= 0 (0 = the default)");
  DeformationPipeline& pipeline = pipelineFor(request);
  const FrameStopping stopping = stoppingFor(request);
  const BoneTransforms transforms = boneTransformsOf(pipeline.bones(), poseFromLinkPoses(scene_, request.link_poses));
  // Warm starts: only from this caller's own previous answer, on the same muscles, and only if no bone moved further
  // than warm_max_*; otherwise cold, and the message says why.
  const std::string cold_reason = request.warm_start ? coldReason(request, transforms) : std::string();
  const bool warm = request.warm_start && cold_reason.empty();
  if (!warm) pipeline.reset();
  const FrameResult& frame =
      pipeline.solve(transforms, warm ? StartMode::warm : StartMode::cold, stopping, request.wants.surfaces,
                     request.wants.metrics && pipeline.metrics() != nullptr);
  const SolveStats& solve = frame.stats.solver;
  has_previous_ = frame.stats.finite && !solve.diverged && !solve.cancelled;
  previous_caller_ = request.caller;
  previous_transforms_ = transforms;

  SinglePoseReply reply;
  reply.frame = &frame;
  reply.success = has_previous_;
  std::ostringstream message;
  const StoppingSettings& sweeps = stopping.sweeps;
  if (!frame.stats.finite) {
    message << "the solve gave non-finite particle positions";
  } else if (solve.diverged) {
    message << "the solve diverged at every time step down to " << solve.time_step_s
            << " s; the particles are its starting state";
  } else if (solve.cancelled) {
    message << "the node is shutting down; the solve was stopped after " << solve.iterations << " iterations";
  } else {
    message << "solved " << frame.particles().muscleCount() << " muscles, " << frame.particles().particleCount()
            << " particles in " << solve.iterations << " iterations, " << solve.total_ms << " ms ("
            << (frame.stats.warm_started ? "warm start from this client's previous call" : "cold start");
    if (!cold_reason.empty()) message << "; warm start refused: " << cold_reason;
    message << ")";
    if (solve.residual >= 0) {
      // Block descent and Newton-Krylov: converged is their residual criterion, whatever stopped the solve.
      message << (solve.converged ? "; converged: force residual " : "; not converged: force residual ")
              << solve.residual << (solve.converged ? " below " : " above ") << sweeps.residual_tolerance
              << " of the springs' material constant";
    } else if (solve.converged && solve.no_descent_left) {
      message << "; converged (no step lowers the energy any more: a minimum within the contacts)";
    } else if (solve.converged) {
      message << "; converged (mean step below " << sweeps.displacement_tolerance_m << " m)";
    } else {
      message << "; not converged";
    }
    if (sweeps.rule == StoppingRule::displacement && solve.stopping_rule_met)
      message << "; the mean step fell below " << sweeps.displacement_tolerance_m << " m";
    if (solve.time_limit_reached)
      message << "; stopped at the time limit of " << sweeps.limits.wall_time_limit_ms << " ms ("
              << (request.time_budget_ms > 0 && sweeps.limits.wall_time_limit_ms == request.time_budget_ms
                      ? "the request's time_budget_ms"
                      : "the node's max_solve_time_s")
              << ")";
    else if (!solve.converged && sweeps.rule != StoppingRule::iterations && !solve.stopping_rule_met)
      message << " after the iteration cap of " << sweeps.max_iterations;
    if (solve.divergence_recoveries > 0)
      message << "; after " << solve.divergence_recoveries << " divergence recoveries (time step halved to "
              << solve.time_step_s << " s)";
    if (!frame.has_surfaces) message << "; no surfaces: " << pipeline.skinningProblem();
  }
  for (const std::string& warning : request.warnings) message << "; warning: " << warning;
  reply.message = message.str();
  return reply;
}

}  // namespace muscle_deformation
