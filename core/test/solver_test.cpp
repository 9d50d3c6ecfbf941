// Damped Verlet solver on small analytic systems.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;
using muscle_deformation::testing::stateAt;

namespace {

// Two free particles 1 m apart joined by one spring; mass 1 kg, stiffness 1 N/m.
MassSpringSystem twoParticleSpring() {
  Eigen::Matrix3Xd positions(3, 2);
  positions << 0, 1, 0, 0, 0, 0;
  return systemFromParticles(positions, {{0, 1}}, 1.0, 1.0);
}

// Iterations until the spring stays within 1e-4 of its rest length and both particles are (nearly) at rest.
int iterationsToSettle(const MassSpringSystem& system, double damping_scale, double dt) {
  VerletSettings settings;
  settings.dt_s = dt;
  settings.damping_scale = damping_scale;
  VerletSolver solver(system, settings);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 1) = 1.5;  // stretched by half its rest length
  state.previous_position = state.position;
  int settled_since = -1;
  for (int iteration = 0; iteration < 200000; ++iteration) {
    solver.step(state);
    const double length = (state.position.col(1) - state.position.col(0)).norm();
    const double speed = (state.position - state.previous_position).norm() / dt;
    const bool settled = std::abs(length - 1.0) < 1e-4 && speed < 1e-4;
    if (settled && settled_since < 0) settled_since = iteration;
    if (!settled) settled_since = -1;
    if (settled_since >= 0 && iteration - settled_since > 100) return settled_since;
  }
  return 200000;
}

// A straight chain of `links` unit springs along x, both ends fixed.
MassSpringSystem fixedChain(int links) {
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, links + 1);
  ParticlePairs springs;
  for (int i = 0; i <= links; ++i) positions(0, i) = i;
  for (int i = 0; i < links; ++i) springs.emplace_back(i, i + 1);
  MassSpringSystem system = systemFromParticles(positions, springs, 1.0, 1.0);
  system.is_fixed[0] = 1;
  system.is_fixed[links] = 1;
  return system;
}

}  // namespace

TEST(Spring, AtRestLengthExertsNoForce) {
  const MassSpringSystem system = twoParticleSpring();
  VerletSolver solver(system, VerletSettings{});
  ParticleState state = stateAt(system.rest_position);
  solver.solve(state, StoppingSettings::afterIterations(10));
  EXPECT_EQ(state.position, system.rest_position);
}

TEST(Spring, StretchedSpringPullsBothEndsTowardsEachOtherEqually) {
  const MassSpringSystem system = twoParticleSpring();
  VerletSettings settings;
  settings.dt_s = 0.01;
  VerletSolver solver(system, settings);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 1) = 2.0;
  state.previous_position = state.position;
  solver.step(state);
  EXPECT_GT(state.position(0, 0), 0.0);
  EXPECT_LT(state.position(0, 1), 2.0);
  EXPECT_NEAR(state.position(0, 0) - 0.0, 2.0 - state.position(0, 1), 1e-15);  // momentum is conserved
}

TEST(Damping, CriticalRuleIsExactlyCriticalForTwoFreeParticles) {
  // Relative coordinate of two free particles: (m/2) x'' + c/2 x' ... i.e. m x'' + c x' + 2k x = 0, critical at
  // c = sqrt(4 * 2k * m).
  const MassSpringSystem system = twoParticleSpring();
  EXPECT_NEAR(criticalDamping(system), std::sqrt(8.0), 1e-12);
}

TEST(Damping, CriticalSettlesFasterThanUnderAndOverDamped) {
  const MassSpringSystem system = twoParticleSpring();
  const double dt = 0.01;  // well below the stability bound of 2/sqrt(2k/m) = 1.41 s
  const int critical = iterationsToSettle(system, 1.0, dt);
  const int under = iterationsToSettle(system, 0.2, dt);
  const int over = iterationsToSettle(system, 5.0, dt);
  EXPECT_LT(critical, under);
  EXPECT_LT(critical, over);
}

