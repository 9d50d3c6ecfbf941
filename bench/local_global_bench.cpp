// Cold single-pose solve on the synthetic thigh (13 muscles x 64 fibres x 20 particles per fibre): distance to the
// converged shape against wall time for the local/global solver (quasi-static, dynamic with a few steps h, with and
// without the volume term) and for the damped Verlet solver; the muscles' volume error; the factorisation's cost.
// Writes out/bench/local_global.json.
#include "bench_util.hpp"
#include "convergence_run.hpp"

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>

using namespace muscle_deformation;

namespace {

using bench::Checkpoint;
using bench::coldSolve;
using bench::rmsMillimetres;
using Run = bench::ConvergenceRun;

// Wall time of a cold solve stopped at exactly `iterations`, without snapshots (median of `repetitions`).
double coldSolveMilliseconds(const MassSpringSystem& system, const BoneTransforms& transforms,
                             CollisionWorld* collision, int repetitions,
                             const std::function<SolveStats(ParticleState&, const AfterUpdateHook&)>& solve) {
  std::vector<double> times;
  for (int r = 0; r < repetitions; ++r) {
    ParticleState state;
    rigidPretransform(system, transforms, state);
    const AfterUpdateHook hook = [&](ParticleState& s) { return collision ? collision->resolve(s) : 0; };
    times.push_back(bench::millisecondsOf([&] { solve(state, hook); }));
  }
  return bench::median(times);
}

}  // namespace

