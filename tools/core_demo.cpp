// Core-only demo: the synthetic thigh flexes at hip and knee over a sequence of frames; each frame is solved warm
// from the previous one. Prints per-frame statistics, writes them as CSV and the last frame's fibres as VTK.
#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

using namespace muscle_deformation;

int main(int argc, char** argv) {
  std::string out_dir = "out/demo";
  int frames = 30;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--out" && i + 1 < argc) {
      out_dir = argv[++i];
    } else if (arg == "--frames" && i + 1 < argc) {
      frames = std::max(2, std::atoi(argv[++i]));
    } else {
      std::cerr << "usage: " << argv[0] << " [--out DIR] [--frames N]\n";
      return 2;
    }
  }
  std::filesystem::create_directories(out_dir);

  const SyntheticScene scene = makeSyntheticThigh();
  PipelineSettings settings;  // the seeds' Verlet solver, particles only
  settings.skin_surfaces = settings.measure_fidelity = false;
  const FrameStopping stopping = FrameStopping::of(StoppingSettings::atDisplacement(1e-6, 400));
  DeformationPipeline simulation(describedByName(scene.muscles), scene.muscles, scene.bones, settings);
  const MassSpringSystem& system = simulation.system();
  std::printf("synthetic thigh: %d muscles, %ld particles, %zu springs, bone spheres", system.muscleCount(),
              static_cast<long>(system.particleCount()), system.springs.size());
  for (int count : simulation.collisionWorld()->boneSphereCounts()) std::printf(" %d", count);
  std::printf(", built in %.0f ms\n", simulation.buildReport().build_ms);

  std::ofstream csv(out_dir + "/core_stats.csv");
  csv << "frame,hip_flexion_rad,knee_flexion_rad,iterations,converged,mss_ms,collision_ms,total_ms,spring_deviation,"
         "mean_strain,contacts,max_penetration_muscle_bone_mm,max_penetration_muscle_muscle_mm\n";
  bool finite = true;
  for (int frame = 0; frame < frames; ++frame) {
    const double phase = static_cast<double>(frame) / (frames - 1);
    const double hip = 0.8 * phase, knee = 1.0 * phase;
    const FrameStats stats = simulation
                                 .solve(boneTransformsOf(simulation.bones(), syntheticThighPose(hip, knee)),
                                        StartMode::warm, stopping, false, false)
                                 .stats;
    finite = finite && stats.finite;
    const SolveStats& solve = stats.solver;
    std::printf("frame %2d hip %.2f knee %.2f: %3d iterations%s, %6.1f ms (MSS %.1f, collision %.1f), spring deviation "
                "%.4f, %d contacts, penetration bone %.2f mm muscle %.2f mm\n",
                frame, hip, knee, solve.iterations, solve.stopping_rule_met ? "" : " (cap)", solve.total_ms,
                solve.mss_ms, solve.collision_ms, solve.spring_deviation_ratio, stats.collision.contacts,
                1e3 * stats.collision.max_penetration_muscle_bone_m, 1e3 * stats.collision.max_penetration_muscle_muscle_m);
    csv << frame << ',' << hip << ',' << knee << ',' << solve.iterations << ',' << solve.stopping_rule_met << ','
        << solve.mss_ms << ',' << solve.collision_ms << ',' << solve.total_ms << ',' << solve.spring_deviation_ratio
        << ',' << solve.mean_strain << ',' << stats.collision.contacts << ','
        << 1e3 * stats.collision.max_penetration_muscle_bone_m << ','
        << 1e3 * stats.collision.max_penetration_muscle_muscle_m << '\n';
  }
  savePolylinesVtk(out_dir + "/fibres_last_frame.vtk", fibrePolylines(system, simulation.state().position));
  std::printf("wrote %s/core_stats.csv and %s/fibres_last_frame.vtk\n", out_dir.c_str(), out_dir.c_str());
  if (!finite) {
    std::fprintf(stderr, "non-finite particle positions\n");
    return 1;
  }
  return 0;
}
