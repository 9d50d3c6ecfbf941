// Newton-Krylov solver: the same frame energy as block descent (springs, contacts, tissue drag), minimised globally.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/solvers/newton_krylov_solver.hpp"
#include "muscle_deformation/core/solvers/solver_factory.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "../src/pipeline/muscle_simulation.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <functional>

using namespace muscle_deformation;
using muscle_deformation::testing::converging;
using muscle_deformation::testing::solvePose;
using muscle_deformation::testing::stateAt;

TEST(NewtonKrylov, ChainStretchedBetweenFixedEndsReachesUniformStrain) {
  // Five unit springs (1 N material) between ends fixed 6 m apart: every spring at 1.2 m.
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, 6);
  ParticlePairs springs;
  for (int i = 0; i < 6; ++i) positions(0, i) = i;
  for (int i = 0; i < 5; ++i) springs.emplace_back(i, i + 1);
  MassSpringSystem system = systemFromParticles(positions, springs, 1.0, 1.0);
  system.is_fixed[0] = system.is_fixed[5] = 1;
  NewtonKrylovSolver solver(system, {}, {});
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 5) = 6.0;
  const SolveStats stats = solver.solve(state, converging(50, 1e-12));
  EXPECT_TRUE(stats.converged);
  EXPECT_LE(stats.iterations, 5);  // Newton on a quadratic along the chain: a step or two
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(state.position(0, i), 1.2 * i, 1e-9);
  EXPECT_NEAR(state.position.row(1).cwiseAbs().maxCoeff(), 0.0, 1e-12);
}

TEST(NewtonKrylov, TissueDragAnswerOfAFloppyParticleMatchesTheAnalyticOne) {
  Eigen::Matrix3Xd positions(3, 2);
  positions << 0, 1, 0, 0, 0, 0;
  MassSpringSystem system = systemFromParticles(positions, {{0, 1}}, 1.0, 1.0);
  system.is_fixed[0] = 1;
  BlockDescentSettings energy;
  energy.tissue_relaxation_s = 0.005;
  NewtonKrylovSolver solver(system, energy, {});
  solver.setFrameInterval(0.01);  // drag weight 0.5 N/m
  ParticleState state = stateAt(system.rest_position);
  const Eigen::Vector3d carried(1.5, 1.0, 0.2);
  state.carried_position = state.position;
  state.carried_position.col(1) = carried;
  EXPECT_TRUE(solver.solve(state, converging(100, 1e-12)).converged);
  const Eigen::Vector3d expected = (1.0 + 0.5 * carried.norm()) / 1.5 * carried.normalized();
  EXPECT_LT((state.position.col(1) - expected).norm(), 1e-9);
}

namespace {
// Three particles 1 m apart on a fibre along x, ends fixed, unit springs (block descent's drag test).
MassSpringSystem threeParticleFibre() {
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, 3);
  positions.row(0) << 0, 1, 2;
  MassSpringSystem system = systemFromParticles(positions, {{0, 1}, {1, 2}}, 1.0, 1.0);
  system.is_fixed[0] = system.is_fixed[2] = 1;
  return system;
}
}  // namespace

TEST(NewtonKrylov, DragAlongTheFibreMatchesTheAnalyticAnswer) {
  // The middle particle's drag weight is 1 N/m; carried 0.3 m along the fibre with a quarter of the drag along it, it
  // moves 0.25 x 0.3 / (2 + 0.25) (block descent's test).
  const MassSpringSystem system = threeParticleFibre();
  BlockDescentSettings energy;
  energy.tissue_relaxation_s = 0.005;
  energy.drag_along_fibre = 0.25;
  NewtonKrylovSolver solver(system, energy, {});
  solver.setFrameInterval(0.01);
  ParticleState state = stateAt(system.rest_position);
  state.carried_position = state.position;
  state.carried_position.col(1) = Eigen::Vector3d(1.3, 0, 0);
  // 1e-9: the line search compares frame energies of about 0.04 J, so steps below ~1e-10 N cannot be told apart.
  EXPECT_TRUE(solver.solve(state, converging(100, 1e-9)).converged);
  EXPECT_NEAR(state.position(0, 1) - 1.0, 0.25 * 0.3 / 2.25, 1e-9);
}

