#include "muscle_simulation.hpp"

#include "muscle_deformation/core/base/median.hpp"
#include "muscle_deformation/core/base/stopwatch.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <stdexcept>
#include <vector>

namespace muscle_deformation {

namespace {

// Adds a further solve of the same frame (sweeps past its budget, or a later part of a cold start) to the frame's
// statistics: its cost and the state it ended in.
void addSweepToFrame(const SolveStats& sweep, SolveStats& frame) {
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
  frame.converged = sweep.converged;
  frame.contacts = sweep.contacts;
  frame.divergence_recoveries += sweep.divergence_recoveries;
  frame.fibre_steps += sweep.fibre_steps;
  frame.diverged = sweep.diverged;
  frame.cancelled = sweep.cancelled;
  frame.time_limit_reached = frame.time_limit_reached || sweep.time_limit_reached;
}

// Per particle, the part of the correction's latest change `change` that the change before it (`before`) confirms: its
// projection on `change`, kept within [0, 1] of it. A drift the motion drives keeps its direction from frame to
// frame and is carried on whole; an alternation of the sweeps' own (a mode a sweep overshoots, which flips sign every
// frame; the volume term, which couples all of a muscle's particles, makes them) is not carried on at all.
// Extrapolating such an alternation fed it back into the next start and made it grow while the skeleton held still
// (thigh13 with a recording's jitter, one sweep a frame: the residual from 3e-4 to about 1 within 200 frames).
Eigen::Matrix3Xd confirmedTrend(const Eigen::Matrix3Xd& change, const Eigen::Matrix3Xd& before) {
  Eigen::Matrix3Xd confirmed(3, change.cols());
  for (Eigen::Index i = 0; i < change.cols(); ++i) {
    const double squared = change.col(i).squaredNorm();
    const double share = squared > 0 ? std::clamp(change.col(i).dot(before.col(i)) / squared, 0.0, 1.0) : 0.0;
    confirmed.col(i) = share * change.col(i);
  }
  return confirmed;
}

}  // namespace

std::string validate(const StartPrediction& prediction) {
  if (!(prediction.predict_extrapolation >= 0 && prediction.predict_extrapolation <= kMaxPredictExtrapolation))
    return "predict_extrapolation must lie in [0, 0.75] (1, linear extrapolation, diverged on the bundled gait)";
  return {};
}

std::string validate(const FrameStopping& stopping) {
  if (const std::string problem = validate(stopping.sweeps); !problem.empty()) return problem;
  if (stopping.cold_start_iterations < 1) return "cold_start_iterations must be >= 1";
  if (stopping.deep_contact_sweeps < 0) return "deep_contact_sweeps must be >= 0";
  if (stopping.catch_up_sweeps < 0) return "catch_up_sweeps must be >= 0";
  if (!(stopping.catch_up_residual_ratio >= 1) || !std::isfinite(stopping.catch_up_residual_ratio))
    return "catch_up_residual_ratio must be a finite number >= 1";
  return {};
}

MuscleSimulation::MuscleSimulation(std::vector<Muscle> muscles, std::vector<Bone> bones, SimulationSettings settings,
                                   int threads, const BoneFields& bone_fields)
    : muscles_(std::move(muscles)), bones_(std::move(bones)), settings_(settings), threads_(threads) {
  for (std::size_t b = 0; b < bones_.size(); ++b) bones_[b].id = static_cast<int>(b);
  if (const std::string problem = validate(settings_.collision); !problem.empty())
    throw std::invalid_argument("collision settings: " + problem);
  if (const std::string problem = validate(settings_.prediction); !problem.empty())
    throw std::invalid_argument("start prediction: " + problem);
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
    collision_->setThreads(passThreads());
  } else {
    system_ = buildMassSpringSystem(muscles_, bones_, settings_.model, &build_report_);
  }
  // The model is final here (radii shrunk for the rest pose), as the solvers need: they read the sphere radii (the
  // local/global contact weights, the adaptive step's boundary particles). The local/global solver factorises its
  // matrix here, once: it depends on the model and settings, not the pose.
  solver_ = makeSolver(SolverChoice{settings_.solver_kind, settings_.verlet, settings_.local_global,
                                    settings_.block_descent, settings_.newton_krylov, threads},
                       system_);
  if (collision_ && solver_->solvesContacts())
    solver_->setContactQuery(
        [this](const ParticleState& state, double margin_m, ContactSet& contacts) {
          collision_->findContacts(state, contacts, margin_m);
        },
        collision_->everyParticleCollides());
  state_ = restState(system_);
  median_collision_radius_m_ = system_.medianCollisionRadius();
  if (solver_->balancesRestShape()) rest_balance_ = restBalanceForces(system_);
  if (settings_.drag_follows_tone && !system_.belly_tone.empty()) spring_stiffness_sum_ = springStiffnessSums(system_);
}

