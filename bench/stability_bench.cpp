// Stability on hard cases, on the bundled scene (the 13 thigh13 muscles, 20 particles per fibre, node defaults), plus
// the 2019 PBD thesis' femur flexion scenario on our data. Every frame stops as the node's frames do (its frame
// stopping); the multi-frame motions are played through the node's stream protocol (the core's StreamSession, poses
// 1/60 s apart), single poses and the forced-warm jump through the pipeline directly. Writes out/bench/stability.json:
// one object per case.
//
//   stability_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "convergence_run.hpp"
#include "node_defaults.hpp"
#include "stream_play.hpp"
#include "worst_folding.hpp"

#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/solvers/solve_control.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

using namespace muscle_deformation;

namespace {

// gait2392: hip_flexion_r positive is flexion, knee_angle_r negative is flexion.
Pose jointPose(const BundledScene& bundled, double hip_flexion_rad, double knee_flexion_rad) {
  return poseFor(bundled, {{"hip_flexion_r", hip_flexion_rad}, {"knee_angle_r", -knee_flexion_rad}});
}

Eigen::Matrix3Xd pretransformOf(const DeformationPipeline& simulation, const Pose& pose) {
  ParticleState state = restState(simulation.system());
  rigidPretransform(simulation.system(), boneTransformsOf(simulation.bones(), pose), state);
  return state.position;
}

bool statsFinite(const FrameStats& stats) {
  const SolveStats& s = stats.solver;
  const CollisionStats& c = stats.collision;
  for (const double v : {s.mss_ms, s.collision_ms, s.total_ms, s.last_dt_s, s.mean_displacement_m,
                         s.spring_deviation_ratio, s.mean_strain, s.max_strain, s.time_step_s,
                         c.max_penetration_muscle_muscle_m, c.max_penetration_muscle_bone_m})
    if (!std::isfinite(v)) return false;
  return true;
}

// Largest |volume change| over muscles, from tetrahedra over each muscle's particles (cheap; no surface skinning).
double maxVolumeErrorPct(const MuscleTetrahedra& tetrahedra, const Eigen::Matrix3Xd& position) {
  return 100.0 * muscleVolumeChange(tetrahedra, position).cwiseAbs().maxCoeff();
}

struct Outcome {
  int recoveries = 0;
  bool diverged = false;
  bool finite = true;
  int iterations = 0;
  double wall_ms = 0;
  double time_step_s = 0;
  double max_penetration_bone_m = 0;
  double max_penetration_muscle_m = 0;
  // How deep any particle's centre went into a bone (its distance field; a fixed particle not counted in its own bone),
  // measured after every frame, whatever the proxy the contacts use.
  double max_particle_depth_m = 0;
  std::string deepest_particle;  // "muscle in bone"
  bench::WorstFolding folding;  // whether the fibres kept their line, the worst frame
  std::unique_ptr<DeformationMetrics> metrics;
};

void accumulate(Outcome& outcome, const DeformationPipeline& simulation, const FrameStats& stats) {
  outcome.recoveries += stats.solver.divergence_recoveries;
  outcome.diverged = outcome.diverged || stats.solver.diverged;
  outcome.finite = outcome.finite && stats.finite && simulation.state().position.allFinite() && statsFinite(stats);
  for (const Eigen::Matrix3Xd& fibre : fibrePolylines(simulation.system(), simulation.state().position))
    outcome.finite = outcome.finite && fibre.allFinite();
  outcome.folding.measure(simulation.system(), simulation.state().position);
  outcome.iterations += stats.solver.iterations;
  outcome.wall_ms += stats.solve_ms;
  outcome.time_step_s = stats.solver.time_step_s;
  outcome.max_penetration_bone_m = std::max(outcome.max_penetration_bone_m, stats.collision.max_penetration_muscle_bone_m);
  outcome.max_penetration_muscle_m =
      std::max(outcome.max_penetration_muscle_m, stats.collision.max_penetration_muscle_muscle_m);
  if (!outcome.metrics)
    outcome.metrics = std::make_unique<DeformationMetrics>(simulation.bones(), simulation.muscles(), simulation.system(),
                                                           simulation.boneFields());
  const SceneMetrics particles = outcome.metrics->measureParticles(simulation.state().position, simulation.boneTransforms());
  for (const MuscleMetrics& muscle : particles.muscles)
    if (muscle.max_particle_inside_bone_depth_m > outcome.max_particle_depth_m) {
      outcome.max_particle_depth_m = muscle.max_particle_inside_bone_depth_m;
      outcome.deepest_particle = muscle.name + " in " + muscle.deepest_particle_bone;
    }
}

class Report {
 public:
  explicit Report(bench::JsonRecords& records) : records_(records), start_(std::chrono::steady_clock::now()) {}
  void add(const std::string& name, const std::string& description, const Outcome& outcome, double rms_to_pretransform_mm,
           double volume_error_pct, const MassSpringSystem& system) {
    records_.begin();
    records_.add("case", name);
    records_.add("description", description);
    records_.add("particles", static_cast<double>(system.particleCount()));
    records_.add("median_sphere_radius_mm", system.medianCollisionRadius() * 1e3);
    records_.add("recoveries", outcome.recoveries);
    records_.add("diverged", outcome.diverged ? 1.0 : 0.0);
    records_.add("finite", outcome.finite ? 1.0 : 0.0);
    records_.add("iterations", outcome.iterations);
    records_.add("wall_ms", outcome.wall_ms);
    records_.add("time_step_s", outcome.time_step_s);
    records_.add("rms_to_pretransform_mm", rms_to_pretransform_mm);
    records_.add("max_penetration_sphere_bone_mm", outcome.max_penetration_bone_m * 1e3);
    records_.add("max_penetration_sphere_muscle_mm", outcome.max_penetration_muscle_m * 1e3);
    records_.add("max_particle_inside_bone_mm", outcome.max_particle_depth_m * 1e3);
    records_.add("deepest_particle", outcome.deepest_particle);
    records_.add("particle_volume_error_max_pct", volume_error_pct);  // tetrahedra over the particles
    outcome.folding.record(records_);
    records_.end();
    std::printf("[%6.1f s] %-22s recoveries %d%s, %s, %d iterations, %.0f ms, RMS to pre-transform %.2f mm, "
                "bone penetration %.2f mm, particles in bone %.2f mm (%s), particle-volume error max %.2f %%\n",
                elapsedSeconds(), name.c_str(), outcome.recoveries, outcome.diverged ? " (gave up)" : "",
                outcome.finite ? "finite" : "NOT FINITE", outcome.iterations, outcome.wall_ms,
                rms_to_pretransform_mm, outcome.max_penetration_bone_m * 1e3, outcome.max_particle_depth_m * 1e3,
                outcome.deepest_particle.empty() ? "none" : outcome.deepest_particle.c_str(), volume_error_pct);
    std::fflush(stdout);
  }
  double elapsedSeconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  bench::JsonRecords& records_;
  std::chrono::steady_clock::time_point start_;
};

// The node's pipeline settings (particles only) with `simulation` for the model and solver, and how its frames stop.
struct Setup {
  PipelineSettings pipeline;
  StreamSessionSettings stream;
};

Setup setupOf(const CoreSettings& node, const SimulationSettings& simulation) {
  Setup setup{bench::particlesOnly(node.pipeline), node.stream};
  setup.pipeline.simulation = simulation;
  return setup;
}

std::unique_ptr<DeformationPipeline> pipelineOf(const Scene& scene, const Setup& setup) {
  return std::make_unique<DeformationPipeline>(scene.muscle_descriptions, scene.muscles, scene.bones, setup.pipeline);
}

// A motion played as the node's stream plays poses, 1/60 s apart: `offer` solves the next pose, or says how the stream
// took it when it solved nothing.
class Stream {
 public:
  Stream(const Scene& scene, const Setup& setup)
      : session_(scene.muscle_descriptions, scene.muscles, scene.bones, setup.pipeline, setup.stream) {}
  // The frame the stream solved for `pose`; nullptr when it solved nothing (no bone moved).
  const FrameResult* offer(const Pose& pose, const FrameWants& wants = {}) {
    const StreamStep step =
        session_.offer(bench::streamStamp(played_++), boneTransformsOf(session_.bones(), pose), wants);
    last_cold_ = step.cold;
    return bench::frameOf(step);
  }
  bool lastCold() const { return last_cold_; }
  bool wantsRefinement() const { return session_.wantsRefinement(); }
  const DeformationPipeline& pipeline() const { return session_.pipeline(); }
  const StreamCounters& counters() const { return session_.counters(); }

