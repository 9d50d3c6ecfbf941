// Speed against error on the bundled scene (issue 7 part 2, issue 8's measurements): the 13 thigh13 muscles, 64
// fibres each, 20 particles per fibre, posed at five frames of the gait. For every configuration (spring layout, time
// step rule, broad phase, cold or warm start, Verlet or local/global solver) one solve per pose is snapshotted at
// growing iteration counts and each snapshot is compared with the same model's converged shape for that pose.
// Also: the converged surface at 20-80 particles per fibre against the converged 80-per-fibre surface.
// Writes out/bench/speed_vs_error.json.
#include "bench_util.hpp"
#include "convergence_run.hpp"
#include "progress.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/core/model/spring_layout.hpp"
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

using namespace muscle_deformation;

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// VerletSettings documents its automatic fixed step as this share of the stability bound; the bound itself is
// recovered from the step an automatic solver picks, so the fractions below are of the very bound the solver uses.
constexpr double kAutoStepFraction = 0.9;

// The converged shape of a pose: the quasi-static local/global solver in its quasi-Newton (L-BFGS) mode run until
// the mean free-particle displacement per iteration is below this (the rule), or the reference cap. The
// damped Verlet solver and the plain local/global iteration both creep along the soft shape changes (bending of the
// long muscles) for tens of thousands of iterations; on gait frame 0 L-BFGS met the rule in about 500 iterations with
// a history of 16 and about 1700 with 8. The default run compares Verlet and L-BFGS(8) with it on one pose.
constexpr double kReferenceToleranceM = 1e-7;
constexpr int kReferenceLbfgsHistory = 16;
constexpr int kCheckLbfgsHistory = 8;
// Iterations per frame of the streaming runs (the node's situation: warm from the previous frame's result).
constexpr int kStreamingVerletIterations[] = {1, 3, 10, 30, 100};
constexpr int kStreamingLbfgsIterations[] = {1, 3, 10, 30};
// Volume term weight of the local/global configurations that use one (relative to the springs' stiffness, see
// LocalGlobalSettings::volume_weight); the local/global bench measured 1 better than 10 on the synthetic thigh.
constexpr double kVolumeWeight = 1.0;

// How much work a run does; --quick shrinks every cap.
struct Budget {
  int particles_per_fibre = 20;
  int verlet_cap = 0;              // Verlet configurations
  int local_global_cap = 0;        // local/global without the volume term
  int local_global_volume_cap = 0; // with it (each iteration costs several times more)
  int lbfgs_cap = 0;               // local/global in its L-BFGS mode
  int reference_cap = 0;           // the converged shapes of the default layout (and the warm starts' frames)
  int other_reference_cap = 0;     // the converged shapes of the other layouts
  int resolution_reference_cap = 0;
  int verlet_check_cap = 0;        // the Verlet solve compared with the reference on one pose
  std::vector<int> resolutions;    // particles per fibre of the resolution study; the last is the finest
  // One pose (the check frame): three poses took 127 s at 40 particles per fibre alone and pushed the default run past
  // its 20-minute budget.
  std::size_t resolution_poses = 1;
};

struct ModelChoice {
  std::string label;  // "cubic6", "nearest18", ...
  SpringLayout layout = SpringLayout::nearest_neighbours;
  int neighbours = 0;  // nearest_neighbours only
};

std::string labelOf(SpringLayout layout, int neighbours) {
  return layout == SpringLayout::nearest_neighbours ? "nearest" + std::to_string(neighbours) : toString(layout);
}

ModelChoice modelChoice(SpringLayout layout, int neighbours = 0) { return {labelOf(layout, neighbours), layout, neighbours}; }

ModelSettings modelSettings(const ModelChoice& choice, int particles_per_fibre) {
  ModelSettings settings;
  settings.particles_per_fibre = particles_per_fibre;
  settings.spring_layout = choice.layout;
  if (choice.layout == SpringLayout::nearest_neighbours) settings.nearest_neighbours = choice.neighbours;
  return settings;
}

LocalGlobalSettings referenceSettings(int lbfgs_history) {
  LocalGlobalSettings settings;
  settings.quasi_static = true;
  settings.lbfgs_history = lbfgs_history;
  return settings;
}

// How a reference solve stops: the displacement rule at kReferenceToleranceM, or `cap` iterations.
StoppingSettings referenceStopping(int cap) { return StoppingSettings::atDisplacement(kReferenceToleranceM, cap); }

SimulationSettings referenceSimulationSettings(const ModelChoice& choice, int particles_per_fibre) {
  SimulationSettings settings;
  settings.model = modelSettings(choice, particles_per_fibre);
  settings.solver_kind = SolverKind::local_global;
  settings.local_global = referenceSettings(kReferenceLbfgsHistory);
  return settings;  // collisions on, default CollisionSettings (octree)
}

// The collision stage exactly as the pipeline builds it (same system, hence the same shrunk radii), for a
// chosen broad phase, so configurations can call it from their own checkpointing hook.
std::unique_ptr<CollisionWorld> collisionWorldFor(const DeformationPipeline& simulation, BroadPhaseKind broad_phase) {
  CollisionSettings settings = simulation.settings().simulation.collision;
  settings.broad_phase = broad_phase;
  std::vector<SphereSet> bone_spheres;
  std::vector<std::string> bone_names;
  for (const Bone& bone : simulation.bones()) {
    bone_spheres.push_back(boneSpheresOneRing(bone.surface, settings.bone_sphere_rule));
    bone_names.push_back(bone.name);
  }
  return std::make_unique<CollisionWorld>(simulation.system(), std::move(bone_spheres), settings, bone_names);
}

// Everything measured at one snapshot.
struct PointMetrics {
  double rms_mm = 0;
  double spring_deviation = 0;
  double volume_error_pct = 0, volume_error_max_pct = 0;  // skinned surfaces, |V - V_rest| / V_rest
  double max_penetration_mm = 0;                            // collision spheres into bone spheres
  double surface_penetration_mm = -1;                       // skinned surface vertices inside bone meshes; -1: not measured
};

