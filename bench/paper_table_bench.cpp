// The GRAPP 2014 paper's Table 1 on real anatomy and on the synthetic thigh: per-iteration time of the MSS update,
// muscle-muscle collision and muscle-bone collision, and their total, at 20/40/60/80 particles per fibre, each
// beside the paper's figure. As in the paper, times are averaged over five poses (of the bundled gait): per pose,
// the median of repeated runs of iterations from a loaded state; then the mean over the poses.
//   bundled_thigh13: config/scenes/right_hip_thigh.yaml, the 13 muscles tagged thigh13 (64 fibres each), every
//                    bone of the scene as spheres from the one-ring heuristic, rest overlaps cleared as the node does.
//   synthetic:       makeSyntheticThigh (13 spindles x 64 fibres), bones carrying the paper's sphere counts, the
//                    gait's hip and knee flexion at the same five frames.
// Writes out/bench/paper_table.json: one object per scene and resolution.
#include "bench_util.hpp"
#include "iteration_split.hpp"
#include "node_defaults.hpp"
#include "paper_figures.hpp"
#include "progress.hpp"
#include "stream_play.hpp"

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"
#include "muscle_deformation/support/bundled_scene.hpp"

#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

using namespace muscle_deformation;

namespace {

// A scene measured at one resolution: the system, its collision spheres and the five poses' bone transforms.
struct MeasuredScene {
  std::string name;
  std::unique_ptr<DeformationPipeline> simulation;  // owns the system for the bundled scene (particles only)
  MassSpringSystem own_system;                   // the synthetic scene's system
  const MassSpringSystem* system = nullptr;
  std::vector<SphereSet> bone_spheres;
  std::vector<std::string> bone_names;
  std::vector<BoneTransforms> pose_transforms;
};

struct Timing {
  int repetitions, iterations_per_run, warmup_iterations;
};

// Mean over poses of the per-pose medians.
struct PoseAverage {
  bench::IterationSplit mean;
  int boundary_particles = 0;
};

PoseAverage measureOverPoses(const MeasuredScene& scene, const VerletSettings& solver_settings,
                             const CollisionSettings& collision_settings, const Timing& timing) {
  VerletSolver solver(*scene.system, solver_settings);
  CollisionWorld world(*scene.system, scene.bone_spheres, collision_settings, scene.bone_names);
  PoseAverage average;
  average.boundary_particles = world.muscleSphereCount();
  const double pose_count = static_cast<double>(scene.pose_transforms.size());
  for (const BoneTransforms& transforms : scene.pose_transforms) {
    const ParticleState start = bench::loadedState(*scene.system, solver, world, transforms, timing.warmup_iterations);
    const bench::IterationSplit split =
        bench::measureIterationSplit(solver, world, start, timing.repetitions, timing.iterations_per_run);
    bench::IterationSplit& m = average.mean;
    m.mss_ms += split.mss_ms / pose_count;
    m.muscle_cd_ms += split.muscle_cd_ms / pose_count;
    m.bone_cd_ms += split.bone_cd_ms / pose_count;
    m.response_ms += split.response_ms / pose_count;
    m.total_ms += split.total_ms / pose_count;
    m.mss_cpu_ms += split.mss_cpu_ms / pose_count;
    m.collision_cpu_ms += split.collision_cpu_ms / pose_count;
    m.total_cpu_ms += split.total_cpu_ms / pose_count;
    m.contacts += split.contacts / pose_count;
  }
  return average;
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const std::array<bench::PaperTableColumn, 4> paper = bench::paperTable1();
  const CoreSettings defaults = bench::loadNodeDefaults();
  const Timing timing = options.quick ? Timing{3, 5, 10} : Timing{21, 20, 50};

  const BundledScene bundled = loadBundledScene(MD_PACKAGE_DIR, {"thigh13"});
  const std::vector<std::size_t> frames = fiveGaitFrames(bundled);
  std::vector<BoneTransforms> bundled_poses;
  for (const std::size_t frame : frames)
    bundled_poses.push_back(boneTransformsOf(bundled.scene.bones, gaitPose(bundled, frame)));

  // The synthetic thigh bends at hip and knee only: the same frames' hip flexion and knee flexion (the bundled
  // skeleton's knee_angle_r is negative in flexion).
  const SyntheticScene synthetic = makeSyntheticThigh(13, 8);
  std::vector<BoneTransforms> synthetic_poses;
  for (const std::size_t frame : frames) {
    const JointValues& joints = bundled.gait.frames.at(frame);
    synthetic_poses.push_back(
        boneTransformsOf(synthetic.bones, syntheticThighPose(joints.at("hip_flexion_r"), -joints.at("knee_angle_r"))));
  }

  const std::vector<std::string> scene_names = {"bundled_thigh13", "synthetic"};
  double total_work = 0;  // particles per fibre summed over the configurations: run time grows with it
  for (std::size_t s = 0; s < scene_names.size(); ++s)
    for (const bench::PaperTableColumn& column : paper) total_work += column.particles_per_fibre;
  bench::Progress progress("paper_table", total_work);

  bench::JsonRecords records;
  std::printf("%-16s %4s %9s %9s %8s | %8s %8s %8s %8s | %8s %8s %8s %8s | %6s\n", "scene", "ppf", "particles",
              "springs", "boundary", "mss", "muscleCD", "boneCD", "total", "p_mss", "p_mCD", "p_bCD", "p_total",
              "ratio");
  for (const std::string& scene_name : scene_names) {
    for (const bench::PaperTableColumn& column : paper) {
      MeasuredScene scene;
      scene.name = scene_name;
      PipelineSettings pipeline_settings = bench::particlesOnly(defaults.pipeline);
      SimulationSettings& settings = pipeline_settings.simulation;
      settings.model.particles_per_fibre = column.particles_per_fibre;
      double build_ms = 0;
      if (scene_name == "bundled_thigh13") {
        build_ms = bench::millisecondsOf([&] {
          scene.simulation = std::make_unique<DeformationPipeline>(
              bundled.scene.muscle_descriptions, bundled.scene.muscles, bundled.scene.bones, pipeline_settings);
        });
        scene.system = &scene.simulation->system();
        const CollisionWorld& built = *scene.simulation->collisionWorld();
        for (std::size_t b = 0; b < bundled.scene.bones.size(); ++b) {
          scene.bone_spheres.push_back(built.boneSpheresRest(static_cast<int>(b)));
          scene.bone_names.push_back(bundled.scene.bones[b].name);
        }
        scene.pose_transforms = bundled_poses;
      } else {
        build_ms = bench::millisecondsOf([&] {
          scene.own_system = buildMassSpringSystem(synthetic.muscles, synthetic.bones, settings.model);
        });
        scene.system = &scene.own_system;
        scene.bone_spheres = bench::paperCountBoneSpheres(synthetic.bones);
        for (const Bone& bone : synthetic.bones) scene.bone_names.push_back(bone.name);
        scene.pose_transforms = synthetic_poses;
      }
      const PoseAverage result = measureOverPoses(scene, settings.verlet, settings.collision, timing);
      const bench::IterationSplit& m = result.mean;
      const double ratio = column.total_ms / m.total_ms;

      records.begin();
      records.add("scene", scene_name);
      records.add("particles_per_fibre", column.particles_per_fibre);
      records.add("mss_ms", m.mss_ms);
      records.add("muscle_cd_ms", m.muscle_cd_ms);
      records.add("bone_cd_ms", m.bone_cd_ms);
      records.add("collision_response_ms", m.response_ms);
      records.add("total_ms", m.total_ms);
      records.add("paper_mss_ms", column.mss_ms);
      records.add("paper_muscle_cd_ms", column.muscle_cd_ms);
      records.add("paper_bone_cd_ms", column.bone_cd_ms);
      records.add("paper_total_ms", column.total_ms);
      records.add("ratio", ratio);
      records.add("mss_ratio", column.mss_ms / m.mss_ms);
      records.add("muscle_cd_ratio", column.muscle_cd_ms / m.muscle_cd_ms);
      records.add("bone_cd_ratio", column.bone_cd_ms / m.bone_cd_ms);
      records.add("mss_cpu_ms", m.mss_cpu_ms);
      records.add("collision_cpu_ms", m.collision_cpu_ms);
      records.add("total_cpu_ms", m.total_cpu_ms);
      records.add("cpu_ratio", column.total_ms / m.total_cpu_ms);
      records.add("contacts_per_iteration", m.contacts);
      records.add("muscles", static_cast<double>(scene.system->muscleCount()));
      records.add("particles", static_cast<double>(scene.system->particleCount()));
      records.add("springs", static_cast<double>(scene.system->springs.size()));
      records.add("boundary_particles", result.boundary_particles);
      double bone_sphere_total = 0;
      for (std::size_t b = 0; b < scene.bone_spheres.size(); ++b) {
        records.add("bone_spheres_" + scene.bone_names[b], static_cast<double>(scene.bone_spheres[b].size()));
        bone_sphere_total += static_cast<double>(scene.bone_spheres[b].size());
      }
      records.add("bone_spheres", bone_sphere_total);
      std::string sphere_counts;  // the same per bone in one field, whatever the scene's bone names
      for (std::size_t b = 0; b < scene.bone_spheres.size(); ++b)
        sphere_counts += (b ? " " : "") + scene.bone_names[b] + ":" + std::to_string(scene.bone_spheres[b].size());
      records.add("bone_sphere_counts", sphere_counts);
      records.add("bones", static_cast<double>(scene.bone_spheres.size()));
      records.add("build_ms", build_ms);
      records.add("poses", static_cast<double>(scene.pose_transforms.size()));
      std::string frame_list;
      for (const std::size_t frame : frames) frame_list += (frame_list.empty() ? "" : " ") + std::to_string(frame);
      records.add("gait_frames", frame_list);
      records.add("warmup_iterations", timing.warmup_iterations);
      records.add("repetitions", timing.repetitions);
      records.add("iterations_per_repetition", timing.iterations_per_run);
      records.add("spring_layout", toString(settings.model.spring_layout));
      records.add("broad_phase", std::string(toString(settings.collision.broad_phase)));
      records.end();

      std::printf("%-16s %4d %9ld %9zu %8d | %8.3f %8.3f %8.3f %8.3f | %8.1f %8.1f %8.1f %8.1f | %5.0fx\n",
                  scene_name.c_str(), column.particles_per_fibre, static_cast<long>(scene.system->particleCount()),
                  scene.system->springs.size(), result.boundary_particles, m.mss_ms, m.muscle_cd_ms, m.bone_cd_ms,
                  m.total_ms, column.mss_ms, column.muscle_cd_ms, column.bone_cd_ms, column.total_ms, ratio);
      std::printf("  bone spheres: %s\n", sphere_counts.c_str());
      progress.finished(scene_name + " " + std::to_string(column.particles_per_fibre) + " particles/fibre",
                        column.particles_per_fibre);
    }
  }
  std::printf("paper_table done in %.0f s\n", progress.elapsedSeconds());
  return bench::finish(records, options, "paper_table.json");
}