 private:
  StreamSession session_;
  std::size_t played_ = 0;
  bool last_cold_ = false;
};

// One pose solved on a fresh thigh13 pipeline, starting as `start` after an optional rest frame.
// How the posed frame starts after the rest frame: warm whatever the jump, or as the node's stream decides (cold at a
// discontinuity: a bone faster than its limits between two frames 1/60 s apart).
enum class After { cold, warm, stream };

void poseCase(Report& report, const BundledScene& bundled, const std::string& name, const std::string& description,
              const Setup& setup, const Pose& pose, After after) {
  const Pose rest = jointPose(bundled, 0, 0);
  std::unique_ptr<DeformationPipeline> own;
  std::unique_ptr<Stream> stream;
  const FrameResult* frame = nullptr;
  if (after == After::stream) {
    stream = std::make_unique<Stream>(bundled.scene, setup);
    stream->offer(rest);
    frame = stream->offer(pose);
    std::printf("[%6.1f s] %s: the stream starts the posed frame %s\n", report.elapsedSeconds(), name.c_str(),
                !frame ? "not at all (no bone moved)" : stream->lastCold() ? "cold" : "warm");
  } else {
    own = pipelineOf(bundled.scene, setup);
    const FrameStopping& stopping = setup.stream.stopping;
    if (after == After::warm)
      own->solve(boneTransformsOf(own->bones(), rest), StartMode::cold, stopping, false, false);
    frame = &own->solve(boneTransformsOf(own->bones(), pose), after == After::cold ? StartMode::cold : StartMode::warm,
                        stopping, false, false);
  }
  const DeformationPipeline& simulation = stream ? stream->pipeline() : *own;
  const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
  Outcome outcome;
  if (frame) accumulate(outcome, simulation, frame->stats);
  report.add(name, description, outcome, bench::rmsMillimetres(simulation.state().position, pretransformOf(simulation, pose)),
             maxVolumeErrorPct(tetrahedra, simulation.state().position), simulation.system());
}

// A motion's stream counters, when the stream did anything but solve every pose warm after the first.
void reportStream(const Report& report, const std::string& name, const Stream& stream) {
  const StreamCounters& c = stream.counters();
  if (c.unchanged > 0 || c.refined > 0 || c.resets > 0 || c.failed > 0)
    std::printf("[%6.1f s] %s: of %u poses the stream left %u unchanged, refined %u, restarted %u times\n",
                report.elapsedSeconds(), name.c_str(), c.offered, c.unchanged, c.refined, c.resets);
}

// A motion streamed as the node streams it (poses 1/60 s apart), then held still: per frame the spring strain (99th
// percentile and max), the particles' depth in bone and the model's own volume (tetrahedra over each muscle's
// particles; no surface, so no projection), and how many held poses it takes until the stream stops refining (the
// residual criterion met, or the residual no longer falling).
struct MotionFigures {
  double strain_p99_median = 0, strain_p99_max = 0;  // over the solved frames of the motion (NaN: none)
  double max_strain = 0, volume_error_max_pct = 0, residual_last = -1;
  double residual_motion_median = std::nan("");  // the solved frames of the motion (not the hold)
  double residual_motion_max = std::nan("");
  int held_until_settled = -1;  // -1: still refining when the hold ended
  int catch_up_sweeps = 0;       // past the budget for a residual far above the stream's (FrameStopping)
  double frame_ms_median = 0;    // the motion's solved frames (not the hold)
  bool settled_converged = false;
  std::uint32_t restarts = 0;
  // The last frame solved within the first kHeldPosesJudged held poses (0: the motion's last frame, when the hold
  // solved none): the worst muscle's volume error of its skinned surface before any correction (the model's own, as
  // the fidelity section measures it; NaN: not measured) and its strain p99, to set against the held pose's own strain
  // when converged (ConvergedStrain::last_p99).
  int after_hold_poses = -1;
  double after_hold_volume_error_max_pct = std::nan("");
  double after_hold_strain_p99 = std::nan("");
};

// Which springs make a motion's strain 99th percentile: per frame, the springs at or above that frame's p99 (as
// measureSprings measures strain: against the segmented length, |l - l0| / l0), counted by their muscle and by kind
// (a tendon: one end a tendon anchor; across the fibres: a belly spring at more than 45 degrees to them, one of the
// springs the belly's transverse_stiffness_ratio makes soft) and by sign (stretched or compressed), summed over the
// motion's frames.
struct StrainOwners {
  std::vector<double> by_muscle;  // springs counted, per muscle
  double tendons = 0, across = 0, stretched = 0, total = 0;