// One model (layout and resolution) with what measuring it needs, and its converged shape per pose.
struct ModelContext {
  ModelChoice choice;
  int particles_per_fibre = 0;
  int reference_cap = 0;
  // Builds the system (with the collision radii it shrinks at rest) that every configuration solves, and runs the
  // reference settings, so the checkpointed reference solves can be checked against it (particles only).
  std::unique_ptr<DeformationPipeline> simulation;
  std::unique_ptr<LocalGlobalSolver> reference_solver;  // the simulation's settings, prefactored once per model
  std::unique_ptr<SurfaceSkinning> skinning;     // default skinning settings (nearest_average)
  std::unique_ptr<DeformationMetrics> metrics;
  std::map<BroadPhaseKind, std::unique_ptr<CollisionWorld>> collision;
  double stability_bound_s = 0;
  std::map<std::size_t, Eigen::Matrix3Xd> reference;           // by gait frame
  std::map<std::size_t, double> reference_drift_mm;            // how much the reference still moved (ReferenceSolve)
  std::map<std::size_t, Eigen::Matrix3Xd> previous_converged;  // converged shape of the frame before (warm starts)
  mutable std::vector<Vertices> surfaces;                      // skinning buffer

  const MassSpringSystem& system() const { return simulation->system(); }
  CollisionWorld& world(BroadPhaseKind kind) {
    auto& slot = collision[kind];
    if (!slot) slot = collisionWorldFor(*simulation, kind);
    return *slot;
  }
};

std::unique_ptr<ModelContext> makeModel(const BundledScene& bundled, const ModelChoice& choice,
                                        int particles_per_fibre, int reference_cap) {
  auto model = std::make_unique<ModelContext>();
  model->choice = choice;
  model->particles_per_fibre = particles_per_fibre;
  model->reference_cap = reference_cap;
  model->simulation = std::make_unique<DeformationPipeline>(
      bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones,
      bench::particlesOnly(referenceSimulationSettings(choice, particles_per_fibre)));
  model->reference_solver =
      std::make_unique<LocalGlobalSolver>(model->system(), model->simulation->settings().simulation.local_global);
  model->skinning = std::make_unique<SurfaceSkinning>(model->system(), model->simulation->muscles(), SkinningSettings{});
  model->metrics =
      std::make_unique<DeformationMetrics>(model->simulation->bones(), model->simulation->muscles(), model->system());
  const VerletSolver automatic(model->system(), VerletSettings{});
  model->stability_bound_s = automatic.timeStep() / kAutoStepFraction;
  return model;
}

// The skinned surfaces of `position` (into model.surfaces).
void skin(const ModelContext& model, const Eigen::Matrix3Xd& position, const BoneTransforms& transforms) {
  model.skinning->update(position, transforms, model.surfaces);
}

PointMetrics measurePoint(ModelContext& model, CollisionWorld& posed_world, const BoneTransforms& transforms,
                          const Eigen::Matrix3Xd& position, const Eigen::Matrix3Xd& reference, bool with_surface) {
  PointMetrics result;
  result.rms_mm = bench::rmsMillimetres(position, reference);
  result.spring_deviation = measureSprings(model.system().springs, position).deviation_ratio;
  skin(model, position, transforms);
  const int muscles = model.system().muscleCount();
  for (int m = 0; m < muscles; ++m) {
    const double volume = std::abs(enclosedVolume(model.surfaces[m], model.skinning->muscles()[m].triangles()));
    const double error_pct = 100.0 * std::abs(volume - model.metrics->restVolume(m)) / model.metrics->restVolume(m);
    result.volume_error_pct += error_pct / muscles;
    result.volume_error_max_pct = std::max(result.volume_error_max_pct, error_pct);
  }
  ParticleState state;
  state.position = position;
  state.previous_position = position;
  result.max_penetration_mm = 1e3 * posed_world.measure(state).max_penetration_muscle_bone_m;
  if (with_surface) {
    const SceneMetrics scene = model.metrics->measure(model.surfaces, position, transforms);
    result.surface_penetration_mm = 1e3 * scene.max_inside_bone_depth_m;
    // The same volume error by DeformationMetrics' own path: a mismatch would mean the fast path above is wrong.
    if (std::abs(scene.volume_error_mean_pct - result.volume_error_pct) > 1e-6 * (1 + result.volume_error_pct))
      std::printf("WARNING: volume error %.6f%% here, %.6f%% from DeformationMetrics\n", result.volume_error_pct,
                  scene.volume_error_mean_pct);
  }
  return result;
}

struct Config {
  std::string label;
  std::string model;  // ModelChoice label
  SolverKind solver = SolverKind::verlet;
  TimeStepRule dt_rule = TimeStepRule::fixed;
  double dt_fraction = 0;  // fixed Verlet step as a share of the stability bound; 0 for adaptive and local/global
  BroadPhaseKind broad_phase = BroadPhaseKind::octree;
  bool warm = false;
  double volume_weight = 0;
  int lbfgs_history = 0;  // local/global quasi-Newton mode; 0 = plain local/global iterations
  int cap = 0;
};

void addCommon(bench::JsonRecords& records, const std::string& kind, const std::string& config, const std::string& solver,
               const std::string& mode, const std::string& layout, const std::string& dt_rule, double dt_s,
               double dt_fraction, const std::string& broad_phase, const std::string& start, double volume_weight,
               int particles_per_fibre, std::size_t pose) {
  records.add("kind", kind);
  records.add("config", config);
  records.add("solver", solver);
  records.add("mode", mode);
  records.add("layout", layout);
  records.add("dt_rule", dt_rule);
  records.add("dt_s", dt_s);
  records.add("dt_fraction", dt_fraction);
  records.add("broad_phase", broad_phase);
  records.add("start", start);
  records.add("volume_weight", volume_weight);
  records.add("particles_per_fibre", particles_per_fibre);
  records.add("pose", static_cast<double>(pose));
}