void MuscleSimulation::reset() {
  has_previous_ = false;
  cold_drag_share_.clear();
}

void MuscleSimulation::continueFrom(const BoneTransforms& transforms, const Eigen::Matrix3Xd& position) {
  if (transforms.size() != bones_.size() || position.cols() != system_.particleCount())
    throw std::invalid_argument("continueFrom: " + std::to_string(transforms.size()) + " transforms and " +
                                std::to_string(position.cols()) + " positions for " + std::to_string(bones_.size()) +
                                " bones and " + std::to_string(system_.particleCount()) + " particles");
  if (!position.allFinite()) throw std::invalid_argument("continueFrom: non-finite position");
  state_.position = position;
  state_.previous_position = position;
  cold_drag_share_.clear();  // whatever pressure it had, the frame continued is not a cold start's
  correction_.setZero(3, position.cols());
  correction_change_.resize(3, 0);
  previous_correction_change_.resize(3, 0);
  previous_transforms_ = transforms;
  has_previous_ = true;
  // The next frame's stretch with the tone (SimulationSettings::drag_follows_tone) starts from the tone at this pose,
  // not at whatever pose the simulation solved last (which put a frame continued from another stream 0.47 mm RMS off
  // the same frame solved in that stream, all 26 muscles, realtime bench).
  const bool tendons_changed = updateTendonRestLengths(system_, transforms);
  if (updateBellyTone(system_, transforms, passThreads()) || tendons_changed) solver_->restLengthsChanged();
}

void MuscleSimulation::keepVolume(const SurfaceSkinning& skinning) {
  const double scale = settings_.block_descent.volume_stiffness;
  if (!(scale > 0) || !solver_->keepsVolume()) return;
  volume_ = std::make_unique<SkinnedVolume>(skinning, system_);
  volume_->setThreads(parallelThreads(threads_, SolveLimits{}));
  // The springs' material constant (median k l0, as the solver's residual is measured in).
  std::vector<double> material;
  for (std::size_t s = 0; s < system_.springs.size(); ++s)
    material.push_back(system_.springs.stiffness[static_cast<Eigen::Index>(s)] *
                       system_.springs.rest_length[static_cast<Eigen::Index>(s)]);
  const double constant = material.empty() ? 1.0 : upperMedian(std::move(material));
  VolumeTerm term;
  term.rest_volume_m3 = volume_->restVolumes();
  for (int m = 0; m < volume_->muscleCount(); ++m) {
    const double rest = std::abs(volume_->restVolumes()[static_cast<std::size_t>(m)]);
    const double area = volume_->restAreas()[static_cast<std::size_t>(m)];
    const int followed = volume_->skinParticleCounts()[static_cast<std::size_t>(m)];
    term.stiffness.push_back(rest > 0 && area > 0 ? scale * constant * followed / (rest * area) : 0.0);
  }
  const SkinnedVolume* volume = volume_.get();
  const BoneTransforms* transforms = &frame_transforms_;
  term.evaluate = [volume, transforms](const Eigen::Matrix3Xd& position, std::vector<double>& volumes,
                                       Eigen::Matrix3Xd& gradients) {
    volume->evaluate(position, *transforms, volumes, gradients);
  };
  term.curvature_times = [volume, transforms](const Eigen::Matrix3Xd& position, const Eigen::Matrix3Xd& direction,
                                              const std::vector<double>& weight, Eigen::Matrix3Xd& out) {
    volume->curvatureTimes(position, *transforms, direction, weight, out);
  };
  solver_->setVolumeTerm(std::move(term));
  resetVolumePressure();
}