TEST(Chain, StretchedBetweenFixedEndsConvergesToUniformStrain) {
  const int links = 8;
  const MassSpringSystem system = fixedChain(links);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, links) = 1.5 * links;  // pull the right end: every spring should end 50 % longer
  state.previous_position = state.position;
  VerletSolver solver(system, VerletSettings{});
  const SolveStats stats = solver.solve(state, StoppingSettings::atDisplacement(1e-12, 200000));
  EXPECT_TRUE(stats.stopping_rule_met);
  for (int i = 0; i < links; ++i) {
    const double length = (state.position.col(i + 1) - state.position.col(i)).norm();
    EXPECT_NEAR(length, 1.5, 1e-6) << "spring " << i;
  }
  EXPECT_NEAR(stats.mean_strain, 0.5, 1e-6);
  EXPECT_NEAR(stats.max_strain, 0.5, 1e-6);
  EXPECT_NEAR(stats.spring_deviation_ratio, 0.5, 1e-6);
}

TEST(FixedParticles, NeverMove) {
  const int links = 5;
  const MassSpringSystem system = fixedChain(links);
  ParticleState state = stateAt(system.rest_position);
  state.position(1, 2) = 0.7;  // disturb a free particle so forces act on the fixed ends too
  state.previous_position = state.position;
  const Eigen::Vector3d left = state.position.col(0), right = state.position.col(links);
  VerletSolver solver(system, VerletSettings{});
  solver.solve(state, StoppingSettings::afterIterations(500));
  EXPECT_EQ(Eigen::Vector3d(state.position.col(0)), left);
  EXPECT_EQ(Eigen::Vector3d(state.position.col(links)), right);
  EXPECT_NE(state.position(1, 2), 0.7);
}

TEST(AdaptiveTimeStep, KeepsEveryBoundaryParticleStepWithinItsRadius) {
  // A jagged, stretched 3-D lattice so that forces differ from particle to particle.
  const int side = 4;
  Eigen::Matrix3Xd positions(3, side * side * side);
  for (int i = 0; i < side * side * side; ++i)
    positions.col(i) = Eigen::Vector3d(i % side, (i / side) % side, i / (side * side)) * 0.01;
  ParticlePairs springs;
  for (int a = 0; a < positions.cols(); ++a)
    for (int b = a + 1; b < positions.cols(); ++b)
      if ((positions.col(a) - positions.col(b)).norm() < 0.0151) springs.emplace_back(a, b);
  MassSpringSystem system = systemFromParticles(positions, springs, 0.001, 5.0);
  for (Eigen::Index i = 0; i < positions.cols(); ++i) {
    system.is_boundary[i] = 1;
    system.radius[i] = 0.001 + 0.0005 * (i % 3);
  }
  system.is_fixed[0] = 1;
  ParticleState state = stateAt(positions);
  state.position *= 1.4;  // everything stretched 40 %: large spring forces
  state.position.col(0) = positions.col(0);
  state.previous_position = state.position;

  VerletSettings settings;
  settings.dt_rule = TimeStepRule::adaptive;
  settings.dt_min_s = 1e-12;  // let the rule, not the clamp, decide
  VerletSolver solver(system, settings);
  for (int iteration = 0; iteration < 300; ++iteration) {
    const Eigen::Matrix3Xd before = state.position;
    solver.step(state);
    for (Eigen::Index i = 1; i < positions.cols(); ++i)
      ASSERT_LE((state.position.col(i) - before.col(i)).norm(), system.radius[i] * (1 + 1e-9))
          << "particle " << i << " iteration " << iteration;
  }
}

TEST(AdaptiveTimeStep, NeverExceedsTheFixedStepOrFallsBelowTheClamp) {
  const int links = 6;
  MassSpringSystem system = fixedChain(links);
  for (int i = 0; i <= links; ++i) {
    system.is_boundary[i] = 1;
    system.radius[i] = 0.05;
  }
  ParticleState state = stateAt(system.rest_position);
  state.position(0, links) = 2.0 * links;
  state.previous_position = state.position;
  VerletSettings settings;
  settings.dt_rule = TimeStepRule::adaptive;
  settings.dt_s = 0.2;
  settings.dt_min_s = 0.01;
  VerletSolver solver(system, settings);
  const SolveStats stats = solver.solve(state, StoppingSettings::afterIterations(200));
  EXPECT_LE(stats.max_dt_s, 0.2);
  EXPECT_GE(stats.min_dt_s, 0.01);
  EXPECT_LT(stats.min_dt_s, 0.2);  // the stretched chain did force smaller steps
}