  void add(const MassSpringSystem& system, const Eigen::Matrix3Xd& position, double p99) {
    if (!(p99 > 0)) return;
    if (by_muscle.empty()) by_muscle.assign(static_cast<std::size_t>(system.muscleCount()), 0.0);
    const SpringSet& springs = system.springs;
    const BellyTone& tone = system.belly_tone;
    const bool with_alignment = tone.alignment_squared.size() == static_cast<Eigen::Index>(springs.size());
    for (std::size_t s = 0; s < springs.size(); ++s) {
      const auto e = static_cast<Eigen::Index>(s);
      const double rest = segmentedLength(springs, e);
      const double length = (position.col(springs.second[s]) - position.col(springs.first[s])).norm();
      if (std::abs(length - rest) / rest < p99) continue;
      if (length > rest) stretched += 1;
      const auto a = static_cast<std::size_t>(springs.first[s]), b = static_cast<std::size_t>(springs.second[s]);
      by_muscle[static_cast<std::size_t>(system.muscle_of[a])] += 1;
      if (system.fibre_of[a] == kTendonAnchor || system.fibre_of[b] == kTendonAnchor) tendons += 1;
      if (with_alignment && tone.first_fibre[s] >= 0 && tone.second_fibre[s] >= 0 && tone.alignment_squared[e] < 0.5)
        across += 1;
      total += 1;
    }
  }

