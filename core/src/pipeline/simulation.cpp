#include "muscle_deformation/core/pipeline/simulation.hpp"

#include <algorithm>
#include <stdexcept>
#include <vector>

namespace muscle_deformation {

namespace {

// Adds one sweep solved past the frame's budget to the frame's statistics: its cost and the state it ended in.
void addDeepContactSweep(const SolveStats& sweep, SolveStats& frame) {
  frame.iterations += sweep.iterations;
  frame.mss_ms += sweep.mss_ms;
  frame.collision_ms += sweep.collision_ms;
  frame.total_ms += sweep.total_ms;
  frame.mean_displacement_m = sweep.mean_displacement_m;
  frame.peak_mean_displacement_m = std::max(frame.peak_mean_displacement_m, sweep.peak_mean_displacement_m);
  frame.spring_deviation_ratio = sweep.spring_deviation_ratio;
  frame.mean_strain = sweep.mean_strain;
  frame.max_strain = sweep.max_strain;
  frame.strain_p99 = sweep.strain_p99;
  frame.residual = sweep.residual;
  frame.contacts = sweep.contacts;
  frame.divergence_recoveries += sweep.divergence_recoveries;
  frame.diverged = sweep.diverged;
  frame.cancelled = sweep.cancelled;
  frame.time_limit_reached = frame.time_limit_reached || sweep.time_limit_reached;
}

}  // namespace

void shareStoppingRule(SimulationSettings& simulation) {
  const StoppingSettings& shared = simulation.stopping;
  VerletSettings& verlet = simulation.verlet;
  LocalGlobalSettings& local_global = simulation.local_global;
  BlockDescentSettings& block_descent = simulation.block_descent;
  verlet.stopping_rule = local_global.stopping_rule = block_descent.stopping_rule = shared.rule;
  verlet.max_iterations = local_global.max_iterations = block_descent.max_iterations = shared.max_iterations;
  verlet.displacement_tolerance_m = local_global.displacement_tolerance_m = block_descent.displacement_tolerance_m =
      shared.displacement_tolerance_m;
  verlet.time_budget_ms = local_global.time_budget_ms = block_descent.time_budget_ms = shared.time_budget_ms;
  verlet.limits = local_global.limits = block_descent.limits = shared.limits;
}

MuscleSimulation::MuscleSimulation(std::vector<Muscle> muscles, std::vector<Bone> bones, SimulationSettings settings,
                                   const BoneFields& bone_fields)
    : muscles_(std::move(muscles)), bones_(std::move(bones)), settings_(settings) {
  for (std::size_t b = 0; b < bones_.size(); ++b) bones_[b].id = static_cast<int>(b);
  if (const std::string problem = validate(settings_.collision); !problem.empty())
    throw std::invalid_argument("collision settings: " + problem);
  if (settings_.collisions) {
    CollisionReadyModel model =
        buildCollisionReadyModel(muscles_, bones_, settings_.model, settings_.collision, &build_report_, bone_fields);
    system_ = std::move(model.system);
    rest_overlaps_ = model.rest_overlaps;
    std::vector<std::string> bone_names;
    for (const Bone& bone : bones_) bone_names.push_back(bone.name);
    if (settings_.collision.bone_proxy == BoneProxyKind::distance_field) {
      bone_fields_ = model.bone_fields;
      collision_ = std::make_unique<CollisionWorld>(system_, std::move(model.bone_fields), settings_.collision, bone_names);
    } else {
      collision_ = std::make_unique<CollisionWorld>(system_, std::move(model.bone_spheres), settings_.collision,
                                                    bone_names);
    }
  } else {
    system_ = buildMassSpringSystem(muscles_, bones_, settings_.model, &build_report_);
  }
  // The model is final here (radii shrunk for the rest pose), as the solvers need: they read the sphere radii (the
  // local/global contact weights, the adaptive step's boundary particles). The local/global solver factorises its
  // matrix here, once: it depends on the model and settings, not the pose.
  solver_ = makeSolver(
      SolverChoice{settings_.solver_kind, settings_.verlet, settings_.local_global, settings_.block_descent,
                   settings_.newton_krylov},
      system_);
  if (collision_ && solver_->solvesContacts())
    solver_->setContactQuery(
        [this](const ParticleState& state, double margin_m, ContactSet& contacts) {
          collision_->findContacts(state, contacts, margin_m);
        },
        collision_->everyParticleCollides());
  state_ = restState(system_);
  median_collision_radius_m_ = system_.medianCollisionRadius();
}

void MuscleSimulation::reset() { has_previous_ = false; }

void MuscleSimulation::continueFrom(const BoneTransforms& transforms, const Eigen::Matrix3Xd& position) {
  if (transforms.size() != bones_.size() || position.cols() != system_.particleCount())
    throw std::invalid_argument("continueFrom: " + std::to_string(transforms.size()) + " transforms and " +
                                std::to_string(position.cols()) + " positions for " + std::to_string(bones_.size()) +
                                " bones and " + std::to_string(system_.particleCount()) + " particles");
  if (!position.allFinite()) throw std::invalid_argument("continueFrom: non-finite position");
  state_.position = position;
  state_.previous_position = position;
  correction_.setZero(3, position.cols());
  previous_correction_.resize(3, 0);
  previous_transforms_ = transforms;
  has_previous_ = true;
}

void MuscleSimulation::setStopping(StoppingRule rule, int max_iterations, double displacement_tolerance_m,
                                   double time_budget_ms, const SolveLimits& limits) {
  solver_->setStopping(rule, max_iterations, displacement_tolerance_m, time_budget_ms, limits);
  settings_.stopping = StoppingSettings{rule, max_iterations, displacement_tolerance_m, time_budget_ms, limits};
  shareStoppingRule(settings_);
}

StoppingSettings MuscleSimulation::runningStopping() const {
  const auto of = [](const auto& solver) {
    return StoppingSettings{solver.stopping_rule, solver.max_iterations, solver.displacement_tolerance_m,
                            solver.time_budget_ms, solver.limits};
  };
  switch (settings_.solver_kind) {
    case SolverKind::verlet:
      return of(settings_.verlet);
    case SolverKind::local_global:
      return of(settings_.local_global);
    case SolverKind::block_descent:
    case SolverKind::newton_krylov:  // stops by the block-descent settings, whose energy it minimises
      return of(settings_.block_descent);
  }
  return of(settings_.verlet);
}

bool MuscleSimulation::tissueDrag() const {
  return (settings_.solver_kind == SolverKind::block_descent || settings_.solver_kind == SolverKind::newton_krylov) &&
         settings_.block_descent.tissue_relaxation_s > 0;
}

FrameStats MuscleSimulation::solve(const Pose& pose, StartMode start, double frame_interval_s) {
  return solve(boneTransformsOf(bones_, pose), start, frame_interval_s);
}

FrameStats MuscleSimulation::solve(const BoneTransforms& transforms, StartMode start, double frame_interval_s) {
  if (transforms.size() != bones_.size())
    throw std::invalid_argument("pose has " + std::to_string(transforms.size()) + " bone transforms for " +
                                std::to_string(bones_.size()) + " bones");
  for (const Eigen::Isometry3d& transform : transforms)
    if (!transform.matrix().allFinite()) throw std::invalid_argument("pose has a non-finite bone transform");
  FrameStats stats;
  stats.has_collision = collision_ != nullptr;
  stats.warm_started = start == StartMode::warm && has_previous_;
  const bool drag = tissueDrag();
  const bool predict = drag && settings_.block_descent.predict_start && stats.warm_started &&
                       correction_.cols() == system_.particleCount();
  ParticleState predicted;
  if (predict) {
    // The previous answer plus its correction, moved with the bones like the answer itself.
    predicted.position = state_.position + correction_;
    const double extrapolation = settings_.block_descent.predict_extrapolation;
    if (extrapolation > 0 && previous_correction_.cols() == correction_.cols())
      predicted.position += extrapolation * (correction_ - previous_correction_);
    warmStart(system_, previous_transforms_, transforms, predicted);
  }
  if (stats.warm_started)
    warmStart(system_, previous_transforms_, transforms, state_);
  else
    rigidPretransform(system_, transforms, state_);
  if (drag) {
    state_.carried_position = state_.position;
    if (predict)
      for (Eigen::Index i = 0; i < system_.particleCount(); ++i)
        if (!system_.is_fixed[static_cast<std::size_t>(i)]) state_.position.col(i) = predicted.position.col(i);
    state_.previous_position = state_.position;
  } else {
    state_.carried_position.resize(3, 0);
  }
  solver_->setFrameInterval(stats.warm_started ? frame_interval_s : kNominalFrameIntervalS);

  // A time budget is the real-time contract of a continuing stream. A cold start (the first frame, a discontinuity)
  // continues nothing: from the rigid pre-transform one budget's sweep leaves particles up to 2 mm inside bone (gait
  // bag rostest), so it runs a fixed number of iterations instead, once. 10: block descent cold on all 26 bundled
  // muscles then ends 0.08 mm deep at most in 118 ms (real-time bench), and a frame that long still fits between the
  // poses of a stream played slower than real time.
  constexpr int kColdStartIterations = 10;
  const StoppingSettings stop = runningStopping();
  const bool cold_under_budget = !stats.warm_started && stop.rule == StoppingRule::time_budget;
  if (cold_under_budget)
    solver_->setStopping(StoppingRule::iterations, std::min(stop.max_iterations, kColdStartIterations),
                         stop.displacement_tolerance_m, stop.time_budget_ms, stop.limits);
  if (collision_ && solver_->solvesContacts()) {
    collision_->setBoneTransforms(transforms);
    collision_->resetTiming();
    stats.solver = solver_->solve(state_);
    stats.collision = collision_->measure(state_);
    // A warm frame under a time budget whose sweeps left a particle's centre in a bone (a jump, not a smooth stream)
    // gets up to deep_contact_sweeps more, one at a time, each from where the last ended, towards the same answer.
    const bool deep_contact_guard = stats.warm_started && stop.rule == StoppingRule::time_budget &&
                                    settings_.solver_kind == SolverKind::block_descent;
    for (int extra = 0; deep_contact_guard && extra < settings_.block_descent.deep_contact_sweeps &&
                        median_collision_radius_m_ > 0 &&
                        stats.collision.max_penetration_muscle_bone_m > median_collision_radius_m_ &&
                        !stats.solver.diverged && !stats.solver.cancelled && !stats.solver.time_limit_reached;
         ++extra) {
      solver_->setStopping(StoppingRule::iterations, 1, stop.displacement_tolerance_m, stop.time_budget_ms,
                           stop.limits);
      const SolveStats more = solver_->solve(state_);
      solver_->setStopping(stop.rule, stop.max_iterations, stop.displacement_tolerance_m, stop.time_budget_ms,
                           stop.limits);
      addDeepContactSweep(more, stats.solver);
      stats.collision = collision_->measure(state_);
    }
  } else if (collision_) {
    collision_->setBoneTransforms(transforms);
    collision_->resetTiming();
    const AfterUpdateHook resolve = [this](ParticleState& state) { return collision_->resolve(state); };
    stats.solver = solver_->solve(state_, resolve);
    stats.collision = collision_->measure(state_);
  } else {
    stats.solver = solver_->solve(state_);
  }
  if (cold_under_budget)
    solver_->setStopping(stop.rule, stop.max_iterations, stop.displacement_tolerance_m, stop.time_budget_ms,
                         stop.limits);
  // The solvers put a diverged state back as it was on entry, which is finite whenever the previous result was. Should
  // anything still leave a non-finite position, fall back to the rigid pre-transform of the rest shape: finite by
  // construction, and a pose-consistent answer rather than none.
  stats.finite = state_.position.allFinite();
  if (!stats.finite) {
    rigidPretransform(system_, transforms, state_);
    stats.solver.diverged = true;
    stats.fell_back_to_pretransform = true;
    if (collision_) stats.collision = collision_->measure(state_);
    stats.finite = state_.position.allFinite();
  }
  previous_transforms_ = transforms;
  has_previous_ = stats.finite && !stats.solver.diverged;  // never warm-start from a broken state
  if (drag && stats.warm_started && has_previous_) {
    previous_correction_ = std::move(correction_);
    correction_ = state_.position - state_.carried_position;  // zero for fixed particles: both follow their bone
  } else {
    previous_correction_.resize(3, 0);  // nothing to extrapolate from after a cold start
    correction_.setZero(3, system_.particleCount());
  }
  return stats;
}

}  // namespace muscle_deformation