TEST(StoppingRule, FixedIterationCountRunsExactlyThatMany) {
  const MassSpringSystem system = fixedChain(4);
  ParticleState state = stateAt(system.rest_position);
  VerletSolver solver(system, VerletSettings{});
  EXPECT_EQ(solver.solve(state, StoppingSettings::afterIterations(37)).iterations, 37);
}

TEST(StoppingRule, DisplacementStopsEarlyAtRest) {
  const MassSpringSystem system = fixedChain(4);
  ParticleState state = stateAt(system.rest_position);
  VerletSolver solver(system, VerletSettings{});
  const SolveStats stats = solver.solve(state, StoppingSettings::atDisplacement(1e-9, 1000));
  EXPECT_EQ(stats.iterations, 2);  // the second iteration shows the displacement is not growing
  EXPECT_TRUE(stats.stopping_rule_met);
}

TEST(StoppingRule, DisplacementDoesNotStopWhileASolveFromRestIsSpeedingUp) {
  // Starting from rest, the first iterations move very little (F dt^2 / m) but more each time: not converged.
  const MassSpringSystem system = fixedChain(10);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 10) = 20;
  state.previous_position = state.position;
  VerletSettings settings;
  settings.dt_s = 1e-4;  // tiny steps: the first displacements are far below the tolerance
  VerletSolver solver(system, settings);
  EXPECT_EQ(solver.solve(state, StoppingSettings::atDisplacement(1e-6, 50)).iterations, 50);
}

TEST(StoppingRule, TimeBudgetEndsTheSolveAfterTheBudget) {
  const MassSpringSystem system = fixedChain(2000);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 2000) = 3000;
  state.previous_position = state.position;
  VerletSolver solver(system, VerletSettings{});
  const SolveStats stats = solver.solve(state, StoppingSettings::withinBudget(5.0, 100000000));
  EXPECT_TRUE(stats.stopping_rule_met);
  EXPECT_GE(stats.total_ms, 5.0);
  EXPECT_LT(stats.iterations, 100000000);
}

TEST(StoppingRule, DisplacementReportsNotMetWhenTheCapEndsTheSolve) {
  const MassSpringSystem system = fixedChain(10);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 10) = 20;
  state.previous_position = state.position;
  VerletSolver solver(system, VerletSettings{});
  const SolveStats stats = solver.solve(state, StoppingSettings::atDisplacement(1e-15, 3));
  EXPECT_EQ(stats.iterations, 3);
  EXPECT_FALSE(stats.stopping_rule_met);
}

TEST(Solver, RejectsAStateOfTheWrongSize) {
  const MassSpringSystem system = fixedChain(3);
  VerletSolver solver(system, VerletSettings{});
  ParticleState state = stateAt(Eigen::Matrix3Xd::Zero(3, 2));
  EXPECT_THROW(solver.solve(state, StoppingSettings{}), std::invalid_argument);
}

TEST(Solver, RejectsNegativeSettings) {
  const MassSpringSystem system = fixedChain(3);
  VerletSettings settings;
  settings.dt_s = -1;
  EXPECT_THROW(VerletSolver(system, settings), std::invalid_argument);
  // The iteration cap comes with each solve now, so a negative one is refused there.
  VerletSolver solver(system, VerletSettings{});
  ParticleState state = stateAt(system.rest_position);
  EXPECT_THROW(solver.solve(state, StoppingSettings::afterIterations(-5)), std::invalid_argument);
}

TEST(Solver, CollisionHookRunsAfterEveryUpdateAndItsTimeIsCounted) {
  const MassSpringSystem system = fixedChain(3);
  ParticleState state = stateAt(system.rest_position);
  VerletSolver solver(system, VerletSettings{});
  int calls = 0;
  const SolveStats stats =
      solver.solve(state, StoppingSettings::afterIterations(12), [&](ParticleState&) { return ++calls; });
  EXPECT_EQ(calls, 12);
  EXPECT_EQ(stats.contacts, 12);
}