  // "rectus_femoris 31 %, ...; tendons 1 %, across the fibres 60 %, stretched 70 %": the muscles holding 80 % of them,
  // at most five; *stretched*: longer than their rest length (the others compressed).
  std::string summary(const MassSpringSystem& system) const {
    if (!(total > 0)) return "";
    std::vector<std::size_t> order(by_muscle.size());
    for (std::size_t m = 0; m < order.size(); ++m) order[m] = m;
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return by_muscle[a] > by_muscle[b]; });
    std::string out;
    double covered = 0;
    for (std::size_t k = 0; k < order.size() && k < 5 && covered < 0.8 * total; ++k) {
      const double share = by_muscle[order[k]] / total;
      covered += by_muscle[order[k]];
      char part[96];
      std::snprintf(part, sizeof part, "%s%s %.0f %%", out.empty() ? "" : ", ", system.muscle_name[order[k]].c_str(),
                    100.0 * share);
      out += part;
    }
    char tail[112];
    std::snprintf(tail, sizeof tail, "; tendons %.0f %%, across the fibres %.0f %%, stretched %.0f %%",
                  100.0 * tendons / total, 100.0 * across / total, 100.0 * stretched / total);
    return out + tail;
  }
};

// Issue 29's window: within this many received poses of the hold, the model's volume and residual must be back.
constexpr int kHeldPosesJudged = 30;

// The stream's own setup, with the skinned surfaces' metrics available on request: the surfaces as the particles carry
// them, neither moved out of the bones nor projected to their rest volume, so their volume is the model's.
Setup measuringModelVolume(Setup setup) {
  setup.pipeline.skin_surfaces = true;
  setup.pipeline.measure_fidelity = true;
  setup.pipeline.keep_surfaces_out_of_bones = false;
  setup.pipeline.surface_volume.keep_volume = false;
  return setup;
}

// The frames' strain p99: the upper median and the largest (NaN when no frame was solved).
struct StrainFigures {
  double p99_median = std::nan(""), p99_max = std::nan("");
};

StrainFigures strainFiguresOf(std::vector<double> strain_p99) {
  StrainFigures figures;
  if (strain_p99.empty()) return figures;
  std::sort(strain_p99.begin(), strain_p99.end());
  figures.p99_median = strain_p99[strain_p99.size() / 2];
  figures.p99_max = strain_p99.back();
  return figures;
}

// The motion's own strain, without the stream's lag: the same poses played as a stream whose every frame runs until it
// meets the node's residual criterion (at most kReferenceSweeps sweeps), so each frame's answer is the converged one
// of the stream's well-posed problem (the tissue carrying its own previous frame). Strain p99 over the frames after the
// first, as the streamed figures; `converged_frames` says how many met the criterion within the cap.
constexpr int kReferenceSweeps = 150;

struct ConvergedStrain : StrainFigures {
  int frames = 0, converged_frames = 0;
  double last_p99 = std::nan("");  // the last pose's, the one a hold holds: what a held stream should come back to
};

ConvergedStrain convergedStrain(const BundledScene& bundled, const Setup& setup, const std::vector<Pose>& motion) {
  Setup converged = setup;
  const double tolerance = setup.stream.stopping.sweeps.residual_tolerance;
  converged.stream.stopping = FrameStopping::of(StoppingSettings::atResidual(tolerance, kReferenceSweeps));
  converged.stream.stopping.cold_start_iterations = setup.stream.stopping.cold_start_iterations;
  Stream stream(bundled.scene, converged);
  std::vector<double> strain_p99;
  ConvergedStrain result;
  for (std::size_t k = 0; k < motion.size(); ++k) {
    const FrameResult* frame = stream.offer(motion[k]);
    if (!frame || k == 0) continue;
    strain_p99.push_back(frame->stats.solver.strain_p99);
    result.last_p99 = frame->stats.solver.strain_p99;
    ++result.frames;
    if (frame->stats.solver.converged) ++result.converged_frames;
  }
  static_cast<StrainFigures&>(result) = strainFiguresOf(std::move(strain_p99));
  return result;
}

