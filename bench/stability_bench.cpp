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

#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
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
  std::unique_ptr<DeformationMetrics> metrics;
};

void accumulate(Outcome& outcome, const DeformationPipeline& simulation, const FrameStats& stats) {
  outcome.recoveries += stats.solver.divergence_recoveries;
  outcome.diverged = outcome.diverged || stats.solver.diverged;
  outcome.finite = outcome.finite && stats.finite && simulation.state().position.allFinite() && statsFinite(stats);
  for (const Eigen::Matrix3Xd& fibre : fibrePolylines(simulation.system(), simulation.state().position))
    outcome.finite = outcome.finite && fibre.allFinite();
  outcome.iterations += stats.solver.iterations;
  outcome.wall_ms += stats.solver.total_ms;
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
  const FrameResult* offer(const Pose& pose) {
    const StreamStep step = session_.offer(bench::streamStamp(played_++), boneTransformsOf(session_.bones(), pose),
                                           FrameWants{});
    last_cold_ = step.cold;
    return bench::frameOf(step);
  }
  bool lastCold() const { return last_cold_; }
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

  return bench::finish(records, options, "stability.json");
}