void addMetrics(bench::JsonRecords& records, const PointMetrics& metrics) {
  records.add("rms_mm", metrics.rms_mm);
  records.add("spring_deviation", metrics.spring_deviation);
  records.add("volume_error_pct", metrics.volume_error_pct);
  records.add("volume_error_max_pct", metrics.volume_error_max_pct);
  records.add("max_penetration_mm", metrics.max_penetration_mm);
  records.add("surface_penetration_mm", metrics.surface_penetration_mm);
}

// The gait frame a warm start comes from: the one before (at the start of the cycle, the one after).
std::size_t neighbourFrame(std::size_t frame) { return frame > 0 ? frame - 1 : frame + 1; }

// Converged shape of `frame` for `model` (a cold reference solve), recorded as a "reference" point. Solved with
// snapshots (the same solver, settings and collision stage as the model's pipeline) so that how much it still
// moved over the second half of its iterations can be reported: a bound on how far it may be from the true minimum.
struct ReferenceSolve {
  Eigen::Matrix3Xd position;
  SolveStats stats;
  double wall_ms = 0;
  double drift_last_half_mm = 0;  // RMS distance from the snapshot at about half the iterations to the end
  int drift_from_iteration = 0;
};

ReferenceSolve solveReference(ModelContext& model, const BundledScene& bundled, std::size_t frame) {
  const BoneTransforms transforms = boneTransformsOf(model.simulation->bones(), gaitPose(bundled, frame));
  CollisionWorld& world = model.world(BroadPhaseKind::octree);
  world.setBoneTransforms(transforms);
  LocalGlobalSolver& solver = *model.reference_solver;
  const StoppingSettings stopping = referenceStopping(model.reference_cap);
  const bench::ConvergenceRun run = bench::coldSolve(
      model.system(), transforms, &world, model.reference_cap,
      [&](ParticleState& state, const AfterUpdateHook& hook) { return solver.solve(state, stopping, hook); });
  ReferenceSolve result;
  result.position = run.final_position;
  result.stats = run.stats;
  result.wall_ms = run.stats.total_ms;
  for (const bench::Checkpoint& checkpoint : run.checkpoints)
    if (2 * checkpoint.iteration <= run.stats.iterations) {
      result.drift_from_iteration = checkpoint.iteration;
      result.drift_last_half_mm = bench::rmsMillimetres(checkpoint.position, run.final_position);
    }
  return result;
}

void recordReference(bench::JsonRecords& records, ModelContext& model, const BundledScene& bundled,
                     std::size_t frame, const ReferenceSolve& reference) {
  const BoneTransforms transforms = boneTransformsOf(model.simulation->bones(), gaitPose(bundled, frame));
  CollisionWorld& world = model.world(BroadPhaseKind::octree);
  world.setBoneTransforms(transforms);
  // Measured against itself through the same path as every curve point: its rms_mm must come out 0.
  const PointMetrics metrics = measurePoint(model, world, transforms, reference.position, reference.position, true);
  records.begin();
  addCommon(records, "reference", "reference " + model.choice.label + " " + std::to_string(model.particles_per_fibre),
            "local_global", "quasi_static", model.choice.label, "fixed", 0, 0, "octree", "cold", 0,
            model.particles_per_fibre, frame);
  records.add("iterations", reference.stats.iterations);
  records.add("wall_ms", reference.wall_ms);
  addMetrics(records, metrics);
  records.add("reference_cap", model.reference_cap);
  records.add("lbfgs_history", kReferenceLbfgsHistory);
  records.add("reference_tolerance_m", kReferenceToleranceM);
  records.add("last_mean_displacement_m", reference.stats.mean_displacement_m);
  records.add("tolerance_reached", reference.stats.stopping_rule_met ? 1 : 0);
  records.add("drift_last_half_mm", reference.drift_last_half_mm);
  records.add("drift_from_iteration", reference.drift_from_iteration);
  records.end();
  std::printf("  reference %-10s ppf %d frame %2zu: %5d iterations, %7.0f ms, last mean displacement %.2e m (rule %s), "
              "moved %.3f mm RMS since iteration %d, rms to itself %.3g mm, volume error %.2f%% (max %.2f%%), sphere "
              "penetration %.2f mm, surface %.2f mm\n",
              model.choice.label.c_str(), model.particles_per_fibre, frame, reference.stats.iterations,
              reference.wall_ms, reference.stats.mean_displacement_m, reference.stats.stopping_rule_met ? "met" : "not met",
              reference.drift_last_half_mm, reference.drift_from_iteration, metrics.rms_mm, metrics.volume_error_pct,
              metrics.volume_error_max_pct, metrics.max_penetration_mm, metrics.surface_penetration_mm);
}

// The mean over poses of one configuration's curve, for the summary.
struct CurveSummary {
  std::vector<int> iterations;
  std::vector<double> wall_ms_sum, rms_mm_sum;
  int poses = 0;
};

// Adds one pose's curve (start state, then the checkpoints) to a summary.
void accumulate(CurveSummary& summary, const std::vector<int>& iterations, const std::vector<double>& wall_ms,
                const std::vector<double>& rms_mm) {
  if (summary.iterations.empty()) {
    summary.iterations = iterations;
    summary.wall_ms_sum.assign(iterations.size(), 0);
    summary.rms_mm_sum.assign(iterations.size(), 0);
  }
  for (std::size_t k = 0; k < iterations.size(); ++k) {
    summary.wall_ms_sum[k] += wall_ms[k];
    summary.rms_mm_sum[k] += rms_mm[k];
  }
  ++summary.poses;
}

