// Solves that keep snapshots of the particles at growing iteration counts, for error-against-time curves. The time a
// snapshot takes is left out of the reported wall time, so the curve shows what a solve stopped there would cost.
#pragma once

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <utility>
#include <vector>

namespace bench {

// RMS distance between two particle sets of the same system, in millimetres.
inline double rmsMillimetres(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return 1e3 * std::sqrt((a - b).colwise().squaredNorm().mean());
}

struct Checkpoint {
  int iteration = 0;
  double wall_ms = 0;  // solve time up to the end of this iteration, the snapshot's own cost excluded
  Eigen::Matrix3Xd position;
};

struct ConvergenceRun {
  Eigen::Matrix3Xd start_position;  // the state the solve started from (iteration 0)
  std::vector<Checkpoint> checkpoints;
  muscle_deformation::SolveStats stats;
  Eigen::Matrix3Xd final_position;
};

// Checkpoints at 1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, ... iterations (about 8 per decade), up to `cap`.
inline std::vector<int> checkpointIterations(int cap) {
  std::vector<int> result;
  for (double k = 1; k <= cap; k = std::max(k + 1, std::round(k * 1.25))) result.push_back(static_cast<int>(k));
  if (result.empty() || result.back() != cap) result.push_back(cap);
  return result;
}

// Runs a solver with the given collision hook (VerletSolver::solve or LocalGlobalSolver::solve bound to a solver and
// the StoppingSettings of the solve).
using SolveFunction =
    std::function<muscle_deformation::SolveStats(muscle_deformation::ParticleState&,
                                                 const muscle_deformation::AfterUpdateHook&)>;

// One solve from `state` (already pre-transformed or warm-started; the collision world already posed), with
// collision after every update, snapshotting the state at the checkpoint iterations of `cap`. The solver decides when
// to stop; give it stopping settings with an iteration cap of `cap` so that every checkpoint is reached.
inline ConvergenceRun checkpointedSolve(muscle_deformation::ParticleState state,
                                        muscle_deformation::CollisionWorld* collision, int cap,
                                        const SolveFunction& solve) {
  using Clock = std::chrono::steady_clock;
  ConvergenceRun run;
  run.start_position = state.position;
  const std::vector<int> wanted = checkpointIterations(cap);
  std::size_t next = 0;
  int iteration = 0;
  double snapshot_ms = 0;
  const auto start = Clock::now();
  const muscle_deformation::AfterUpdateHook hook = [&](muscle_deformation::ParticleState& s) {
    const int contacts = collision ? collision->resolve(s) : 0;
    ++iteration;
    if (next < wanted.size() && iteration == wanted[next]) {
      const auto snapshot_start = Clock::now();
      const double elapsed = std::chrono::duration<double, std::milli>(snapshot_start - start).count();
      run.checkpoints.push_back({iteration, elapsed - snapshot_ms, s.position});
      snapshot_ms += std::chrono::duration<double, std::milli>(Clock::now() - snapshot_start).count();
      ++next;
    }
    return contacts;
  };
  run.stats = solve(state, hook);
  run.final_position = state.position;
  return run;
}

// The same from the rigid pre-transform (cold start, as the seeds solve every pose).
inline ConvergenceRun coldSolve(const muscle_deformation::MassSpringSystem& system,
                                const muscle_deformation::BoneTransforms& transforms,
                                muscle_deformation::CollisionWorld* collision, int cap, const SolveFunction& solve) {
  muscle_deformation::ParticleState state;
  muscle_deformation::rigidPretransform(system, transforms, state);
  return checkpointedSolve(std::move(state), collision, cap, solve);
}

}  // namespace bench
