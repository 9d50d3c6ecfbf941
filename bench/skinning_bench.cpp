// Surface skinning: per-muscle update and precompute time of each method at 2k, 5k and 20k surface vertices, and the
// fidelity of each method (volume error, surface inside bones) on the synthetic thigh after a bending pose.
#include "bench_util.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"

#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <cstdio>
#include <filesystem>

using namespace muscle_deformation;

namespace {

struct Variant {
  std::string label;
  SkinningSettings settings;
};

std::vector<Variant> variants() {
  std::vector<Variant> out;
  for (SkinningMethod method : {SkinningMethod::nearest_average, SkinningMethod::mean_value, SkinningMethod::embedded}) {
    SkinningSettings settings;
    settings.method = method;
    out.push_back({toString(method), settings});
  }
  // "mean_value" above uses the default cage (convex hull); the alternative cage for comparison:
  SkinningSettings tube;
  tube.method = SkinningMethod::mean_value;
  tube.cage = CageKind::fibre_tube;
  out.push_back({"mean_value_fibre_tube", tube});
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  bench::JsonRecords records;

  // --- Timing: one spindle muscle (8 x 8 fibres x 20 particles) whose surface has ~2k, 5k, 20k vertices.
  struct Resolution {
    int segments, rings;  // vertices = (rings + 1) * segments + 2
  };
  const Resolution resolutions[] = {{40, 49}, {64, 77}, {100, 199}};
  const int update_runs = options.quick ? 5 : 41;
  const int precompute_runs = options.quick ? 1 : 3;
  std::printf("%-24s %9s %12s %15s %10s %14s\n", "method", "vertices", "update ms", "precompute ms", "nnz", "max sum|w|");
  for (const Resolution& resolution : resolutions) {
    const Muscle muscle = makeSpindleMuscle("spindle", {0, 0, 0}, {0.01, 0.0, 0.25}, 0.025, 0.8, 8, 50,
                                            resolution.segments, resolution.rings);
    const MassSpringSystem system = buildMassSpringSystem({muscle}, {}, ModelSettings{});
    // Particles moved off rest (a bend and a squeeze), so the update reads realistic data.
    Eigen::Matrix3Xd moved = system.rest_position;
    for (Eigen::Index i = 0; i < moved.cols(); ++i) {
      const double t = moved(2, i) / 0.25;
      moved(0, i) += 0.03 * t * t;
      moved(1, i) *= 1.0 + 0.1 * t;
    }
    const BoneTransforms no_bones;
    for (const Variant& variant : variants()) {
      std::vector<double> precompute_ms, update_ms;
      std::unique_ptr<MuscleSkin> skin;
      for (int r = 0; r < precompute_runs; ++r)
        precompute_ms.push_back(bench::millisecondsOf([&] {
          skin = std::make_unique<MuscleSkin>(system, 0, muscle.surface, variant.settings);
        }));
      Vertices surface;
      skin->update(moved, no_bones, surface);  // sizes the output once; the timed updates allocate nothing
      for (int r = 0; r < update_runs; ++r)
        update_ms.push_back(bench::millisecondsOf([&] { skin->update(moved, no_bones, surface); }));
      const double update = bench::median(update_ms), precompute = bench::median(precompute_ms);
      std::printf("%-24s %9ld %12.3f %15.1f %10ld %14.2f\n", variant.label.c_str(), static_cast<long>(skin->vertexCount()),
                  update, precompute, static_cast<long>(skin->weights().nonZeros()), skin->diagnostics().max_abs_weight_sum);
      records.begin();
      records.add("measurement", "timing");
      records.add("method", variant.label);
      records.add("surface_vertices", static_cast<double>(skin->vertexCount()));
      records.add("particles", static_cast<double>(system.particleCount()));
      records.add("update_ms", update);
      records.add("precompute_ms", precompute);
      records.add("weights_nonzero", static_cast<double>(skin->weights().nonZeros()));
      records.add("max_abs_weight_sum", skin->diagnostics().max_abs_weight_sum);
      records.add("update_repetitions", update_runs);
      records.end();
    }
  }

  // --- Fidelity on the synthetic thigh after a bending pose: cold start, then the MSS alone (no collision stage yet).
  const SyntheticScene scene = makeSyntheticThigh(13, 8);
  // The full pipeline, collision included: cold start (rigid pre-transform), then the solve.
  SimulationSettings simulation_settings;  // the Verlet solver
  simulation_settings.model.particles_per_fibre = 20;
  DeformationPipeline simulation(describedByName(scene.muscles), scene.muscles, scene.bones,
                                 bench::particlesOnly(simulation_settings));
  const MassSpringSystem& system = simulation.system();
  const Pose pose = syntheticThighPose(0.6, 0.9);
  const BoneTransforms transforms = boneTransformsOf(scene.bones, pose);
  const FrameStats frame =
      simulation
          .solve(transforms, StartMode::cold, FrameStopping::of(StoppingSettings::atDisplacement(1e-6, 2000)), false,
                 false)
          .stats;
  SolveStats stats = frame.solver;  // the solve behind the surfaces being recorded
  const ParticleState& state = simulation.state();
  std::printf("\nscene: %ld particles, solve %d iterations (%s), %.0f ms, with sphere collision (%d contacts left)\n",
              static_cast<long>(system.particleCount()), stats.iterations, stats.stopping_rule_met ? "converged" : "cap",
              stats.total_ms, frame.collision.contacts);
  const DeformationMetrics metrics(scene.bones, scene.muscles, system);
  std::printf("%-24s %14s %14s %12s %10s %16s\n", "method", "vol err mean%", "vol err max%", "inside mm", "inside", "fibre change %");

  std::string scene_label = "synthetic thigh", pose_label = "hip 0.6 rad, knee 0.9 rad";
  auto record = [&](const std::string& label, const SceneMetrics& result) {
    double fibre_min = 0, fibre_max = 0;
    for (const MuscleMetrics& muscle : result.muscles) {
      fibre_min = std::min(fibre_min, muscle.fibre_length_change_min_pct);
      fibre_max = std::max(fibre_max, muscle.fibre_length_change_max_pct);
    }
    std::printf("%-24s %14.3f %14.3f %12.3f %10d %7.1f..%6.1f\n", label.c_str(), result.volume_error_mean_pct,
                result.volume_error_max_pct, result.max_inside_bone_depth_m * 1000, result.vertices_inside_bone, fibre_min,
                fibre_max);
    records.begin();
    records.add("measurement", "scene");
    records.add("method", label);
    records.add("scene", scene_label);
    records.add("pose", pose_label);
    records.add("volume_error_mean_pct", result.volume_error_mean_pct);
    records.add("volume_error_max_pct", result.volume_error_max_pct);
    records.add("max_inside_bone_depth_mm", result.max_inside_bone_depth_m * 1000);
    records.add("vertices_inside_bone", result.vertices_inside_bone);
    records.add("fibre_length_change_min_pct", fibre_min);
    records.add("fibre_length_change_max_pct", fibre_max);
    records.add("solver_iterations", stats.iterations);
    records.add("metrics_ms", result.compute_ms);
    records.end();
  };

  // Reference: the undeformed surfaces in the rest pose (what the bones touch before anything moves).
  std::vector<Vertices> rest_surfaces;
  for (const Muscle& muscle : scene.muscles) rest_surfaces.push_back(muscle.surface.vertices);
  record("rest_pose_reference", metrics.measure(rest_surfaces, system.rest_position, BoneTransforms(scene.bones.size(), Eigen::Isometry3d::Identity())));
  for (const Variant& variant : variants()) {
    const SurfaceSkinning skinning(system, scene.muscles, variant.settings);
    std::vector<Vertices> surfaces;
    skinning.update(state.position, transforms, surfaces);
    record(variant.label, metrics.measure(surfaces, state.position, transforms));
  }

  // The bundled real scene (all 26 muscles): real muscles are curved and tightly packed, which the synthetic spindles
  // are not, so the choice of default is checked here too.
  {
    const std::string package = MD_PACKAGE_DIR;
    const SceneDescription description = loadSceneDescription(package + "/config/scenes/right_hip_thigh.yaml");
    const UriResolver resolve = makeUriResolver({{"muscle_deformation", package}}, package);
    const Skeleton skeleton = Skeleton::fromUrdfFile(resolveScenePath(description, description.urdf_file, resolve));
    const Scene bundled = loadScene(description, skeleton, resolve);
    const SimulationSettings bundled_settings;  // the Verlet solver, 200 iterations below
    DeformationPipeline bundled_simulation(bundled.muscle_descriptions, bundled.muscles, bundled.bones,
                                           bench::particlesOnly(bundled_settings));
    const Pose bundled_pose = poseFromLinkPoses(bundled, skeleton.linkPoses({{"hip_flexion_r", 0.5}, {"knee_angle_r", -1.0}}));
    const BoneTransforms bundled_transforms = boneTransformsOf(bundled.bones, bundled_pose);
    const FrameStats bundled_frame =
        bundled_simulation
            .solve(bundled_transforms, StartMode::cold, FrameStopping::of(StoppingSettings::afterIterations(200)), false,
                   false)
            .stats;
    const DeformationMetrics bundled_metrics(bundled.bones, bundled.muscles, bundled_simulation.system());
    scene_label = "bundled right_hip_thigh (26 muscles)";
    pose_label = "hip_flexion_r 0.5 rad, knee_angle_r -1.0 rad";
    std::printf("\nbundled scene: %ld particles, cold solve %d iterations, %.0f ms, with sphere collision\n",
                static_cast<long>(bundled_simulation.system().particleCount()), bundled_frame.solver.iterations,
                bundled_frame.solve_ms);
    stats = bundled_frame.solver;
    for (const Variant& variant : variants()) {
      const SurfaceSkinning skinning(bundled_simulation.system(), bundled.muscles, variant.settings);
      std::vector<Vertices> surfaces;
      skinning.update(bundled_simulation.state().position, bundled_transforms, surfaces);
      record(variant.label, bundled_metrics.measure(surfaces, bundled_simulation.state().position, bundled_transforms));
    }
  }

  return bench::finish(records, options, "skinning.json");
}
