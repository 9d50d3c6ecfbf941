// Stability on hard cases, on the bundled scene (the 13 thigh13 muscles, 20 particles per fibre, node defaults), plus
// the 2019 PBD thesis' femur flexion scenario on our data. Writes out/bench/stability.json: one object per case.
//
//   stability_bench [--out DIR] [--quick]
#include "bench_util.hpp"
#include "convergence_run.hpp"
#include "gait_stream.hpp"
#include "node_defaults.hpp"

#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/pipeline/simulation.hpp"
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

Eigen::Matrix3Xd pretransformOf(const MuscleSimulation& simulation, const Pose& pose) {
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

void accumulate(Outcome& outcome, const MuscleSimulation& simulation, const FrameStats& stats) {
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

// One pose solved on a fresh thigh13 simulation, starting as `start` after an optional rest frame.
// How the posed frame starts after the rest frame: warm whatever the jump, or as the node's stream decides (cold at a
// discontinuity: a bone faster than its limits between two frames 1/60 s apart).
enum class After { cold, warm, stream };

void poseCase(Report& report, const BundledScene& bundled, const std::string& name, const std::string& description,
              const SimulationSettings& settings, const Pose& pose, After after,
              const PoseStreamSettings& stream_settings = {}) {
  MuscleSimulation simulation(bundled.scene.muscles, bundled.scene.bones, settings);
  const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
  StartMode start = after == After::cold ? StartMode::cold : StartMode::warm;
  if (after != After::cold) {
    const BoneTransforms rest = boneTransformsOf(simulation.bones(), jointPose(bundled, 0, 0));
    simulation.solve(rest, StartMode::warm);
    if (after == After::stream) {
      bench::GaitStream stream(simulation.bones(), stream_settings);
      stream.solved(0, rest);
      start = stream.start(1, boneTransformsOf(simulation.bones(), pose));
      std::printf("[%6.1f s] %s: the stream starts the posed frame %s\n", report.elapsedSeconds(), name.c_str(),
                  start == StartMode::cold ? "cold" : "warm");
    }
  }
  Outcome outcome;
  accumulate(outcome, simulation, simulation.solve(pose, start));
  report.add(name, description, outcome, bench::rmsMillimetres(simulation.state().position, pretransformOf(simulation, pose)),
             maxVolumeErrorPct(tetrahedra, simulation.state().position), simulation.system());
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  bench::JsonRecords records;
  Report report(records);
  constexpr double kDegree = 3.14159265358979323846 / 180.0;

  const bench::NodeDefaults node = bench::loadNodeDefaults();  // config/muscle_deformation.yaml
  const SimulationSettings settings = node.simulation;
  const BundledScene thigh = loadBundledScene(MD_PACKAGE_DIR, {"thigh13"});
  std::printf("[%6.1f s] loaded thigh13\n", report.elapsedSeconds());
  const Pose walking = jointPose(thigh, 0.5, 1.0);

  poseCase(report, thigh, "pose_jump_90", "rest to hip flexion 90 deg in one frame, forced warm", settings,
           jointPose(thigh, 90 * kDegree, 0), After::warm);
  poseCase(report, thigh, "pose_jump_90_stream",
           "rest to hip flexion 90 deg one frame (1/60 s) later, started as the node's stream decides", settings,
           jointPose(thigh, 90 * kDegree, 0), After::stream, node.stream);
  poseCase(report, thigh, "gait_extreme", "hip flexion 110 deg, knee flexion 130 deg, cold", settings,
           jointPose(thigh, 110 * kDegree, 130 * kDegree), After::cold);

  double auto_step_s = 0;
  {
    MuscleSimulation probe(thigh.scene.muscles, thigh.scene.bones, settings);
    auto_step_s = VerletSolver(probe.system(), settings.verlet).timeStep();
  }
  SimulationSettings long_step = settings;
  long_step.verlet.dt_s = 10 * auto_step_s / 0.9;  // the automatic step is 0.9 of the largest stable one
  poseCase(report, thigh, "dt_x10", "dt 10 x the largest stable step, hip 0.5 rad knee 1.0 rad, cold", long_step,
           walking, After::cold);
  SimulationSettings stiff = settings;
  stiff.model.spring_material_n *= 1000;
  stiff.verlet.dt_s = auto_step_s;
  poseCase(report, thigh, "stiffness_x1000", "springs 1000 x stiffer, the previous automatic step, cold", stiff, walking,
           After::cold);

  // Interpenetration: the segmented muscles overlap each other and the substituted hip bone at rest; the model must
  // keep the rest pose still and solve a pose without a blow-up.
  {
    MuscleSimulation simulation(thigh.scene.muscles, thigh.scene.bones, settings);
    const RestOverlapSummary& overlaps = simulation.restOverlaps();
    std::printf("[%6.1f s] thigh13 rest overlaps: %d muscle-muscle, %d muscle-bone sphere pairs cleared\n",
                report.elapsedSeconds(), overlaps.muscle_muscle_pairs, overlaps.muscle_bone_pairs);
    const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
    Outcome outcome;
    accumulate(outcome, simulation, simulation.solve(jointPose(thigh, 0, 0), StartMode::cold));
    const double rest_rms_mm = bench::rmsMillimetres(simulation.state().position, simulation.system().rest_position);
    report.add("interpenetrated_rest", "segmented overlaps at rest, rest pose solved", outcome, rest_rms_mm,
               maxVolumeErrorPct(tetrahedra, simulation.state().position), simulation.system());
  }

  // Tunnelling: femur and tibia swung 0.2 rad per frame (about 8 cm at the knee, many particle radii), warm.
  {
    MuscleSimulation simulation(thigh.scene.muscles, thigh.scene.bones, settings);
    const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(simulation.system());
    Outcome outcome;
    simulation.solve(jointPose(thigh, 0, 0), StartMode::warm);
    Pose pose;
    for (int frame = 1; frame <= 5; ++frame) {
      pose = jointPose(thigh, 0.2 * frame, 0.2 * frame);
      accumulate(outcome, simulation, simulation.solve(pose, StartMode::warm));
    }
    report.add("fast_bones", "hip and knee 0.2 rad per warm frame to 1 rad (bone faster than a radius per frame)",
               outcome, bench::rmsMillimetres(simulation.state().position, pretransformOf(simulation, pose)),
               maxVolumeErrorPct(tetrahedra, simulation.state().position), simulation.system());
  }

  // The 2019 PBD thesis' scenario: the femur flexes 1 rad forward and back over 200 frames, warm every frame; how far
  // does the gluteus maximus end from its starting shape, and how deep do particles sink into bone on the way.
  {
    const BundledScene with_gluteus = loadBundledScene(MD_PACKAGE_DIR, {"thigh13", "gluteus_maximus"});
    MuscleSimulation simulation(with_gluteus.scene.muscles, with_gluteus.scene.bones, settings);
    const MassSpringSystem& system = simulation.system();
    int gluteus = -1;
    for (int m = 0; m < system.muscleCount(); ++m)
      if (system.muscle_name[m] == "gluteus_maximus") gluteus = m;
    const Eigen::Index begin = system.muscle_begin[gluteus], count = system.muscle_begin[gluteus + 1] - begin;
    const int frames = options.quick ? 40 : 200;
    simulation.solve(jointPose(with_gluteus, 0, 0), StartMode::warm);
    const Eigen::Matrix3Xd start = simulation.state().position.middleCols(begin, count);
    Outcome outcome;
    double peak_rms_mm = 0;
    for (int frame = 1; frame <= frames; ++frame) {
      const double hip_rad = 1.0 - std::abs(1.0 - 2.0 * frame / frames);  // 0 -> 1 rad -> 0
      accumulate(outcome, simulation, simulation.solve(jointPose(with_gluteus, hip_rad, 0), StartMode::warm));
      peak_rms_mm = std::max(peak_rms_mm, bench::rmsMillimetres(simulation.state().position.middleCols(begin, count), start));
      if (frame % 20 == 0)
        std::printf("[%6.1f s]   pbd frame %d/%d, hip %.2f rad\n", report.elapsedSeconds(), frame, frames, hip_rad);
    }
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

  const std::string path = options.out_dir + "/stability.json";
  if (!records.write(path)) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    return 1;
  }
  std::printf("wrote %s\n", path.c_str());
  return 0;
}