namespace {

// The three-particle fibre solved from `start` by the whole-frame Newton steps (frameForces, frameHessianTimes) and by
// block descent's sweeps with `energy`: the two reach the same answer, and the answer moves when `switch_off` takes the
// term under test away (so that it takes part).
void expectNewtonMatchesSweepsWithTheTermTakingPart(const BlockDescentSettings& energy, const ParticleState& start,
                                                    const std::function<void(BlockDescentSettings&)>& switch_off) {
  const MassSpringSystem system = threeParticleFibre();
  ParticleState newton = start, sweeps = start;
  NewtonKrylovSolver solver(system, energy, {});
  solver.setFrameInterval(0.01);
  // 1e-8: the line search compares frame energies of about 0.1 J, which cannot tell steps below a few 1e-9 N apart.
  EXPECT_TRUE(solver.solve(newton, converging(100, 1e-8)).converged);
  BlockDescentSolver reference(system, energy);
  reference.setFrameInterval(0.01);
  EXPECT_TRUE(reference.solve(sweeps, converging(2000, 1e-12)).converged);
  EXPECT_LT((newton.position.col(1) - sweeps.position.col(1)).norm(), 1e-8);
  BlockDescentSettings without_term = energy;
  switch_off(without_term);
  BlockDescentSolver other(system, without_term);
  other.setFrameInterval(0.01);
  ParticleState without = start;
  EXPECT_TRUE(other.solve(without, converging(2000, 1e-12)).converged);
  EXPECT_GT((sweeps.position.col(1) - without.position.col(1)).norm(), 0.05);
}

}  // namespace

TEST(NewtonKrylov, TheAcrossFibreTieMatchesBlockDescentsAnswer) {
  // The three-particle fibre of the drag test with a quarter of the drag along it and the across-fibre tie (2 N/m on the
  // middle particle), carried off along and across, its rest carried off along and across.
  const MassSpringSystem system = threeParticleFibre();
  BlockDescentSettings energy;
  energy.tissue_relaxation_s = 0.005;
  energy.drag_along_fibre = 0.25;
  energy.across_fibre_tie = 1.0;
  ParticleState start = stateAt(system.rest_position);
  start.carried_position = start.position;
  start.carried_position.col(1) = Eigen::Vector3d(1.2, 0.3, -0.1);
  start.rest_carried_position = start.position;
  start.rest_carried_position.col(1) = Eigen::Vector3d(0.9, -0.2, 0.1);
  expectNewtonMatchesSweepsWithTheTermTakingPart(energy, start, [](BlockDescentSettings& s) { s.across_fibre_tie = 0; });
}

TEST(NewtonKrylov, TheRestBalanceMatchesBlockDescentsAnswer) {
  // The tie's test above with a rest balance force on the middle particle, off along and across the fibre.
  const MassSpringSystem system = threeParticleFibre();
  BlockDescentSettings energy;
  energy.tissue_relaxation_s = 0.005;
  energy.drag_along_fibre = 0.25;
  energy.across_fibre_tie = 1.0;
  energy.balance_rest_shape = true;
  ParticleState start = stateAt(system.rest_position);
  start.carried_position = start.position;
  start.carried_position.col(1) = Eigen::Vector3d(1.1, 0.2, 0);
  start.rest_carried_position = start.position;
  start.rest_balance_force = Eigen::Matrix3Xd::Zero(3, 3);
  start.rest_balance_force.col(1) = Eigen::Vector3d(0.3, -0.2, 0.1);
  expectNewtonMatchesSweepsWithTheTermTakingPart(energy, start,
                                                 [](BlockDescentSettings& s) { s.balance_rest_shape = false; });
}

TEST(NewtonKrylov, ReachesTheSameFrameAnswerAsBlockDescentFromTheSameStart) {
  // The synthetic thigh after a warm pose change, with contacts and the node's tissue drag: both solvers converged to
  // a tight force residual from the same start end in the same state.
  const SyntheticScene scene = makeSyntheticThigh(4, 4);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.block_descent.tissue_relaxation_s = 0.0005;
  const FrameStopping stopping = FrameStopping::of(converging(4000, 1e-8));
  Eigen::Matrix3Xd answers[2], first_frame;
  int contacts = 0;
  const BoneTransforms first_pose = boneTransformsOf(scene.bones, syntheticThighPose(0.3, 0.5));
  for (const SolverKind kind : {SolverKind::block_descent, SolverKind::newton_krylov}) {
    settings.solver_kind = kind;
    MuscleSimulation simulation(scene.muscles, scene.bones, settings);
    if (kind == SolverKind::block_descent) {
      simulation.solve(first_pose, StartMode::cold, stopping);
      first_frame = simulation.state().position;
    } else {
      simulation.continueFrom(first_pose, first_frame);  // only the second frame's solver differs
    }
    const FrameStats stats = solvePose(simulation, syntheticThighPose(0.45, 0.7), StartMode::warm, stopping);
    ASSERT_TRUE(stats.solver.converged) << toString(kind);
    if (kind == SolverKind::block_descent) contacts = stats.solver.contacts;
    answers[kind == SolverKind::newton_krylov] = simulation.state().position;
  }
  EXPECT_GT(contacts, 0);  // contacts take part
  EXPECT_LT((answers[0] - answers[1]).colwise().norm().maxCoeff(), 1e-6);  // metres
}