MotionFigures motionCase(Report& report, bench::JsonRecords& records, const BundledScene& bundled, const Setup& setup,
                         const std::string& name, const std::string& description, const std::vector<Pose>& motion,
                         int held_poses) {
  Stream stream(bundled.scene, measuringModelVolume(setup));
  const DeformationPipeline& simulation = stream.pipeline();
  const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
  Outcome outcome;
  MotionFigures figures;
  const FrameWants model_volume{false, true};
  const auto takeAfterHold = [&](const FrameResult* frame, int held) {
    if (!frame) return;
    figures.after_hold_poses = held;
    figures.after_hold_strain_p99 = frame->stats.solver.strain_p99;
    figures.after_hold_volume_error_max_pct = frame->has_metrics ? frame->metrics.volume_error_max_pct : std::nan("");
  };
  const auto take = [&](const FrameResult* frame) {
    if (!frame) return;
    accumulate(outcome, simulation, frame->stats);
    figures.max_strain = std::max(figures.max_strain, frame->stats.solver.max_strain);
    figures.volume_error_max_pct =
        std::max(figures.volume_error_max_pct, maxVolumeErrorPct(tetrahedra, simulation.state().position));
    figures.residual_last = frame->stats.solver.residual;
    figures.settled_converged = frame->stats.solver.converged;
    figures.catch_up_sweeps += frame->stats.catch_up_sweeps;
  };
  std::vector<double> strain_p99, frame_ms, residuals;
  StrainOwners owners;
  for (std::size_t k = 0; k < motion.size(); ++k) {
    const bool last = k + 1 == motion.size();
    const FrameResult* frame = stream.offer(motion[k], last ? model_volume : FrameWants{});
    take(frame);
    if (last) takeAfterHold(frame, 0);
    if (frame && k > 0) {
      strain_p99.push_back(frame->stats.solver.strain_p99);
      owners.add(simulation.system(), simulation.state().position, frame->stats.solver.strain_p99);
      frame_ms.push_back(frame->stats.solve_ms);
      if (std::isfinite(frame->stats.solver.residual)) residuals.push_back(frame->stats.solver.residual);
    }
  }
  figures.frame_ms_median = frame_ms.empty() ? std::nan("") : bench::median(frame_ms);
  if (!residuals.empty()) {
    figures.residual_motion_max = *std::max_element(residuals.begin(), residuals.end());
    figures.residual_motion_median = bench::median(std::move(residuals));
  }
  const StrainFigures strain = strainFiguresOf(std::move(strain_p99));
  figures.strain_p99_median = strain.p99_median;
  figures.strain_p99_max = strain.p99_max;
  // The motion stops: the last pose held; each held pose refines an unfinished frame.
  for (int held = 1; held <= held_poses; ++held) {
    const bool judged = held <= kHeldPosesJudged;
    const FrameResult* frame = stream.offer(motion.back(), judged ? model_volume : FrameWants{});
    take(frame);
    if (judged) takeAfterHold(frame, held);
    if (!stream.wantsRefinement()) {
      figures.held_until_settled = held;
      break;
    }
  }
  figures.restarts = stream.counters().resets;
  reportStream(report, name, stream);
  const ConvergedStrain converged = convergedStrain(bundled, setup, motion);
  records.begin();
  records.add("case", name);
  records.add("description", description);
  records.add("motion_frames", static_cast<double>(motion.size()));
  records.add("particles", static_cast<double>(simulation.system().particleCount()));
  records.add("finite", outcome.finite ? 1.0 : 0.0);
  records.add("recoveries", outcome.recoveries);
  records.add("restarts", static_cast<double>(figures.restarts));
  records.add("iterations", outcome.iterations);
  records.add("wall_ms", outcome.wall_ms);
  records.add("frame_ms_median", figures.frame_ms_median);
  records.add("catch_up_sweeps", figures.catch_up_sweeps);
  records.add("strain_p99_median", figures.strain_p99_median);
  records.add("strain_p99_max", figures.strain_p99_max);
  const std::string strain_owners = owners.summary(simulation.system());
  if (!strain_owners.empty()) records.add("strain_p99_owners", strain_owners);
  records.add("max_strain", figures.max_strain);
  records.addMeasured("converged_strain_p99_median", converged.p99_median);
  records.addMeasured("converged_strain_p99_max", converged.p99_max);
  records.add("converged_frames", converged.converged_frames);
  records.add("reference_frames", converged.frames);
  records.add("max_particle_inside_bone_mm", outcome.max_particle_depth_m * 1e3);
  records.add("deepest_particle", outcome.deepest_particle);
  records.add("particle_volume_error_max_pct", figures.volume_error_max_pct);
  if (figures.held_until_settled >= 0) records.add("held_poses_until_settled", figures.held_until_settled);
  records.add("settled_converged", figures.settled_converged ? 1.0 : 0.0);
  if (figures.residual_last >= 0) records.add("residual_last", figures.residual_last);
  records.addMeasured("residual_motion_median", figures.residual_motion_median);
  records.addMeasured("residual_motion_max", figures.residual_motion_max);
  records.add("residual_tolerance", setup.stream.stopping.sweeps.residual_tolerance);
  records.add("after_hold_poses", figures.after_hold_poses);
  records.addMeasured("after_hold_volume_error_max_pct", figures.after_hold_volume_error_max_pct);
  records.addMeasured("after_hold_strain_p99", figures.after_hold_strain_p99);
  records.addMeasured("converged_last_strain_p99", converged.last_p99);
  outcome.folding.record(records);
  records.end();
  std::printf("[%6.1f s] %-22s after the hold (held pose %d, within %d): model volume error max %.3f %%, strain p99 "
              "%.3f (the held pose converged: %.3f)\n",
              report.elapsedSeconds(), name.c_str(), figures.after_hold_poses, kHeldPosesJudged,
              figures.after_hold_volume_error_max_pct, figures.after_hold_strain_p99, converged.last_p99);
  std::printf("[%6.1f s] %-22s springs at or above each frame's strain p99: %s\n", report.elapsedSeconds(), name.c_str(),
              strain_owners.c_str());
  std::printf("[%6.1f s] %-22s frame %.1f ms median, %d catch-up sweeps; converged frame by frame (%d of %d met the "
              "criterion): strain p99 median %.3f max %.3f\n",
              report.elapsedSeconds(), name.c_str(), figures.frame_ms_median, figures.catch_up_sweeps,
              converged.converged_frames, converged.frames, converged.p99_median, converged.p99_max);
  std::printf("[%6.1f s] %-22s %s, restarts %u, strain p99 median %.3f max %.3f, max strain %.1f, particles in bone "
              "%.2f mm (%s), particle-volume error max %.2f %%, settled after %d held poses (%s, residual %.3g)\n",
              report.elapsedSeconds(), name.c_str(), outcome.finite ? "finite" : "NOT FINITE", figures.restarts,
              figures.strain_p99_median, figures.strain_p99_max, figures.max_strain, outcome.max_particle_depth_m * 1e3,
              outcome.deepest_particle.empty() ? "none" : outcome.deepest_particle.c_str(),
              figures.volume_error_max_pct, figures.held_until_settled,
              figures.held_until_settled < 0 ? "still refining when the hold ended"
              : figures.settled_converged   ? "converged"
                                            : "residual no longer falling",
              figures.residual_last);
  std::fflush(stdout);
  return figures;
}