void MuscleSimulation::resetVolumePressure() {
  if (!volume_) return;
  volume_target_m3_ = volume_->restVolumes();
  solver_->setVolumeTargets(volume_target_m3_);
}

void MuscleSimulation::updateVolumePressure() {
  if (!pressureBuilds() || !state_.position.allFinite()) return;
  const double gain = settings_.block_descent.volume_pressure_gain;
  std::vector<double> volumes;
  volume_->volumes(state_.position, frame_transforms_, volumes);
  const std::vector<double>& rest = volume_->restVolumes();
  std::vector<double> shift(volumes.size());
  for (std::size_t m = 0; m < volumes.size(); ++m) shift[m] = -gain * (volumes[m] - rest[m]);
  moveVolumeTargets(shift);
}

void MuscleSimulation::moveVolumeTargets(const std::vector<double>& shift) {
  const std::vector<double>& rest = volume_->restVolumes();
  for (std::size_t m = 0; m < shift.size(); ++m) {
    // A muscle held from its volume by the bones (or a volume the skin cannot reach) would wind its pressure up
    // without end: the target stays within kMaxVolumeTargetShift of the rest volume.
    const double bound = kMaxVolumeTargetShift * std::abs(rest[m]);
    volume_target_m3_[m] = std::clamp(volume_target_m3_[m] + shift[m], rest[m] - bound, rest[m] + bound);
  }
  solver_->setVolumeTargets(volume_target_m3_);
}

StoppingSettings MuscleSimulation::mainSolveStopping(bool warm, const FrameStopping& stopping) const {
  if (warm || stopping.sweeps.rule != StoppingRule::time_budget) return stopping.sweeps;
  StoppingSettings cold = stopping.sweeps;
  cold.rule = StoppingRule::iterations;
  cold.max_iterations = std::min(stopping.sweeps.max_iterations, stopping.cold_start_iterations);
  return cold;
}