int main(int argc, char** argv) {
  const bench::Options options = bench::parseOptions(argc, argv);
  std::filesystem::create_directories(options.out_dir);
  const SyntheticScene scene = makeSyntheticThigh(13, 8);
  ModelSettings model;
  model.particles_per_fibre = 20;
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, model);
  const BoneTransforms transforms = boneTransformsOf(scene.bones, syntheticThighPose(0.6, 0.9));
  const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(system);
  const int repetitions = options.quick ? 1 : 5;
  std::printf("synthetic thigh: %ld particles, %zu springs, %zu tetrahedra for volume measurement\n",
              static_cast<long>(system.particleCount()), system.springs.size(), tetrahedra.tetrahedra.size());

  bench::JsonRecords records;
  for (const bool collisions : {true, false}) {
    std::unique_ptr<CollisionWorld> collision;
    if (collisions) {
      collision = std::make_unique<CollisionWorld>(system, scene.bones, CollisionSettings{});
      collision->setBoneTransforms(transforms);
    }
    const char* collision_name = collisions ? "on" : "off";

    // Reference: the quasi-static local/global solver (no volume term) iterated until the mean displacement per
    // iteration is below 1e-7 m or the cap. The spring energy is very flat along some shape changes (whole bellies
    // rolling about their fibres), so a small displacement per iteration does not by itself mean converged: the
    // reference is checked by starting Verlet from it (it must stay put) and compared with Verlet run cold to its
    // own displacement rule (which stops on the flat part, far from the minimum).
    const int reference_cap = options.quick ? 2000 : 10000;
    LocalGlobalSolver lg_reference(system, LocalGlobalSettings{});
    const StoppingSettings lg_reference_stopping = StoppingSettings::atDisplacement(1e-7, reference_cap);
    const Run lg_converged = coldSolve(system, transforms, collision.get(), 1, [&](ParticleState& s, const AfterUpdateHook& h) {
      return lg_reference.solve(s, lg_reference_stopping, h);
    });
    const Eigen::Matrix3Xd& reference = lg_converged.final_position;
    VerletSolver verlet_reference(system, VerletSettings{});
    const StoppingSettings verlet_reference_stopping =
        StoppingSettings::atDisplacement(1e-7, options.quick ? 5000 : 20000);
    const Run verlet_converged = coldSolve(system, transforms, collision.get(), 1, [&](ParticleState& s, const AfterUpdateHook& h) {
      return verlet_reference.solve(s, verlet_reference_stopping, h);
    });
    ParticleState check;
    check.position = reference;
    check.previous_position = reference;
    const StoppingSettings check_stopping = StoppingSettings::afterIterations(options.quick ? 1000 : 5000);
    VerletSolver check_solver(system, VerletSettings{});
    if (collision)
      check_solver.solve(check, check_stopping, [&](ParticleState& s) { return collision->resolve(s); });
    else
      check_solver.solve(check, check_stopping);
    const double verlet_moves_reference_mm = rmsMillimetres(check.position, reference);
    const double verlet_cold_to_reference_mm = rmsMillimetres(verlet_converged.final_position, reference);
    std::printf("\ncollisions %s. reference: local/global quasi-static, %d iterations (rule met: %d, last mean "
                "displacement %.2e m); Verlet started there moves it %.3f mm RMS in %d iterations; Verlet cold, %d "
                "iterations (rule met: %d, %.2e m), ends %.3f mm RMS from it\n",
                collision_name, lg_converged.stats.iterations, lg_converged.stats.stopping_rule_met,
                lg_converged.stats.mean_displacement_m, verlet_moves_reference_mm, check_stopping.max_iterations,
                verlet_converged.stats.iterations, verlet_converged.stats.stopping_rule_met,
                verlet_converged.stats.mean_displacement_m, verlet_cold_to_reference_mm);
    records.begin();
    records.add("solver", "reference");
    records.add("collisions", collision_name);
    records.add("reference_solver", "local_global_quasi_static");
    records.add("reference_iterations", lg_converged.stats.iterations);
    records.add("reference_last_mean_displacement_m", lg_converged.stats.mean_displacement_m);
    records.add("verlet_from_reference_rms_mm", verlet_moves_reference_mm);
    records.add("verlet_cold_iterations", verlet_converged.stats.iterations);
    records.add("verlet_cold_to_reference_rms_mm", verlet_cold_to_reference_mm);
    records.end();

    struct Variant {
      std::string solver, mode;
      double time_step_s, volume_weight, chebyshev_rho;
      int cap;
    };
    std::vector<Variant> variants = {
        {"verlet", "dynamic", 0, 0, 0, options.quick ? 1000 : 3000},
        {"local_global", "quasi_static", 0, 0, 0, 200},
        {"local_global", "quasi_static", 0, 0, 0.95, 200},
        {"local_global", "dynamic", 1e-3, 0, 0, 200},
        {"local_global", "dynamic", 1e-2, 0, 0, 200},
        {"local_global", "dynamic", 1.0 / 30, 0, 0, 200},
        {"local_global", "quasi_static", 0, 1.0, 0, 200},
        {"local_global", "quasi_static", 0, 10.0, 0, 200},
    };
    std::printf("%-13s %-13s %9s %6s %5s %11s %9s %9s %9s %9s %9s %11s\n", "solver", "mode", "h_s", "vol_w", "cheb",
                "factor_ms", "iters", "wall_ms", "rms_mm", "vol_mean%", "vol_max%", "ms_to_1mm");
    for (const Variant& variant : variants) {
      std::function<SolveStats(ParticleState&, const AfterUpdateHook&)> solve;
      std::unique_ptr<VerletSolver> verlet;
      std::unique_ptr<LocalGlobalSolver> local_global;
      double factorisation_ms = 0;
      StoppingSettings stopping;
      auto makeSolver = [&](int iterations) {
        stopping = StoppingSettings::afterIterations(iterations);
        if (variant.solver == "verlet") {
          verlet = std::make_unique<VerletSolver>(system, VerletSettings{});
          solve = [&](ParticleState& s, const AfterUpdateHook& h) { return verlet->solve(s, stopping, h); };
        } else {
          LocalGlobalSettings settings;
          settings.quasi_static = variant.mode == "quasi_static";
          if (!settings.quasi_static) settings.time_step_s = variant.time_step_s;
          settings.volume_weight = variant.volume_weight;
          settings.chebyshev_rho = variant.chebyshev_rho;
          local_global = std::make_unique<LocalGlobalSolver>(system, settings);
          factorisation_ms = local_global->factorisationMilliseconds();
          solve = [&](ParticleState& s, const AfterUpdateHook& h) { return local_global->solve(s, stopping, h); };
        }
      };
      makeSolver(variant.cap);
      const Run run = coldSolve(system, transforms, collision.get(), variant.cap, solve);
      // The first checkpoint within 1 mm, re-timed without snapshots.
      int iterations_to_1mm = -1;
      for (const Checkpoint& checkpoint : run.checkpoints)
        if (rmsMillimetres(checkpoint.position, reference) <= 1.0) {
          iterations_to_1mm = checkpoint.iteration;
          break;
        }
      double ms_to_1mm = -1;
      if (iterations_to_1mm > 0) {
        makeSolver(iterations_to_1mm);
        ms_to_1mm = coldSolveMilliseconds(system, transforms, collision.get(), repetitions, solve);
      }
      for (const Checkpoint& checkpoint : run.checkpoints) {
        const Eigen::VectorXd volume = 100.0 * muscleVolumeChange(tetrahedra, checkpoint.position).cwiseAbs();
        records.begin();
        records.add("solver", variant.solver);
        records.add("mode", variant.mode);
        records.add("collisions", collision_name);
        records.add("time_step_s", variant.time_step_s);
        records.add("volume_weight", variant.volume_weight);
        records.add("chebyshev_rho", variant.chebyshev_rho);
        records.add("iterations", checkpoint.iteration);
        records.add("wall_ms", checkpoint.wall_ms);
        records.add("rms_mm", rmsMillimetres(checkpoint.position, reference));
        records.add("volume_error_pct", volume.mean());
        records.add("volume_error_max_pct", volume.maxCoeff());
        records.add("factorisation_ms", factorisation_ms);
        records.end();
      }
      const Checkpoint& last = run.checkpoints.back();
      const Eigen::VectorXd volume = 100.0 * muscleVolumeChange(tetrahedra, last.position).cwiseAbs();
      std::printf("%-13s %-13s %9.4g %6.1f %5.2f %11.1f %9d %9.1f %9.3f %9.2f %9.2f %11.1f\n", variant.solver.c_str(),
                  variant.mode.c_str(), variant.time_step_s, variant.volume_weight, variant.chebyshev_rho,
                  factorisation_ms, last.iteration, last.wall_ms, rmsMillimetres(last.position, reference),
                  volume.mean(), volume.maxCoeff(), ms_to_1mm);
      std::printf("    rms_mm by iterations:");
      for (const Checkpoint& checkpoint : run.checkpoints)
        std::printf(" %d:%.2f", checkpoint.iteration, rmsMillimetres(checkpoint.position, reference));
      std::printf("\n");
      records.begin();
      records.add("solver", variant.solver);
      records.add("mode", variant.mode);
      records.add("collisions", collision_name);
      records.add("time_step_s", variant.time_step_s);
      records.add("volume_weight", variant.volume_weight);
      records.add("chebyshev_rho", variant.chebyshev_rho);
      records.add("iterations_to_1mm", iterations_to_1mm);
      records.add("wall_ms_to_1mm", ms_to_1mm);
      records.add("factorisation_ms", factorisation_ms);
      records.add("repetitions", repetitions);
      records.end();
    }
  }
  return bench::finish(records, options, "local_global.json");
}