// Joint values eased from `from` to `to` over `frames` frames (smoothstep), the first frame at `from`.
std::vector<Pose> ramp(const BundledScene& bundled, const JointValues& from, const JointValues& to, int frames) {
  std::vector<Pose> poses;
  for (int k = 0; k <= frames; ++k) {
    const double t = static_cast<double>(k) / frames, eased = t * t * (3 - 2 * t);
    JointValues joints;
    for (const auto& [joint, start] : from) joints[joint] = start + eased * (to.at(joint) - start);
    poses.push_back(poseFor(bundled, joints));
  }
  return poses;
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  bench::JsonRecords records;
  Report report(records);
  constexpr double kDegree = 3.14159265358979323846 / 180.0;

  const CoreSettings node = bench::loadNodeDefaults();  // config/muscle_deformation.yaml
  const SimulationSettings settings = node.pipeline.simulation;
  const BundledScene thigh = loadBundledScene(MD_PACKAGE_DIR, {"thigh13"});
  std::printf("[%6.1f s] loaded thigh13\n", report.elapsedSeconds());
  const Pose walking = jointPose(thigh, 0.5, 1.0);

  const Setup setup = setupOf(node, settings);
  const FrameStopping& stopping = setup.stream.stopping;

  poseCase(report, thigh, "pose_jump_90", "rest to hip flexion 90 deg in one frame, forced warm", setup,
           jointPose(thigh, 90 * kDegree, 0), After::warm);
  poseCase(report, thigh, "pose_jump_90_stream",
           "rest to hip flexion 90 deg one frame (1/60 s) later, started as the node's stream decides", setup,
           jointPose(thigh, 90 * kDegree, 0), After::stream);
  poseCase(report, thigh, "gait_extreme", "hip flexion 110 deg, knee flexion 130 deg, cold", setup,
           jointPose(thigh, 110 * kDegree, 130 * kDegree), After::cold);

  double auto_step_s = 0;
  {
    const std::unique_ptr<DeformationPipeline> probe = pipelineOf(thigh.scene, setup);
    auto_step_s = VerletSolver(probe->system(), settings.verlet).timeStep();
  }
  SimulationSettings long_step = settings;
  long_step.verlet.dt_s = 10 * auto_step_s / 0.9;  // the automatic step is 0.9 of the largest stable one
  poseCase(report, thigh, "dt_x10", "dt 10 x the largest stable step, hip 0.5 rad knee 1.0 rad, cold",
           setupOf(node, long_step), walking, After::cold);
  SimulationSettings stiff = settings;
  stiff.model.spring_material_n *= 1000;
  stiff.verlet.dt_s = auto_step_s;
  poseCase(report, thigh, "stiffness_x1000", "springs 1000 x stiffer, the previous automatic step, cold",
           setupOf(node, stiff), walking, After::cold);

  // Interpenetration: the segmented muscles overlap each other and the substituted hip bone at rest; the model must
  // keep the rest pose still and solve a pose without a blow-up.
  {
    const std::unique_ptr<DeformationPipeline> pipeline = pipelineOf(thigh.scene, setup);
    const DeformationPipeline& simulation = *pipeline;
    const RestOverlapSummary& overlaps = simulation.restOverlaps();
    std::printf("[%6.1f s] thigh13 rest overlaps: %d muscle-muscle, %d muscle-bone sphere pairs cleared\n",
                report.elapsedSeconds(), overlaps.muscle_muscle_pairs, overlaps.muscle_bone_pairs);
    const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
    Outcome outcome;
    accumulate(outcome, simulation,
               pipeline->solve(boneTransformsOf(simulation.bones(), jointPose(thigh, 0, 0)), StartMode::cold, stopping,
                               false, false)
                   .stats);
    const double rest_rms_mm = bench::rmsMillimetres(simulation.state().position, simulation.system().rest_position);
    report.add("interpenetrated_rest", "segmented overlaps at rest, rest pose solved", outcome, rest_rms_mm,
               maxVolumeErrorPct(tetrahedra, simulation.state().position), simulation.system());
  }

  // Tunnelling: femur and tibia swung 0.2 rad per frame (about 8 cm at the knee, many particle radii), warm: the
  // node's stream takes these poses 1/60 s apart as a smooth motion (no bone beyond its speed limits).
  {
    Stream stream(thigh.scene, setup);
    const DeformationPipeline& simulation = stream.pipeline();
    const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
    Outcome outcome;
    stream.offer(jointPose(thigh, 0, 0));
    Pose pose;
    for (int frame = 1; frame <= 5; ++frame) {
      pose = jointPose(thigh, 0.2 * frame, 0.2 * frame);
      if (const FrameResult* solved = stream.offer(pose)) accumulate(outcome, simulation, solved->stats);
    }
    reportStream(report, "fast_bones", stream);
    report.add("fast_bones", "hip and knee 0.2 rad per warm frame to 1 rad (bone faster than a radius per frame)",
               outcome, bench::rmsMillimetres(simulation.state().position, pretransformOf(simulation, pose)),
               maxVolumeErrorPct(tetrahedra, simulation.state().position), simulation.system());
  }

  // The 2019 PBD thesis' scenario: the femur flexes 1 rad forward and back over 200 frames, warm every frame (the
  // node's stream, poses 1/60 s apart); how far does the gluteus maximus end from its starting shape, and how deep do
  // particles sink into bone on the way.
  {
    const BundledScene with_gluteus = loadBundledScene(MD_PACKAGE_DIR, {"thigh13", "gluteus_maximus"});
    Stream stream(with_gluteus.scene, setup);
    const DeformationPipeline& simulation = stream.pipeline();
    const MassSpringSystem& system = simulation.system();
    int gluteus = -1;
    for (int m = 0; m < system.muscleCount(); ++m)
      if (system.muscle_name[m] == "gluteus_maximus") gluteus = m;
    const Eigen::Index begin = system.muscle_begin[gluteus], count = system.muscle_begin[gluteus + 1] - begin;
    const int frames = options.quick ? 40 : 200;
    stream.offer(jointPose(with_gluteus, 0, 0));
    const Eigen::Matrix3Xd start = simulation.state().position.middleCols(begin, count);
    Outcome outcome;
    double peak_rms_mm = 0;
    for (int frame = 1; frame <= frames; ++frame) {
      const double hip_rad = 1.0 - std::abs(1.0 - 2.0 * frame / frames);  // 0 -> 1 rad -> 0
      if (const FrameResult* solved = stream.offer(jointPose(with_gluteus, hip_rad, 0)))
        accumulate(outcome, simulation, solved->stats);
      peak_rms_mm = std::max(peak_rms_mm, bench::rmsMillimetres(simulation.state().position.middleCols(begin, count), start));
      if (frame % 20 == 0)
        std::printf("[%6.1f s]   pbd frame %d/%d, hip %.2f rad\n", report.elapsedSeconds(), frame, frames, hip_rad);
    }
    reportStream(report, "pbd_femur_flexion", stream);
    const double end_rms_mm = bench::rmsMillimetres(simulation.state().position.middleCols(begin, count), start);
    records.begin();
    records.add("case", std::string("pbd_femur_flexion"));
    records.add("description", std::string("thigh13 + gluteus_maximus, hip_flexion_r 0 -> 1 rad -> 0 over ") +
                                   std::to_string(frames) + " warm frames, node defaults");
    records.add("frames", frames);
    records.add("particles", static_cast<double>(system.particleCount()));
    records.add("gluteus_particles", static_cast<double>(count));
    records.add("median_sphere_radius_mm", system.medianCollisionRadius() * 1e3);
    records.add("gluteus_end_rms_to_start_mm", end_rms_mm);
    records.add("gluteus_peak_rms_to_start_mm", peak_rms_mm);
    outcome.folding.record(records);
    records.add("max_penetration_sphere_bone_mm", outcome.max_penetration_bone_m * 1e3);
    records.add("max_penetration_sphere_muscle_mm", outcome.max_penetration_muscle_m * 1e3);
    records.add("max_particle_inside_bone_mm", outcome.max_particle_depth_m * 1e3);
    records.add("deepest_particle", outcome.deepest_particle);
    records.add("recoveries", outcome.recoveries);
    records.add("diverged", outcome.diverged ? 1.0 : 0.0);
    records.add("finite", outcome.finite ? 1.0 : 0.0);
    records.add("iterations", outcome.iterations);
    records.add("wall_ms", outcome.wall_ms);
    records.end();
    std::printf("[%6.1f s] pbd_femur_flexion: gluteus maximus ends %.2f mm RMS from its start (peak %.2f mm), max "
                "bone penetration %.2f mm, particles in bone %.2f mm, recoveries %d, %s\n",
                report.elapsedSeconds(), end_rms_mm, peak_rms_mm, outcome.max_penetration_bone_m * 1e3,
                outcome.max_particle_depth_m * 1e3,
                outcome.recoveries, outcome.finite ? "finite" : "NOT FINITE");
  }

  // Motions beyond the gait (issue 29), each then held still for up to 2 s. The gait at its own speed is the yardstick.
  {
    const int hold = options.quick ? 30 : 120;
    std::vector<Pose> gait;
    for (std::size_t f = 0; f < thigh.gait.frames.size(); ++f) gait.push_back(gaitPose(thigh, f));
    const MotionFigures walk = motionCase(report, records, thigh, setup, "gait_1x", "the 1-cycle gait at 60 Hz",
                                          gait, hold);
    std::vector<Pose> fast;
    for (std::size_t f = 0; f < gait.size(); f += 4) fast.push_back(gait[f]);
    motionCase(report, records, thigh, setup, "gait_4x", "the 1-cycle gait played 4 x faster (every 4th pose)", fast,
               hold);
    const JointValues straight = {{"hip_flexion_r", 0.0}, {"knee_angle_r", 0.0}};
    std::vector<Pose> jump = ramp(thigh, straight, {{"hip_flexion_r", 1.2}, {"knee_angle_r", 0.0}}, 40);
    for (int k = 0; k < 30; ++k) jump.push_back(jump.back());  // held 0.5 s: the stream skips or refines these
    jump.push_back(poseFor(thigh, {{"hip_flexion_r", -0.3}, {"knee_angle_r", 0.0}}));
    motionCase(report, records, thigh, setup, "hold_then_jump",
               "hip flexion to 1.2 rad, held 0.5 s, then -0.3 rad in one frame", jump, hold);
    std::vector<Pose> kick = ramp(thigh, straight, {{"hip_flexion_r", 1.6}, {"knee_angle_r", -2.0}}, 40);
    const std::vector<Pose> swing =
        ramp(thigh, {{"hip_flexion_r", 1.6}, {"knee_angle_r", -2.0}}, {{"hip_flexion_r", -0.35}, {"knee_angle_r", 0.0}}, 15);
    kick.insert(kick.end(), swing.begin() + 1, swing.end());
    motionCase(report, records, thigh, setup, "kick",
               "hip 1.6 -> -0.35 rad and knee -2.0 -> 0 rad in 0.25 s (peak about 12 rad/s)", kick, hold);
    const std::vector<Pose> deep = ramp(
        thigh, {{"hip_flexion_r", 0.0}, {"hip_adduction_r", 0.0}, {"hip_rotation_r", 0.0}, {"knee_angle_r", 0.0}},
        {{"hip_flexion_r", 1.5}, {"hip_adduction_r", 0.3}, {"hip_rotation_r", 0.4}, {"knee_angle_r", -2.0}}, 60);
    motionCase(report, records, thigh, setup, "deep_combined_flexion",
               "hip flexion 1.5, adduction 0.3, rotation 0.4 rad with the knee at -2 rad, over 1 s", deep, hold);
    // A skeleton standing still as a recording gives it: every joint jitters by up to 10 urad (above the stream's
    // unchanged-pose threshold, so every pose is solved warm), for 5 s. The sweeps' own alternation must not build up.
    std::vector<Pose> standing;
    const std::vector<std::string> joints = {"hip_flexion_r", "hip_adduction_r", "hip_rotation_r", "knee_angle_r"};
    for (int k = 0; k < 300; ++k) {
      JointValues jittered;
      for (std::size_t j = 0; j < joints.size(); ++j)
        jittered[joints[j]] = 1e-5 * std::sin(0.7 * k + static_cast<double>(j));
      standing.push_back(poseFor(thigh, jittered));
    }
    const MotionFigures still = motionCase(report, records, thigh, setup, "standing_jitter",
                                           "standing still for 5 s, every joint jittering by up to 10 urad", standing,
                                           hold);
    std::printf("[%6.1f s] standing_jitter: residual median %.3g max %.3g over its frames\n", report.elapsedSeconds(),
                still.residual_motion_median, still.residual_motion_max);
    std::printf("[%6.1f s] the gait's median strain p99: %.3f (the yardstick of issue 29: 2 x is %.3f)\n",
                report.elapsedSeconds(), walk.strain_p99_median, 2 * walk.strain_p99_median);
  }

  return bench::finish(records, options, "stability.json");
}