FrameStats MuscleSimulation::solve(const BoneTransforms& transforms, StartMode start, const FrameStopping& stopping,
                                   double frame_interval_s) {
  const auto solve_start = std::chrono::steady_clock::now();
  if (const std::string problem = validate(stopping); !problem.empty())
    throw std::invalid_argument("frame stopping: " + problem);
  if (transforms.size() != bones_.size())
    throw std::invalid_argument("pose has " + std::to_string(transforms.size()) + " bone transforms for " +
                                std::to_string(bones_.size()) + " bones");
  for (const Eigen::Isometry3d& transform : transforms)
    if (!transform.matrix().allFinite()) throw std::invalid_argument("pose has a non-finite bone transform");
  FrameStats stats;
  stats.has_collision = collision_ != nullptr;
  stats.warm_started = start == StartMode::warm && has_previous_;
  const bool drag = solver_->dragsTissue();
  // Tendons over bones beyond their anchor keep their whole length: their springs' rest lengths follow the pose.
  // The belly's tone: its rest length follows its attachments' span (ModelSettings::fibre_tone).
  const bool tendons_changed = updateTendonRestLengths(system_, transforms);
  // The tissue's stretch with the tone (SimulationSettings::drag_follows_tone), on a frame that continues the previous
  // one: from the tone and the fibres' lengths of the previous answer. A cold start's anchor stays the rest shape the
  // bones carry: stretched there at once by the tone's whole change from rest (up to 25 %), the cold extreme pose of the
  // stability bench ended 1.39 mm deep in bone instead of 0.39 mm.
  const bool drag_stretches =
      drag && settings_.drag_follows_tone && !system_.belly_tone.empty() && stats.warm_started;
  std::vector<double> previous_tone, previous_arcs;
  if (drag_stretches) {
    previous_tone = system_.belly_tone.factor;
    previous_arcs = fibreArcLengths(system_, state_.position);
  }
  if (updateBellyTone(system_, transforms, passThreads()) || tendons_changed) solver_->restLengthsChanged();
  const bool predict = drag && settings_.prediction.predict_start && stats.warm_started &&
                       correction_.cols() == system_.particleCount();
  ParticleState predicted;
  if (predict) {
    // The previous answer plus its correction, moved with the bones like the answer itself.
    predicted.position = state_.position + correction_;
    const double extrapolation = settings_.prediction.predict_extrapolation;
    if (extrapolation > 0 && correction_change_.cols() == correction_.cols() &&
        previous_correction_change_.cols() == correction_.cols())
      predicted.position += extrapolation * confirmedTrend(correction_change_, previous_correction_change_);
    warmStart(system_, previous_transforms_, transforms, predicted, passThreads());
  }
  if (stats.warm_started)
    warmStart(system_, previous_transforms_, transforms, state_, passThreads());
  else
    rigidPretransform(system_, transforms, state_, passThreads());
  if (drag_stretches) {
    stretchWithTone(system_, spring_stiffness_sum_, previous_tone, previous_arcs, state_.position);
    if (predict) stretchWithTone(system_, spring_stiffness_sum_, previous_tone, previous_arcs, predicted.position);
  }
  if (drag) {
    state_.carried_position = state_.position;
    if (predict)
      for (Eigen::Index i = 0; i < system_.particleCount(); ++i)
        if (!system_.is_fixed[static_cast<std::size_t>(i)]) state_.position.col(i) = predicted.position.col(i);
    state_.previous_position = state_.position;
  } else {
    state_.carried_position.resize(3, 0);
  }
  if (drag && solver_->tiesToRestShape()) {
    // The across-fibre tie's anchor: the rest shape as the bones carry it in this pose (a cold start's carried
    // positions are that already).
    if (stats.warm_started) {
      ParticleState rest_carried;
      rigidPretransform(system_, transforms, rest_carried, passThreads());
      state_.rest_carried_position = std::move(rest_carried.position);
    } else {
      state_.rest_carried_position = state_.carried_position;
    }
  } else {
    state_.rest_carried_position.resize(3, 0);
  }
  if (drag && solver_->balancesRestShape())
    state_.rest_balance_force = carryRestVectors(system_, transforms, rest_balance_, passThreads());
  else
    state_.rest_balance_force.resize(3, 0);
  solver_->setFrameInterval(stats.warm_started ? frame_interval_s : kNominalFrameIntervalS);

  // A time budget is the real-time contract of a continuing stream; a cold start continues nothing and runs a fixed
  // number of iterations instead (FrameStopping::cold_start_iterations).
  frame_transforms_ = transforms;
  stats.preparation_ms = millisecondsSince(solve_start);
  const StoppingSettings main = afterTimeSpent(mainSolveStopping(stats.warm_started, stopping), stats.preparation_ms);
  if (!stats.warm_started)
    resetVolumePressure();
  else
    takeColdDragOutOfPressure();
  if (!stats.warm_started && pressureBuilds() && main.rule == StoppingRule::iterations && main.max_iterations > 1) {
    // A cold start carries no pressure from a frame before: the muscles' pressures build within its own sweeps, one
    // update after every kColdPressureSweeps (the same update a warm frame gets once, after its solve). Each part is a
    // solve of its own, with its closing contact pass and statistics: one update per sweep made the service's cold pose
    // of the 13 thigh muscles 1.8x slower.
    // The parts share the solve's wall-time ceiling (a single pose may ask for unlimited sweeps within a time limit).
    const auto cold_start = std::chrono::steady_clock::now();
    StoppingSettings part = main;
    part.max_iterations = std::min(main.max_iterations, kColdPressureSweeps);
    runSolver(transforms, part, stopping, stats, false);
    for (int done = part.max_iterations; done < main.max_iterations && !stats.solver.diverged &&
                                         !stats.solver.cancelled && !stats.solver.time_limit_reached &&
                                         state_.position.allFinite();
         done += part.max_iterations) {
      if (main.limits.wall_time_limit_ms > 0) {
        const double left_ms = main.limits.wall_time_limit_ms - millisecondsSince(cold_start);
        if (left_ms <= 0) {
          stats.solver.time_limit_reached = true;
          stats.solver.stopping_rule_met = false;
          break;
        }
        part.limits.wall_time_limit_ms = left_ms;
      }
      updateVolumePressure();
      part.max_iterations = std::min(kColdPressureSweeps, main.max_iterations - done);
      FrameStats more;
      more.has_collision = stats.has_collision;
      runSolver(transforms, part, stopping, more, false);
      addSweepToFrame(more.solver, stats.solver);
      stats.solver.stopping_rule_met = more.solver.stopping_rule_met;
      stats.collision = more.collision;
    }
  } else {
    runSolver(transforms, main, stopping, stats, false);
  }
  // A cold start in a stream under a time budget gets the deep-contact sweeps a warm frame gets: its fixed sweeps can
  // leave a particle's centre in a bone at an extreme pose (thigh13 at hip 110 deg, knee 130 deg: 1.55 mm after 10).
  if (!stats.warm_started && stopping.sweeps.rule == StoppingRule::time_budget)
    sweepDeepContacts(main, stopping, stats);
  finishFrame(transforms, drag, false, stats);
  updateVolumePressure();
  measureColdDragShare(stats.warm_started);
  stats.solve_ms = millisecondsSince(solve_start);
  return stats;
}