// `summary` gathers every pose; `check_summary` only `check_frame`.
void runConfig(const Config& config, ModelContext& model, const BundledScene& bundled,
               const std::vector<std::size_t>& frames, std::size_t check_frame, bench::JsonRecords& records,
               CurveSummary& summary, CurveSummary& check_summary) {
  const MassSpringSystem& system = model.system();
  std::unique_ptr<VerletSolver> verlet;
  std::unique_ptr<LocalGlobalSolver> local_global;
  double dt_s = 0;
  double factorisation_ms = 0;
  if (config.solver == SolverKind::verlet) {
    VerletSettings settings;
    settings.dt_rule = config.dt_rule;
    if (config.dt_rule == TimeStepRule::fixed) settings.dt_s = config.dt_fraction * model.stability_bound_s;
    verlet = std::make_unique<VerletSolver>(system, settings);
    dt_s = verlet->timeStep();  // the fixed step, or the adaptive rule's upper clamp
  } else {
    LocalGlobalSettings settings;
    settings.quasi_static = true;
    settings.volume_weight = config.volume_weight;
    settings.lbfgs_history = config.lbfgs_history;
    // Prefactored once per model and settings and reused for every pose, as the pipeline does; reported apart.
    local_global = std::make_unique<LocalGlobalSolver>(system, settings);
    factorisation_ms = local_global->factorisationMilliseconds();
  }
  const StoppingSettings stopping = StoppingSettings::afterIterations(config.cap);
  const bench::SolveFunction solve = [&](ParticleState& state, const AfterUpdateHook& hook) {
    return verlet ? verlet->solve(state, stopping, hook) : local_global->solve(state, stopping, hook);
  };
  const std::string solver_name = toString(config.solver);
  const std::string mode = config.solver == SolverKind::verlet ? "dynamic" : "quasi_static";
  const std::string dt_rule = config.dt_rule == TimeStepRule::fixed ? "fixed" : "adaptive";
  CollisionWorld& world = model.world(config.broad_phase);

  for (const std::size_t frame : frames) {
    const BoneTransforms transforms = boneTransformsOf(model.simulation->bones(), gaitPose(bundled, frame));
    world.setBoneTransforms(transforms);
    ParticleState start;
    if (config.warm) {
      // What the pipeline's StartMode::warm does after solving the frame before to convergence.
      const std::size_t before = neighbourFrame(frame);
      start.position = model.previous_converged.at(frame);
      start.previous_position = start.position;
      warmStart(system, boneTransformsOf(model.simulation->bones(), gaitPose(bundled, before)), transforms, start);
    } else {
      rigidPretransform(system, transforms, start);
    }
    if (verlet) {
      VerletSettings settings = verlet->settings();
      verlet = std::make_unique<VerletSolver>(system, settings);  // fresh: the adaptive rule remembers its last step
    }
    const bench::ConvergenceRun run = bench::checkpointedSolve(start, &world, config.cap, solve);
    const Eigen::Matrix3Xd& reference = model.reference.at(frame);

    auto record = [&](int iteration, double wall_ms, const Eigen::Matrix3Xd& position, bool last) {
      const PointMetrics metrics = measurePoint(model, world, transforms, position, reference, last);
      records.begin();
      addCommon(records, "curve", config.label, solver_name, mode, model.choice.label, dt_rule, dt_s,
                config.dt_fraction, toString(config.broad_phase), config.warm ? "warm" : "cold", config.volume_weight,
                model.particles_per_fibre, frame);
      records.add("iterations", iteration);
      records.add("wall_ms", wall_ms);
      addMetrics(records, metrics);
      records.add("factorisation_ms", factorisation_ms);
      records.add("reference_drift_mm", model.reference_drift_mm.at(frame));
      records.add("lbfgs_history", config.lbfgs_history);
      records.end();
      return metrics;
    };
    const PointMetrics at_start = record(0, 0, run.start_position, false);
    PointMetrics at_end;
    std::vector<int> iterations = {0};
    std::vector<double> wall_ms = {0}, rms_mm = {at_start.rms_mm};
    for (std::size_t c = 0; c < run.checkpoints.size(); ++c) {
      const bench::Checkpoint& checkpoint = run.checkpoints[c];
      at_end = record(checkpoint.iteration, checkpoint.wall_ms, checkpoint.position, c + 1 == run.checkpoints.size());
      iterations.push_back(checkpoint.iteration);
      wall_ms.push_back(checkpoint.wall_ms);
      rms_mm.push_back(at_end.rms_mm);
    }
    accumulate(summary, iterations, wall_ms, rms_mm);
    if (frame == check_frame) accumulate(check_summary, iterations, wall_ms, rms_mm);
    std::printf("    %-44s frame %2zu: rms %.2f mm at start, %.3f mm after %d iterations (%.0f ms); volume %.2f%% "
                "(max %.2f%%), sphere penetration %.2f mm, surface %.2f mm\n",
                config.label.c_str(), frame, at_start.rms_mm, at_end.rms_mm, run.checkpoints.back().iteration,
                run.checkpoints.back().wall_ms, at_end.volume_error_pct, at_end.volume_error_max_pct,
                at_end.max_penetration_mm, at_end.surface_penetration_mm);
  }
}

// Wall time (mean over poses) of the first checkpoint whose mean RMS over poses is within `target_mm`; -1 if none.
double millisecondsTo(const CurveSummary& summary, double target_mm) {
  for (std::size_t c = 0; c < summary.iterations.size(); ++c)
    if (summary.rms_mm_sum[c] / summary.poses <= target_mm) return summary.wall_ms_sum[c] / summary.poses;
  return -1;
}

