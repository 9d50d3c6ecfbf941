// Per-iteration time of one solver iteration split as the paper's Table 1 splits it: the MSS update, muscle-muscle
// collision and muscle-bone collision, measured from a loaded state (contacts settled as in the middle of a solve).
#pragma once

#include "bench_util.hpp"

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"

#include <vector>

namespace bench {

struct IterationSplit {
  double mss_ms = 0, muscle_cd_ms = 0, bone_cd_ms = 0, response_ms = 0, total_ms = 0;  // wall, per iteration
  double mss_cpu_ms = 0, collision_cpu_ms = 0, total_cpu_ms = 0;  // thread CPU time, per iteration
  double contacts = 0;                                            // per iteration
};

// The state a solve reaches at `transforms` after `warmup_iterations` MSS updates with collision, from the rigid
// pre-transform: iterations timed from here see the contacts a real solve sees, not the unloaded rest shape.
inline muscle_deformation::ParticleState loadedState(const muscle_deformation::MassSpringSystem& system,
                                                     muscle_deformation::VerletSolver& solver,
                                                     muscle_deformation::CollisionWorld& world,
                                                     const muscle_deformation::BoneTransforms& transforms,
                                                     int warmup_iterations) {
  muscle_deformation::ParticleState state;
  muscle_deformation::rigidPretransform(system, transforms, state);
  world.setBoneTransforms(transforms);
  for (int i = 0; i < warmup_iterations; ++i) {
    solver.step(state);
    world.resolve(state);
  }
  return state;
}

// Medians over `repetitions` runs of `iterations_per_run` iterations, each run from `start`. The world must hold
// the pose `start` belongs to.
inline IterationSplit measureIterationSplit(muscle_deformation::VerletSolver& solver,
                                            muscle_deformation::CollisionWorld& world,
                                            const muscle_deformation::ParticleState& start, int repetitions,
                                            int iterations_per_run) {
  std::vector<double> mss, muscle, bone, response, total, mss_cpu, collision_cpu, total_cpu, contacts;
  for (int r = 0; r < repetitions; ++r) {
    muscle_deformation::ParticleState state = start;
    // The first pass after a reset builds lazy structures; it belongs to the run's warm-up, not its timing.
    world.resolve(state);
    state = start;
    world.resetTiming();
    double mss_ms = 0, total_ms = 0, mss_cpu_ms = 0, collision_cpu_ms = 0, run_contacts = 0;
    for (int i = 0; i < iterations_per_run; ++i) {
      total_ms += millisecondsOf([&] {
        mss_ms += millisecondsOf([&] { mss_cpu_ms += cpuMillisecondsOf([&] { solver.step(state); }); });
        collision_cpu_ms += cpuMillisecondsOf([&] { run_contacts += world.resolve(state); });
      });
    }
    const muscle_deformation::CollisionStats& stats = world.accumulatedStats();
    const double n = iterations_per_run;
    muscle.push_back(stats.muscle_cd_ms / n);
    bone.push_back(stats.bone_cd_ms / n);
    response.push_back(stats.response_ms / n);
    mss.push_back(mss_ms / n);
    total.push_back(total_ms / n);
    mss_cpu.push_back(mss_cpu_ms / n);
    collision_cpu.push_back(collision_cpu_ms / n);
    total_cpu.push_back((mss_cpu_ms + collision_cpu_ms) / n);
    contacts.push_back(run_contacts / n);
  }
  IterationSplit split;
  split.mss_ms = median(mss);
  split.muscle_cd_ms = median(muscle);
  split.bone_cd_ms = median(bone);
  split.response_ms = median(response);
  split.total_ms = median(total);
  split.mss_cpu_ms = median(mss_cpu);
  split.collision_cpu_ms = median(collision_cpu);
  split.total_cpu_ms = median(total_cpu);
  split.contacts = median(contacts);
  return split;
}

}  // namespace bench