void MuscleSimulation::measureColdDragShare(bool warm) {
  cold_drag_share_.clear();
  if (warm || !has_previous_ || !pressureBuilds()) return;
  cold_drag_share_ = solver_->dragShareOfVolumeTargets(state_);
}

void MuscleSimulation::takeColdDragOutOfPressure() {
  if (cold_drag_share_.size() == volume_target_m3_.size() && pressureBuilds()) moveVolumeTargets(cold_drag_share_);
  cold_drag_share_.clear();
}

FrameStats MuscleSimulation::refine(const FrameStopping& stopping) {
  if (const std::string problem = validate(stopping); !problem.empty())
    throw std::invalid_argument("frame stopping: " + problem);
  if (!has_previous_) throw std::logic_error("refine: there is no finished previous frame to continue");
  const auto solve_start = std::chrono::steady_clock::now();
  FrameStats stats;
  stats.has_collision = collision_ != nullptr;
  stats.warm_started = last_frame_warm_;
  // The same pose and the same anchor of the tissue drag (state_.carried_position as the frame set it): the answer
  // stays the frame's, and the sweeps continue from where they stopped.
  frame_transforms_ = previous_transforms_;
  runSolver(previous_transforms_, stopping.sweeps, stopping, stats, true);
  const BoneTransforms transforms = previous_transforms_;
  finishFrame(transforms, solver_->dragsTissue(), true, stats);
  updateVolumePressure();
  measureColdDragShare(stats.warm_started);
  stats.solve_ms = millisecondsSince(solve_start);
  return stats;
}

void MuscleSimulation::sweepPastBudget(const StoppingSettings& main, int cap, const std::function<bool()>& needed,
                                       FrameStats& stats, int& count) {
  StoppingSettings one_sweep = main;
  one_sweep.rule = StoppingRule::iterations;
  one_sweep.max_iterations = 1;
  for (int extra = 0; extra < cap && needed() && !stats.solver.diverged && !stats.solver.cancelled &&
                      !stats.solver.time_limit_reached;
       ++extra) {
    addSweepToFrame(solver_->solve(state_, one_sweep), stats.solver);
    ++count;
    stats.collision = collision_->measureListed(state_);
  }
}

void MuscleSimulation::sweepDeepContacts(const StoppingSettings& main, const FrameStopping& stopping,
                                         FrameStats& stats) {
  if (!collision_ || !solver_->solvesContacts() || median_collision_radius_m_ <= 0) return;
  sweepPastBudget(
      main, stopping.deep_contact_sweeps,
      [&] { return stats.collision.max_penetration_muscle_bone_m > median_collision_radius_m_; }, stats,
      stats.deep_contact_sweeps);
}