void printSummary(const std::string& title, const std::vector<Config>& configs,
                  const std::vector<CurveSummary>& summaries) {
  std::printf("\nsummary, %s (ms to reach a mean RMS; -1 = not reached within the cap):\n", title.c_str());
  std::printf("%-48s %9s %9s %9s %9s %9s %11s %9s %9s\n", "config", "rms0_mm", "ms_to_5mm", "ms_to_2mm", "ms_to_1mm",
              "ms_to_.5", "best_rms_mm", "at_iter", "at_ms");
  for (std::size_t c = 0; c < configs.size(); ++c) {
    const CurveSummary& summary = summaries[c];
    if (summary.poses == 0) continue;
    std::size_t best = 0;
    for (std::size_t k = 1; k < summary.iterations.size(); ++k)
      if (summary.rms_mm_sum[k] < summary.rms_mm_sum[best]) best = k;
    std::printf("%-48s %9.3f %9.0f %9.0f %9.0f %9.0f %11.3f %9d %9.0f\n", configs[c].label.c_str(),
                summary.rms_mm_sum[0] / summary.poses, millisecondsTo(summary, 5), millisecondsTo(summary, 2),
                millisecondsTo(summary, 1), millisecondsTo(summary, 0.5), summary.rms_mm_sum[best] / summary.poses,
                summary.iterations[best], summary.wall_ms_sum[best] / summary.poses);
  }
}

