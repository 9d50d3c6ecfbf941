// Limits every solve obeys whatever its stopping rule (wall-time ceiling, cancellation), the meaning of `converged`,
// and the robust strain percentile.
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <limits>

using namespace muscle_deformation;
using muscle_deformation::testing::stateAt;

namespace {

// A straight chain of `links` unit springs along x, both ends fixed, the right end pulled to 1.5 x its length.
MassSpringSystem pulledChain(int links, ParticleState& state) {
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, links + 1);
  ParticlePairs springs;
  for (int i = 0; i <= links; ++i) positions(0, i) = i;
  for (int i = 0; i < links; ++i) springs.emplace_back(i, i + 1);
  MassSpringSystem system = systemFromParticles(positions, springs, 1.0, 1.0);
  system.is_fixed[0] = 1;
  system.is_fixed[links] = 1;
  state = stateAt(system.rest_position);
  state.position(0, links) = 1.5 * links;
  state.previous_position = state.position;
  return system;
}

double secondsOf(const std::function<void()>& run) {
  const auto start = std::chrono::steady_clock::now();
  run();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

TEST(SolveLimits, WallTimeLimitEndsAVerletSolveUnderTheIterationsRule) {
  ParticleState state;
  const MassSpringSystem system = pulledChain(50, state);
  // Unbounded but for the limit.
  StoppingSettings stopping = StoppingSettings::afterIterations(std::numeric_limits<int>::max());
  stopping.limits.wall_time_limit_ms = 50;
  VerletSolver solver(system, VerletSettings{});
  SolveStats stats;
  const double seconds = secondsOf([&] { stats = solver.solve(state, stopping); });
  EXPECT_TRUE(stats.time_limit_reached);
  EXPECT_FALSE(stats.stopping_rule_met) << "the iteration count was not reached";
  EXPECT_FALSE(stats.converged);
  EXPECT_GT(stats.iterations, 0);
  EXPECT_LT(seconds, 2.0) << "the 50 ms limit bounds the solve (2 s allows for a loaded machine)";
  EXPECT_TRUE(state.position.allFinite());
}

TEST(SolveLimits, WallTimeLimitEndsALocalGlobalSolveUnderTheIterationsRule) {
  for (const int history : {0, 8}) {
    ParticleState state;
    const MassSpringSystem system = pulledChain(50, state);
    LocalGlobalSettings settings;
    settings.lbfgs_history = history;
    StoppingSettings stopping = StoppingSettings::afterIterations(std::numeric_limits<int>::max());
    stopping.limits.wall_time_limit_ms = 50;
    // A contact hook that keeps moving one particle, so L-BFGS never runs out of descent before the limit.
    int calls = 0;
    const AfterUpdateHook jiggle = [&](ParticleState& s) {
      s.position(1, 10) = (++calls % 2) ? 1e-3 : -1e-3;
      return 1;
    };
    LocalGlobalSolver solver(system, settings);
    SolveStats stats;
    const double seconds = secondsOf([&] { stats = solver.solve(state, stopping, jiggle); });
    EXPECT_TRUE(stats.time_limit_reached) << "history " << history;
    EXPECT_FALSE(stats.stopping_rule_met) << "history " << history;
    EXPECT_LT(seconds, 2.0) << "history " << history;
  }
}

TEST(SolveLimits, RaisedCancelFlagStopsTheSolveAfterOneIteration) {
  ParticleState state;
  const MassSpringSystem system = pulledChain(20, state);
  std::atomic<bool> cancel{true};
  StoppingSettings stopping = StoppingSettings::afterIterations(1000000);
  stopping.limits.cancel = &cancel;
  VerletSolver solver(system, VerletSettings{});
  const SolveStats stats = solver.solve(state, stopping);
  EXPECT_TRUE(stats.cancelled);
  EXPECT_EQ(stats.iterations, 1);
  EXPECT_FALSE(stats.converged);
}

TEST(SolveLimits, EachSolveStopsAsItsOwnStoppingSaysWithoutRebuilding) {
  ParticleState state;
  const MassSpringSystem system = pulledChain(20, state);
  VerletSolver solver(system, VerletSettings());
  EXPECT_EQ(solver.solve(state, StoppingSettings::afterIterations(7)).iterations, 7);
  EXPECT_EQ(solver.solve(state, StoppingSettings::afterIterations(3)).iterations, 3);  // the same solver
  EXPECT_THROW(solver.solve(state, StoppingSettings::afterIterations(-1)), std::invalid_argument);
}

TEST(Converged, OnlyWhenTheDisplacementToleranceIsMet) {
  ParticleState state;
  const MassSpringSystem system = pulledChain(8, state);
  const ParticleState start = state;
  VerletSolver solver(system, VerletSettings{});
  const SolveStats counted = solver.solve(state, StoppingSettings::afterIterations(50));  // far from settled
  EXPECT_TRUE(counted.stopping_rule_met) << "the iterations rule ran its count";
  EXPECT_FALSE(counted.converged) << "running out of iterations is not convergence";

  state = start;
  VerletSolver by_tolerance(system, VerletSettings{});
  const SolveStats settled = by_tolerance.solve(state, StoppingSettings::atDisplacement(1e-10, 200000));
  EXPECT_TRUE(settled.converged);

  state = start;
  VerletSolver capped(system, VerletSettings{});
  // The tolerance cannot be met in 10 iterations.
  const SolveStats unsettled = capped.solve(state, StoppingSettings::atDisplacement(1e-10, 10));
  EXPECT_FALSE(unsettled.stopping_rule_met);
  EXPECT_FALSE(unsettled.converged);
}

TEST(StrainPercentile, IgnoresAFewExtremeSpringsWhereTheMaximumCannot) {
  // 1000 springs stretched by 10 % and 5 micro-springs stretched 10^4 times their length: the 99th percentile is the
  // ordinary 10 %, the maximum the outlier.
  const int ordinary = 1000, extreme = 5;
  Eigen::Matrix3Xd rest = Eigen::Matrix3Xd::Zero(3, 2 * (ordinary + extreme));
  ParticlePairs pairs;
  for (int s = 0; s < ordinary + extreme; ++s) {
    const double length = s < ordinary ? 1.0 : 1e-6;
    rest.col(2 * s) = Eigen::Vector3d(0, 0, 10.0 * s);
    rest.col(2 * s + 1) = Eigen::Vector3d(length, 0, 10.0 * s);
    pairs.emplace_back(2 * s, 2 * s + 1);
  }
  const MassSpringSystem system = systemFromParticles(rest, pairs, 1.0, 1.0);
  Eigen::Matrix3Xd deformed = rest;
  for (int s = 0; s < ordinary + extreme; ++s) {
    const double rest_length = s < ordinary ? 1.0 : 1e-6;
    deformed(0, 2 * s + 1) = s < ordinary ? 1.1 * rest_length : 1e4 * rest_length;
  }
  const SpringMetrics metrics = measureSprings(system.springs, deformed);
  EXPECT_NEAR(metrics.max_strain, 1e4 - 1, 1e-3);
  EXPECT_GE(metrics.strain_p99, 0.1 * (1 - 1e-9)) << "an upper bound";
  EXPECT_LE(metrics.strain_p99, 0.1 * 1.0625) << "at most one bin (1/16 octave) above";
}

TEST(StrainPercentile, EqualsTheStrainOfAUniformlyStretchedSet) {
  Eigen::Matrix3Xd rest(3, 2);
  rest << 0, 1, 0, 0, 0, 0;
  const MassSpringSystem system = systemFromParticles(rest, {{0, 1}}, 1.0, 1.0);
  Eigen::Matrix3Xd deformed = rest;
  deformed(0, 1) = 1.5;
  const SpringMetrics metrics = measureSprings(system.springs, deformed);
  EXPECT_NEAR(metrics.strain_p99, 0.5, 1e-12) << "clamped to the largest strain";
  deformed(0, 1) = 1.0;
  EXPECT_EQ(measureSprings(system.springs, deformed).strain_p99, 0.0);
}

// The per-frame spring metrics, measured in chunks shared by threads: 10000 unit springs along a line (three chunks and
// a part), spring i stretched by i / 10000 of its rest length, so the strains are 0 .. 0.9999 evenly: mean 0.49995,
// max 0.9999, the 99th percentile's bin at or above 0.99; the figures are the same for one, two and three threads.
TEST(SpringMetrics, AnalyticStrainsAndTheSameFiguresForAnyThreadCount) {
  constexpr int kSprings = 10000;
  Eigen::Matrix3Xd position = Eigen::Matrix3Xd::Zero(3, 2 * kSprings);
  SpringSet springs;
  springs.rest_length = Eigen::VectorXd::Ones(kSprings);
  springs.stiffness = Eigen::VectorXd::Ones(kSprings);
  for (int i = 0; i < kSprings; ++i) {
    position(1, 2 * i) = position(1, 2 * i + 1) = static_cast<double>(i);  // springs side by side
    position(0, 2 * i + 1) = 1.0 + static_cast<double>(i) / kSprings;
    springs.first.push_back(2 * i);
    springs.second.push_back(2 * i + 1);
  }
  const SpringMetrics one = measureSprings(springs, position, 1);
  EXPECT_NEAR(one.mean_strain, 0.49995, 1e-12);
  EXPECT_NEAR(one.max_strain, 0.9999, 1e-12);
  EXPECT_NEAR(one.deviation_ratio, 0.49995, 1e-12);
  EXPECT_GE(one.strain_p99, 0.99);
  EXPECT_LE(one.strain_p99, one.max_strain);
  for (int threads : {2, 3}) {
    const SpringMetrics many = measureSprings(springs, position, threads);
    EXPECT_EQ(many.mean_strain, one.mean_strain) << threads;
    EXPECT_EQ(many.max_strain, one.max_strain) << threads;
    EXPECT_EQ(many.deviation_ratio, one.deviation_ratio) << threads;
    EXPECT_EQ(many.strain_p99, one.strain_p99) << threads;
  }
}

TEST(SolveLimits, TimeSpentBeforeASolveComesOffItsBudgetAndItsCeiling) {
  StoppingSettings stopping = StoppingSettings::withinBudget(12.0, 30);
  stopping.limits.wall_time_limit_ms = 50.0;
  const StoppingSettings after = afterTimeSpent(stopping, 4.5);
  EXPECT_DOUBLE_EQ(after.time_budget_ms, 7.5);
  EXPECT_DOUBLE_EQ(after.limits.wall_time_limit_ms, 45.5);
  EXPECT_EQ(after.max_iterations, 30);
  EXPECT_EQ(after.rule, StoppingRule::time_budget);
  // Used up: no budget left (the solve still runs its one iteration), and the ceiling stays a ceiling, not "none".
  const StoppingSettings used_up = afterTimeSpent(stopping, 60.0);
  EXPECT_EQ(used_up.time_budget_ms, 0.0);
  EXPECT_GT(used_up.limits.wall_time_limit_ms, 0.0);
  EXPECT_LT(used_up.limits.wall_time_limit_ms, 1e-300);
  EXPECT_TRUE(validate(used_up).empty());
  // No ceiling stays none; nothing spent changes nothing.
  stopping.limits.wall_time_limit_ms = 0;
  EXPECT_EQ(afterTimeSpent(stopping, 5.0).limits.wall_time_limit_ms, 0.0);
  EXPECT_DOUBLE_EQ(afterTimeSpent(stopping, 0.0).time_budget_ms, 12.0);
}

TEST(SolveLimits, ACeilingUsedUpBeforeTheSolveStopsItAfterOneIteration) {
  ParticleState state;
  const MassSpringSystem system = pulledChain(50, state);
  VerletSolver solver(system, VerletSettings{});
  StoppingSettings stopping = StoppingSettings::afterIterations(1000);
  stopping.limits.wall_time_limit_ms = 10.0;
  const SolveStats stats = solver.solve(state, afterTimeSpent(stopping, 10.0));
  EXPECT_EQ(stats.iterations, 1);
  EXPECT_TRUE(stats.time_limit_reached);
}