void MuscleSimulation::runSolver(const BoneTransforms& transforms, const StoppingSettings& main,
                                 const FrameStopping& stopping, FrameStats& stats, bool refinement) {
  if (collision_ && solver_->solvesContacts()) {
    collision_->setBoneTransforms(transforms);
    collision_->resetTiming();
    stats.solver = solver_->solve(state_, main);
    // Over the contacts the solver's last search listed, completed for the few particles that moved further since than
    // its margin: the same figures as measure() without a second search of every sphere pair (1.6 against 0.34 ms a
    // frame on the 26 bundled muscles).
    stats.collision = collision_->measureListed(state_);
    // A warm frame under a time budget whose sweeps left a particle's centre in a bone (a jump, not a smooth stream)
    // gets up to deep_contact_sweeps more (a cold start gets them after its last part, in solve()).
    const bool past_budget_allowed = stats.warm_started && main.rule == StoppingRule::time_budget;
    if (past_budget_allowed) sweepDeepContacts(main, stopping, stats);
    // A warm frame (not a refinement) whose residual after its budget lies far above the stream's typical one gets up
    // to catch_up_sweeps more; the typical residual is taken before them, from the budgeted sweeps alone.
    if (past_budget_allowed && !refinement && measuresResidual() && stats.solver.iterations > 0 &&
        std::isfinite(stats.solver.residual) && stats.solver.residual > 0) {
      const double budget_residual = stats.solver.residual;
      if (has_typical_residual_) {
        const double threshold = stopping.catch_up_residual_ratio * std::exp(typical_log_residual_);
        sweepPastBudget(
            main, stopping.catch_up_sweeps, [&] { return stats.solver.residual > threshold; }, stats,
            stats.catch_up_sweeps);
      }
      const double log_residual = std::log(budget_residual);
      typical_log_residual_ = has_typical_residual_ ? (1 - kTypicalResidualWeight) * typical_log_residual_ +
                                                          kTypicalResidualWeight * log_residual
                                                    : log_residual;
      has_typical_residual_ = true;
    }
  } else if (collision_) {
    collision_->setBoneTransforms(transforms);
    collision_->resetTiming();
    const AfterUpdateHook resolve = [this](ParticleState& state) { return collision_->resolve(state); };
    stats.solver = solver_->solve(state_, main, resolve);
    stats.collision = collision_->measure(state_);
  } else {
    stats.solver = solver_->solve(state_, main);
  }
}

void MuscleSimulation::finishFrame(const BoneTransforms& transforms, bool drag, bool refinement, FrameStats& stats) {
  // The solvers put a diverged state back as it was on entry, which is finite whenever the previous result was. Should
  // anything still leave a non-finite position, fall back to the rigid pre-transform of the rest shape: finite by
  // construction, and a pose-consistent answer rather than none.
  stats.finite = state_.position.allFinite();
  if (!stats.finite) {
    rigidPretransform(system_, transforms, state_, passThreads());
    stats.solver.diverged = true;
    stats.fell_back_to_pretransform = true;
    if (collision_) stats.collision = collision_->measure(state_);
    stats.finite = state_.position.allFinite();
  }
  previous_transforms_ = transforms;
  has_previous_ = stats.finite && !stats.solver.diverged;  // never warm-start from a broken state
  last_frame_warm_ = stats.warm_started && has_previous_;
  if (drag && last_frame_warm_) {
    // After a refinement the change of the correction is the refinement's, not a drift of the motion that the next
    // frame could extrapolate: the next frame carries the correction on without extrapolating.
    Eigen::Matrix3Xd correction = state_.position - state_.carried_position;  // zero for fixed particles
    if (refinement) {
      correction_change_.resize(3, 0);
      previous_correction_change_.resize(3, 0);
    } else {
      previous_correction_change_ = std::move(correction_change_);
      if (correction_.cols() == correction.cols())
        correction_change_ = correction - correction_;
      else
        correction_change_.resize(3, 0);
    }
    correction_ = std::move(correction);
  } else {
    correction_change_.resize(3, 0);  // nothing to extrapolate from after a cold start
    previous_correction_change_.resize(3, 0);
    correction_.setZero(3, system_.particleCount());
  }
}

}  // namespace muscle_deformation