// The node's situation: the gait streamed through the node's stream protocol (the core's StreamSession, poses 1/60 s
// apart), every frame warm from the previous result with `iterations_per_frame` iterations, as the node does. The
// cycle is played twice and the five reference frames are measured on the second pass, so each starts warm from a
// stream that has run for a cycle. One curve point per reference frame: iterations = iterations per frame, wall_ms =
// that frame's solve time.
void runStreaming(const std::string& label, SolverKind solver, int lbfgs_history, int iterations_per_frame,
                  ModelContext& model, const BundledScene& bundled, const std::vector<std::size_t>& frames,
                  bench::JsonRecords& records) {
  PipelineSettings settings = model.simulation->settings();
  settings.simulation.solver_kind = solver;
  settings.simulation.local_global.lbfgs_history = lbfgs_history;
  StreamSessionSettings stream_settings;  // the core's stream defaults (warm starts, the node's speed limits)
  stream_settings.stopping = FrameStopping::of(StoppingSettings::afterIterations(iterations_per_frame));
  StreamSession stream(bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones, settings,
                       stream_settings);
  const std::size_t frame_count = bundled.gait.frames.size();
  double solve_ms_sum = 0;
  // The gait loops smoothly, so the second pass goes on warm.
  std::size_t played = 0;
  for (int pass = 0; pass < 2; ++pass)
    for (std::size_t frame = 0; frame < frame_count; ++frame) {
      const Pose pose = gaitPose(bundled, frame);
      const FrameResult* solved =
          bench::frameOf(stream.offer(bench::streamStamp(played++), boneTransformsOf(stream.bones(), pose), FrameWants{}));
      if (pass == 0 || std::find(frames.begin(), frames.end(), frame) == frames.end()) continue;
      if (!solved) {
        std::printf("    %-44s frame %zu: no bone moved since the last solved pose, not solved again\n", label.c_str(),
                    frame);
        continue;
      }
      const FrameStats& stats = solved->stats;
      solve_ms_sum += stats.solver.total_ms;
      const BoneTransforms transforms = boneTransformsOf(model.simulation->bones(), pose);
      CollisionWorld& world = model.world(BroadPhaseKind::octree);
      world.setBoneTransforms(transforms);
      const PointMetrics metrics =
          measurePoint(model, world, transforms, stream.pipeline().state().position, model.reference.at(frame), false);
      records.begin();
      addCommon(records, "curve", label, toString(solver), solver == SolverKind::verlet ? "dynamic" : "quasi_static",
                model.choice.label, "fixed",
                solver == SolverKind::verlet ? stream.pipeline().settings().simulation.verlet.dt_s : 0,
                solver == SolverKind::verlet ? kAutoStepFraction : 0, "octree", "warm", 0, model.particles_per_fibre,
                frame);
      records.add("iterations", iterations_per_frame);
      records.add("wall_ms", stats.solver.total_ms);
      addMetrics(records, metrics);
      records.add("reference_drift_mm", model.reference_drift_mm.at(frame));
      records.add("lbfgs_history", lbfgs_history);
      records.add("streaming", 1);
      records.end();
    }
  const StreamCounters& counters = stream.counters();
  std::printf("    %-44s %3d iterations per frame: mean solve %.1f ms at the reference frames (%u poses: %u solved, %u "
              "unchanged, %u restarts)\n",
              label.c_str(), iterations_per_frame, solve_ms_sum / static_cast<double>(frames.size()), counters.offered,
              counters.solved, counters.unchanged, counters.resets);
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const auto start = Clock::now();

  Budget budget;
  if (options.quick) {
    budget.verlet_cap = 200;
    budget.local_global_cap = 50;
    budget.local_global_volume_cap = 20;
    budget.lbfgs_cap = 50;
    budget.reference_cap = 300;
    budget.other_reference_cap = 300;
    budget.resolution_reference_cap = 300;
    budget.verlet_check_cap = 600;
    budget.resolutions = {20, 40};
  } else {
    budget.verlet_cap = 1500;
    budget.local_global_cap = 400;
    budget.local_global_volume_cap = 100;
    budget.lbfgs_cap = 300;
    budget.reference_cap = 3000;
    budget.other_reference_cap = 3000;
    budget.resolution_reference_cap = 3000;
    budget.verlet_check_cap = 20000;
    budget.resolutions = {20, 40, 60, 80};
  }

  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR);
  const std::vector<std::size_t> five = fiveGaitFrames(bundled);
  // Quick runs use the middle frame only (mid-cycle, where the default run checks the two solvers against each other).
  const std::size_t check_frame = five[five.size() / 2];
  const std::vector<std::size_t> frames = options.quick ? std::vector<std::size_t>{check_frame} : five;
  // The resolution study's poses: the check frame first, then the others of the five.
  std::vector<std::size_t> resolution_frames = {check_frame};
  for (const std::size_t frame : frames)
    if (resolution_frames.size() < budget.resolution_poses && frame != check_frame) resolution_frames.push_back(frame);

  const ModelSettings defaults;
  const ModelChoice default_model = modelChoice(defaults.spring_layout, defaults.nearest_neighbours);
  const std::vector<ModelChoice> models = {
      modelChoice(SpringLayout::cubic6),
      modelChoice(SpringLayout::cubic26),
      modelChoice(SpringLayout::nearest_neighbours, 10),
      modelChoice(SpringLayout::nearest_neighbours, 18),
      modelChoice(SpringLayout::nearest_neighbours, 25),
      modelChoice(SpringLayout::delaunay),
  };

  // Configurations: every layout with the automatic fixed step; the rest on the default layout.
  std::vector<Config> configs;
  auto verletConfig = [&](const std::string& model, TimeStepRule rule, double fraction, BroadPhaseKind broad, bool warm) {
    Config config;
    config.model = model;
    config.solver = SolverKind::verlet;
    config.dt_rule = rule;
    config.dt_fraction = rule == TimeStepRule::fixed ? fraction : 0;
    config.broad_phase = broad;
    config.warm = warm;
    config.cap = budget.verlet_cap;
    char label[160];
    std::snprintf(label, sizeof label, "verlet %s dt %s %s %s", model.c_str(),
                  rule == TimeStepRule::fixed ? (std::to_string(fraction).substr(0, 4) + "xbound").c_str() : "adaptive",
                  toString(broad), warm ? "warm" : "cold");
    config.label = label;
    return config;
  };
  const std::string default_label = default_model.label;
  for (const ModelChoice& model : models)
    configs.push_back(verletConfig(model.label, TimeStepRule::fixed, kAutoStepFraction, BroadPhaseKind::octree, false));
  for (const double fraction : {0.25, 0.5})
    configs.push_back(verletConfig(default_label, TimeStepRule::fixed, fraction, BroadPhaseKind::octree, false));
  configs.push_back(verletConfig(default_label, TimeStepRule::adaptive, 0, BroadPhaseKind::octree, false));
  configs.push_back(verletConfig(default_label, TimeStepRule::fixed, kAutoStepFraction, BroadPhaseKind::hash_grid, false));
  configs.push_back(verletConfig(default_label, TimeStepRule::fixed, kAutoStepFraction, BroadPhaseKind::octree, true));
  for (const double volume_weight : {0.0, kVolumeWeight})
    for (const bool warm : {false, true}) {
      Config config;
      config.model = default_label;
      config.solver = SolverKind::local_global;
      config.volume_weight = volume_weight;
      config.warm = warm;
      config.cap = volume_weight > 0 ? budget.local_global_volume_cap : budget.local_global_cap;
      config.label = "local_global " + default_label + (volume_weight > 0 ? " volume " : " ") + (warm ? "warm" : "cold");
      configs.push_back(config);
    }
  for (const bool warm : {false, true}) {
    Config config;
    config.model = default_label;
    config.solver = SolverKind::local_global;
    config.lbfgs_history = kReferenceLbfgsHistory;
    config.warm = warm;
    config.cap = budget.lbfgs_cap;
    config.label = "local_global " + default_label + " lbfgs" + std::to_string(kReferenceLbfgsHistory) + (warm ? " warm" : " cold");
    configs.push_back(config);
  }

  // Work for the time estimate, in particle iterations over particles per fibre (the fibre count is the same for
  // every model): references at their caps, the reference check, every configuration, the resolution study.
  const auto work = [](double iterations, int particles_per_fibre) { return iterations * particles_per_fibre; };
  double total_work = 0;
  for (const ModelChoice& model : models)
    total_work += work(static_cast<double>(model.label == default_label ? 2 * budget.reference_cap : budget.other_reference_cap) *
                           static_cast<double>(frames.size()),
                       budget.particles_per_fibre);
  for (const Config& config : configs)
    total_work += work(static_cast<double>(config.cap) * static_cast<double>(frames.size()), budget.particles_per_fibre);
  total_work += work(budget.verlet_check_cap + budget.reference_cap, budget.particles_per_fibre);
  // Streaming: two passes over the gait per iteration count; an L-BFGS iteration costs about three Verlet ones.
  double streaming_work = 0;
  for (const int per_frame : kStreamingVerletIterations)
    streaming_work += work(2.0 * static_cast<double>(bundled.gait.frames.size()) * per_frame, budget.particles_per_fibre);
  for (const int per_frame : kStreamingLbfgsIterations)
    streaming_work += work(6.0 * static_cast<double>(bundled.gait.frames.size()) * per_frame, budget.particles_per_fibre);
  total_work += streaming_work;
  for (const int ppf : budget.resolutions)
    if (ppf != budget.particles_per_fibre)
      total_work += work(static_cast<double>(budget.resolution_reference_cap) * static_cast<double>(resolution_frames.size()), ppf);
  bench::Progress progress("speed_vs_error", total_work);

  std::printf("speed against error: thigh13, %d particles per fibre, gait frames", budget.particles_per_fibre);
  for (const std::size_t frame : frames) std::printf(" %zu", frame);
  std::printf("; caps: Verlet %d, local/global %d (with volume term %d, L-BFGS %d); references: local/global L-BFGS(%d) to "
              "%.0e m per iteration or %d iterations (default layout), %d (other layouts), %d (resolution study)\n",
              budget.verlet_cap, budget.local_global_cap, budget.local_global_volume_cap, budget.lbfgs_cap,
              kReferenceLbfgsHistory, kReferenceToleranceM, budget.reference_cap, budget.other_reference_cap,
              budget.resolution_reference_cap);

  bench::JsonRecords records;
  std::vector<CurveSummary> summaries(configs.size()), check_summaries(configs.size());
  std::map<std::size_t, ReferenceSolve> default_references;  // the default model's converged shapes, for resolution

  for (const ModelChoice& choice : models) {
    const auto model_start = Clock::now();
    const bool is_default = choice.label == default_label;
    std::unique_ptr<ModelContext> model = makeModel(bundled, choice, budget.particles_per_fibre,
                                                    is_default ? budget.reference_cap : budget.other_reference_cap);
    std::printf("model %s: %ld particles, %zu springs, stability bound %.3e s (built in %.1f s)\n", choice.label.c_str(),
                static_cast<long>(model->system().particleCount()), model->system().springs.size(),
                model->stability_bound_s, secondsSince(model_start));
    for (const std::size_t frame : frames) {
      const ReferenceSolve reference = solveReference(*model, bundled, frame);
      model->reference[frame] = reference.position;
      model->reference_drift_mm[frame] = reference.drift_last_half_mm;
      if (is_default) default_references[frame] = reference;
      recordReference(records, *model, bundled, frame, reference);
      if (is_default) {
        const ReferenceSolve before = solveReference(*model, bundled, neighbourFrame(frame));
        model->previous_converged[frame] = before.position;
        std::printf("  converged frame %zu for the warm start of frame %zu: %d iterations, last mean displacement %.2e m, "
                    "moved %.3f mm RMS since iteration %d\n",
                    neighbourFrame(frame), frame, before.stats.iterations, before.stats.mean_displacement_m,
                    before.drift_last_half_mm, before.drift_from_iteration);
      }
    }
    progress.finished("references of " + choice.label,
                      work(static_cast<double>((is_default ? 2 : 1) * model->reference_cap) * static_cast<double>(frames.size()),
                           budget.particles_per_fibre));

    if (is_default) {
      // The checkpointed solves must be the solves the pipeline runs: its own solve, stopped at a checkpoint's
      // iteration count, has to land on that checkpoint.
      const BoneTransforms transforms = boneTransformsOf(model->simulation->bones(), gaitPose(bundled, check_frame));
      CollisionWorld& world = model->world(BroadPhaseKind::octree);
      const int same_cap = budget.local_global_cap;
      const PipelineSettings& short_settings = model->simulation->settings();
      const StoppingSettings short_stopping = StoppingSettings::afterIterations(same_cap);
      DeformationPipeline short_simulation(bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones,
                                           short_settings);
      short_simulation.solve(transforms, StartMode::cold, FrameStopping::of(short_stopping), false, false);
      world.setBoneTransforms(transforms);
      LocalGlobalSolver short_solver(model->system(), short_settings.simulation.local_global);
      const bench::ConvergenceRun short_run = bench::coldSolve(
          model->system(), transforms, &world, same_cap,
          [&](ParticleState& state, const AfterUpdateHook& hook) { return short_solver.solve(state, short_stopping, hook); });
      const double harness_difference_mm = bench::rmsMillimetres(short_run.final_position, short_simulation.state().position);
      std::printf("  the pipeline against the checkpointed solve after %d iterations: %.3g mm RMS apart\n", same_cap,
                  harness_difference_mm);

      // Which solver gives the trustworthy converged shape: damped Verlet and L-BFGS with a shorter history, each run
      // cold to the same rule, compared with the reference.
      const Eigen::Matrix3Xd& reference = model->reference.at(check_frame);
      struct CheckSolve {
        std::string solver;
        int lbfgs_history;
        bench::ConvergenceRun run;
      };
      std::vector<CheckSolve> checks;
      {
        VerletSolver verlet(model->system(), VerletSettings{});
        const StoppingSettings verlet_stopping = referenceStopping(budget.verlet_check_cap);
        checks.push_back({"verlet", 0, bench::coldSolve(model->system(), transforms, &world, budget.verlet_check_cap,
                                                        [&](ParticleState& state, const AfterUpdateHook& hook) {
                                                          return verlet.solve(state, verlet_stopping, hook);
                                                        })});
        LocalGlobalSolver lbfgs(model->system(), referenceSettings(kCheckLbfgsHistory));
        const StoppingSettings lbfgs_stopping = referenceStopping(budget.reference_cap);
        checks.push_back({"local_global", kCheckLbfgsHistory,
                          bench::coldSolve(model->system(), transforms, &world, budget.reference_cap,
                                           [&](ParticleState& state, const AfterUpdateHook& hook) {
                                             return lbfgs.solve(state, lbfgs_stopping, hook);
                                           })});
      }
      for (const CheckSolve& check : checks) {
        const bench::ConvergenceRun& run = check.run;
        double drift_mm = 0;
        int drift_from = 0;
        for (const bench::Checkpoint& checkpoint : run.checkpoints)
          if (2 * checkpoint.iteration <= run.stats.iterations) {
            drift_from = checkpoint.iteration;
            drift_mm = bench::rmsMillimetres(checkpoint.position, run.final_position);
          }
        const double to_reference_mm = bench::rmsMillimetres(run.final_position, reference);
        std::printf("  reference check, frame %zu: %s (L-BFGS history %d) cold to the same rule ran %d iterations (%.0f "
                    "ms, last mean displacement %.2e m, rule %s, moved %.3f mm since iteration %d) and ends %.3f mm RMS "
                    "from the reference\n",
                    check_frame, check.solver.c_str(), check.lbfgs_history, run.stats.iterations, run.stats.total_ms,
                    run.stats.mean_displacement_m, run.stats.stopping_rule_met ? "met" : "not met", drift_mm, drift_from,
                    to_reference_mm);
        records.begin();
        addCommon(records, "reference_check", "reference check " + check.solver, check.solver,
                  check.solver == "verlet" ? "dynamic" : "quasi_static", choice.label, "fixed",
                  check.solver == "verlet" ? kAutoStepFraction * model->stability_bound_s : 0,
                  check.solver == "verlet" ? kAutoStepFraction : 0, "octree", "cold", 0, budget.particles_per_fibre,
                  check_frame);
        records.add("lbfgs_history", check.lbfgs_history);
        records.add("iterations", run.stats.iterations);
        records.add("wall_ms", run.stats.total_ms);
        records.add("rms_mm", to_reference_mm);
        records.add("last_mean_displacement_m", run.stats.mean_displacement_m);
        records.add("tolerance_reached", run.stats.stopping_rule_met ? 1 : 0);
        records.add("drift_last_half_mm", drift_mm);
        records.add("drift_from_iteration", drift_from);
        records.add("simulation_vs_checkpointed_rms_mm", harness_difference_mm);
        records.add("simulation_vs_checkpointed_iterations", same_cap);
        records.end();
      }
      progress.finished("reference check", work(budget.verlet_check_cap + budget.reference_cap, budget.particles_per_fibre));
    }

    for (std::size_t c = 0; c < configs.size(); ++c) {
      if (configs[c].model != choice.label) continue;
      runConfig(configs[c], *model, bundled, frames, check_frame, records, summaries[c], check_summaries[c]);
      progress.finished(configs[c].label,
                        work(static_cast<double>(configs[c].cap) * static_cast<double>(frames.size()), budget.particles_per_fibre));
    }
    if (is_default) {
      for (const int per_frame : kStreamingVerletIterations)
        runStreaming("verlet " + default_label + " streaming", SolverKind::verlet, 0, per_frame, *model, bundled, frames,
                     records);
      for (const int per_frame : kStreamingLbfgsIterations)
        runStreaming("local_global " + default_label + " lbfgs" + std::to_string(kReferenceLbfgsHistory) + " streaming",
                     SolverKind::local_global, kReferenceLbfgsHistory, per_frame, *model, bundled, frames, records);
      progress.finished("streaming", streaming_work);
    }
  }

  // Resolution: converged surfaces at each resolution against the finest, same pose, same skinning.
  std::vector<std::vector<std::vector<Vertices>>> surfaces_by_resolution(budget.resolutions.size());
  std::vector<std::vector<ReferenceSolve>> solves_by_resolution(budget.resolutions.size());
  std::vector<std::vector<PointMetrics>> metrics_by_resolution(budget.resolutions.size());
  for (std::size_t r = 0; r < budget.resolutions.size(); ++r) {
    const int ppf = budget.resolutions[r];
    std::unique_ptr<ModelContext> model = makeModel(bundled, default_model, ppf, budget.resolution_reference_cap);
    for (const std::size_t frame : resolution_frames) {
      ReferenceSolve solve;
      if (ppf == budget.particles_per_fibre && default_references.count(frame)) {
        solve = default_references.at(frame);  // already solved above with the same settings
      } else {
        solve = solveReference(*model, bundled, frame);
        recordReference(records, *model, bundled, frame, solve);
      }
      const BoneTransforms transforms = boneTransformsOf(model->simulation->bones(), gaitPose(bundled, frame));
      CollisionWorld& world = model->world(BroadPhaseKind::octree);
      world.setBoneTransforms(transforms);
      metrics_by_resolution[r].push_back(measurePoint(*model, world, transforms, solve.position, solve.position, true));
      surfaces_by_resolution[r].push_back(model->surfaces);  // measurePoint left the skinned surfaces here
      solves_by_resolution[r].push_back(solve);
    }
    progress.finished("resolution " + std::to_string(ppf) + " particles per fibre",
                      ppf == budget.particles_per_fibre
                          ? 0.0
                          : work(static_cast<double>(budget.resolution_reference_cap) * static_cast<double>(resolution_frames.size()), ppf));
  }
  const std::size_t finest = budget.resolutions.size() - 1;
  std::printf("\nresolution (converged surfaces against %d particles per fibre):\n", budget.resolutions[finest]);
  for (std::size_t r = 0; r < budget.resolutions.size(); ++r)
    for (std::size_t f = 0; f < resolution_frames.size(); ++f) {
      double squared = 0;
      Eigen::Index vertices = 0;
      const std::vector<Vertices>& surfaces = surfaces_by_resolution[r][f];
      const std::vector<Vertices>& target = surfaces_by_resolution[finest][f];
      for (std::size_t m = 0; m < surfaces.size(); ++m) {
        squared += (surfaces[m] - target[m]).colwise().squaredNorm().sum();
        vertices += surfaces[m].cols();
      }
      PointMetrics metrics = metrics_by_resolution[r][f];
      metrics.rms_mm = 1e3 * std::sqrt(squared / static_cast<double>(vertices));
      const ReferenceSolve& solve = solves_by_resolution[r][f];
      records.begin();
      addCommon(records, "resolution", "resolution " + std::to_string(budget.resolutions[r]), "local_global",
                "quasi_static", default_label, "fixed", 0, 0, "octree", "cold", 0, budget.resolutions[r],
                resolution_frames[f]);
      records.add("lbfgs_history", kReferenceLbfgsHistory);
      records.add("iterations", solve.stats.iterations);
      records.add("wall_ms", solve.wall_ms);
      addMetrics(records, metrics);
      records.add("surface_vertices", static_cast<double>(vertices));
      records.add("last_mean_displacement_m", solve.stats.mean_displacement_m);
      records.add("tolerance_reached", solve.stats.stopping_rule_met ? 1 : 0);
      records.add("drift_last_half_mm", solve.drift_last_half_mm);
      records.add("drift_from_iteration", solve.drift_from_iteration);
      records.end();
      std::printf("  %2d per fibre, frame %2zu: surface RMS %.3f mm, volume error %.2f%% (max %.2f%%), surface "
                  "penetration %.2f mm\n",
                  budget.resolutions[r], resolution_frames[f], metrics.rms_mm, metrics.volume_error_pct,
                  metrics.volume_error_max_pct, metrics.surface_penetration_mm);
    }

  printSummary("mean over " + std::to_string(frames.size()) + " poses", configs, summaries);
  printSummary("frame " + std::to_string(check_frame) + " only, the pose whose converged shape settles best",
               configs, check_summaries);

  std::printf("speed_vs_error done in %.0f s\n", secondsSince(start));
  return bench::finish(records, options, "speed_vs_error.json");
}
