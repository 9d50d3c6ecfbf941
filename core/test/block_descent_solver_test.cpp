// Block descent solver: analytic equilibria, the force-residual stopping rule, contacts in the solve, thread-count
// independence and robustness on the synthetic thigh.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "../src/pipeline/muscle_simulation.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cmath>

using namespace muscle_deformation;
using muscle_deformation::testing::converging;
using muscle_deformation::testing::solvePose;
using muscle_deformation::testing::stateAt;

namespace {

// A straight chain of `links` springs of rest length 1 m along x, both ends fixed (material constant 1 N).
MassSpringSystem fixedChain(int links) {
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, links + 1);
  ParticlePairs springs;
  for (int i = 0; i <= links; ++i) positions(0, i) = i;
  for (int i = 0; i < links; ++i) springs.emplace_back(i, i + 1);
  MassSpringSystem system = systemFromParticles(positions, springs, 1.0, 1.0);
  system.is_fixed[0] = 1;
  system.is_fixed[static_cast<std::size_t>(links)] = 1;
  return system;
}

// A 4 x 4 x 4 lattice of unit spacing with edge and face-diagonal springs; the x = 0 face fixed.
MassSpringSystem latticeBlock() {
  const int n = 4;
  Eigen::Matrix3Xd positions(3, n * n * n);
  const auto index = [n](int x, int y, int z) { return x + n * (y + n * z); };
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) positions.col(index(x, y, z)) = Eigen::Vector3d(x, y, z);
  ParticlePairs springs;
  for (int a = 0; a < n * n * n; ++a)
    for (int b = a + 1; b < n * n * n; ++b) {
      const double d = (positions.col(a) - positions.col(b)).norm();
      if (d < 1.5) springs.emplace_back(a, b);
    }
  MassSpringSystem system = systemFromParticles(positions, springs, 1.0, 10.0);
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y) system.is_fixed[static_cast<std::size_t>(index(0, y, z))] = 1;
  return system;
}

}  // namespace

TEST(BlockDescent, ChainStretchedBetweenFixedEndsReachesUniformStrain) {
  const int links = 10;
  const MassSpringSystem system = fixedChain(links);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, links) = 15.0;  // the end pulled: every link at 1.5 m at equilibrium
  for (int i = 1; i < links; ++i) state.position(1, i) = 0.3 * std::sin(i);  // and a bent start
  BlockDescentSolver solver(system, {});
  const SolveStats stats = solver.solve(state, converging(5000, 1e-10));
  EXPECT_TRUE(stats.converged);
  EXPECT_LT(stats.residual, 1e-10);
  for (int i = 0; i <= links; ++i) {
    EXPECT_NEAR(state.position(0, i), 1.5 * i, 1e-8);
    EXPECT_NEAR(state.position(1, i), 0.0, 1e-8);
  }
}

TEST(BlockDescent, StretchedBlockMatchesAnIndependentSolverAndIsAtRestWhenUnloaded) {
  const MassSpringSystem system = latticeBlock();
  ParticleState state = stateAt(system.rest_position);
  BlockDescentSolver solver(system, {});
  SolveStats stats = solver.solve(state, converging(100, 1e-12));  // at rest: nothing to do
  EXPECT_TRUE(stats.converged);
  EXPECT_LT((state.position - system.rest_position).cwiseAbs().maxCoeff(), 1e-12);

  // Pull the x = 3 face by 0.5 m with it fixed: the equilibrium is the minimum of the spring energy, which damped
  // Verlet run long reaches too (different method, same answer).
  MassSpringSystem pulled = system;
  for (Eigen::Index i = 0; i < pulled.particleCount(); ++i)
    if (pulled.rest_position(0, i) == 3.0) pulled.is_fixed[static_cast<std::size_t>(i)] = 1;
  ParticleState start = stateAt(pulled.rest_position);
  for (Eigen::Index i = 0; i < pulled.particleCount(); ++i)
    if (pulled.rest_position(0, i) == 3.0) start.position(0, i) += 0.5;
  start.previous_position = start.position;
  ParticleState descent = start;
  BlockDescentSolver block(pulled, {});
  stats = block.solve(descent, converging(20000, 1e-11));
  EXPECT_TRUE(stats.converged);
  ParticleState verlet = start;
  VerletSolver(pulled, {}).solve(verlet, StoppingSettings::atDisplacement(1e-13, 200000));
  EXPECT_LT((descent.position - verlet.position).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(relativeSpringResidual(pulled, descent.position), 1e-10);
  // The block got longer and, by symmetry, its centre line stayed on the mid-plane.
  EXPECT_GT(descent.position.row(0).maxCoeff(), 3.4);
}

TEST(BlockDescent, ForceResidualRuleStopsBelowItsToleranceAndSaysSo) {
  const MassSpringSystem system = fixedChain(10);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 10) = 15.0;
  BlockDescentSolver solver(system, {});
  const SolveStats met = solver.solve(state, converging(100000, 1e-4));
  EXPECT_TRUE(met.converged);
  EXPECT_TRUE(met.stopping_rule_met);
  EXPECT_LT(met.residual, 1e-4);
  EXPECT_GT(met.iterations, 1);

  ParticleState again = stateAt(system.rest_position);
  again.position(0, 10) = 15.0;
  BlockDescentSolver capped(system, {});
  const SolveStats cut = capped.solve(again, converging(2, 1e-12));
  EXPECT_FALSE(cut.converged);
  EXPECT_FALSE(cut.stopping_rule_met);
  EXPECT_EQ(cut.iterations, 2);
  EXPECT_GT(cut.residual, 1e-12);
}

TEST(BlockDescent, OtherSolversRefuseTheForceResidualRule) {
  const MassSpringSystem system = fixedChain(3);
  // The rule comes with each solve now, so it is refused there.
  const StoppingSettings residual_rule = converging(10, 1e-6);
  VerletSolver verlet(system, {});
  ParticleState state = stateAt(system.rest_position);
  EXPECT_THROW(verlet.solve(state, residual_rule), std::invalid_argument);
  LocalGlobalSolver local_global(system, {});
  EXPECT_THROW(local_global.solve(state, residual_rule), std::invalid_argument);
  // -1 is the measured choice, 0 every core
  EXPECT_THROW(BlockDescentSolver(system, {}, -2), std::invalid_argument);
}

namespace {

// A particle hung between two fixed ends 2 m apart by springs of rest length 0.2 m (material constant 1 N), starting
// 0.8 m above the line between them.
MassSpringSystem hungParticle() {
  Eigen::Matrix3Xd positions(3, 3);
  positions << -1, 0, 1,  //
      0, 0.8, 0,          //
      0, 0, 0;
  MassSpringSystem system = systemFromParticles(positions, {{0, 1}, {1, 2}}, 1.0, 1.0);
  system.springs.rest_length.setConstant(0.2);
  system.springs.stiffness.setConstant(5.0);
  system.is_fixed[0] = system.is_fixed[2] = 1;
  return system;
}

}  // namespace

TEST(BlockDescent, ContactKeepsAParticlePressedAgainstAFixedSphereOutsideIt) {
  // A particle hung between two fixed ends 2 m apart, pulled by its springs (rest length 0.2 m) straight through a
  // fixed sphere of radius 0.5 m around the midpoint's foot: at equilibrium it rests on the sphere, pressed against it.
  MassSpringSystem system = hungParticle();
  system.radius.setConstant(0.1);
  const Eigen::Vector3d centre(0, -0.2, 0);
  const double distance = 0.5 + 0.1;  // sphere radius plus the particle's
  const BlockDescentSettings settings;
  const StoppingSettings stopping = converging(10000, 1e-9);
  BlockDescentSolver solver(system, settings);
  solver.setContactQuery(
      [&](const ParticleState&, double, ContactSet& contacts) {
        contacts.clear();
        contacts.obstacles.push_back({1, centre, distance});
      },
      false);
  ParticleState state = stateAt(system.rest_position);
  const SolveStats stats = solver.solve(state, stopping);
  EXPECT_TRUE(stats.converged);
  const double gap = (state.position.col(1) - centre).norm() - distance;
  // Pressed: the springs pull it down (about 2 x 5 N/m x 0.8 m), the contact holds it within force / stiffness.
  EXPECT_LT(gap, 0.0);
  EXPECT_GT(gap, -10.0 / solver.contactStiffness());
  EXPECT_NEAR(state.position(0, 1), 0.0, 1e-9);  // on the symmetry line
  // Without the sphere it would sink to the line between the ends.
  ParticleState free_state = stateAt(system.rest_position);
  BlockDescentSolver(system, settings).solve(free_state, stopping);
  EXPECT_NEAR(free_state.position(1, 1), 0.0, 1e-6);
}

TEST(BlockDescent, AHalfSpaceContactHoldsAParticleOnItsPlane) {
  // The same hung particle over a floor (a bone's field linearised): the plane y >= 0.3 holds it pressed on it.
  const MassSpringSystem system = hungParticle();
  BlockDescentSolver solver(system, {});
  solver.setContactQuery(
      [&](const ParticleState&, double, ContactSet& contacts) {
        contacts.clear();
        contacts.half_spaces.push_back({1, Eigen::Vector3d(0, 0.3, 0), Eigen::Vector3d::UnitY()});
      },
      true);
  ParticleState state = stateAt(system.rest_position);
  const SolveStats stats = solver.solve(state, converging(10000, 1e-9));
  EXPECT_TRUE(stats.converged);
  const double gap = state.position(1, 1) - 0.3;
  EXPECT_LT(gap, 0.0);
  EXPECT_GT(gap, -10.0 / solver.contactStiffness());
  EXPECT_NEAR(state.position(0, 1), 0.0, 1e-9);
}

TEST(BlockDescent, BonesAsDistanceFieldsKeepEveryParticleOutAfterALargePoseJumpOnAnyThreadCount) {
  const SyntheticScene scene = makeSyntheticThigh(4, 4);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.solver_kind = SolverKind::block_descent;
  const FrameStopping stopping = FrameStopping::of(StoppingSettings::afterIterations(10));
  settings.collision.bone_proxy = BoneProxyKind::distance_field;
  settings.model.tendons = false;  // the fixture's muscle ends are built to be fixed beside their bones
  Eigen::Matrix3Xd positions[2];
  for (const int threads : {1, 2}) {
    MuscleSimulation simulation(scene.muscles, scene.bones, settings, threads);
    ASSERT_EQ(simulation.boneFields().size(), scene.bones.size());
    const FrameStats rest = solvePose(simulation, syntheticThighPose(0, 0), StartMode::cold, stopping);
    EXPECT_EQ(rest.collision.muscle_bone_contacts, 0) << "the rest pose has no bone contact";
    const FrameStats jump = solvePose(simulation, syntheticThighPose(1.6, 2.0), StartMode::warm, stopping);
    EXPECT_TRUE(jump.finite);
    EXPECT_FALSE(jump.solver.diverged);
    // Every free particle (not only boundary ones) within a tenth of a millimetre of its clearance.
    EXPECT_LT(jump.collision.max_penetration_muscle_bone_m, 1e-4);
    positions[threads - 1] = simulation.state().position;
  }
  EXPECT_TRUE((positions[0].array() == positions[1].array()).all());  // bit for bit
}

TEST(BlockDescent, OneAndTwoThreadsGiveIdenticalPositions) {
  const SyntheticScene scene = makeSyntheticThigh(4, 4);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.solver_kind = SolverKind::block_descent;
  const FrameStopping stopping = FrameStopping::of(StoppingSettings::afterIterations(12));
  // Quasi-static; with a tissue drag and prediction; and with the drag, a toned belly and the coarse step along the
  // fibres (whose sums and energies are split among the threads).
  for (const int variant : {0, 1, 2}) {
    settings.block_descent.tissue_relaxation_s = variant == 0 ? 0.0 : 0.0005;
    settings.block_descent.fibre_modes = variant == 2 ? 4 : 0;
    settings.model.fibre_tone = variant == 2 ? 1.0 : 0.0;
    Eigen::Matrix3Xd positions[2];
    int contacts[2] = {0, 0}, fibre_steps[2] = {0, 0};
    for (const int threads : {1, 2}) {
      MuscleSimulation simulation(scene.muscles, scene.bones, settings, threads);
      solvePose(simulation, syntheticThighPose(0.4, 0.6), StartMode::cold, stopping);
      solvePose(simulation, syntheticThighPose(0.5, 0.7), StartMode::warm, stopping);
      const FrameStats stats = solvePose(simulation, syntheticThighPose(0.7, 1.0), StartMode::warm, stopping);
      positions[threads - 1] = simulation.state().position;
      contacts[threads - 1] = stats.solver.contacts;
      fibre_steps[threads - 1] = stats.solver.fibre_steps;
    }
    EXPECT_GT(contacts[0], 0);  // the case exercises contacts in the solve
    EXPECT_EQ(contacts[0], contacts[1]);
    if (variant == 2) EXPECT_GT(fibre_steps[0], 0) << "the coarse step took part";
    EXPECT_EQ(fibre_steps[0], fibre_steps[1]);
    EXPECT_TRUE((positions[0].array() == positions[1].array()).all()) << "variant " << variant;
  }
}

namespace {
// One free particle hanging from a fixed one by a spring of rest length 1 m and stiffness 1 N/m: without drag it may
// sit anywhere on the unit sphere. Carried to `carried`, with drag weight w = relaxation / interval (its summed spring
// stiffness is 1 N/m), the answer is the minimiser of 1/2 (|x| - 1)^2 + w/2 |x - y|^2: on the ray through y at
// r = (1 + w |y|) / (1 + w).
MassSpringSystem pendulum() {
  Eigen::Matrix3Xd positions(3, 2);
  positions << 0, 1, 0, 0, 0, 0;
  MassSpringSystem system = systemFromParticles(positions, {{0, 1}}, 1.0, 1.0);
  system.is_fixed[0] = 1;
  return system;
}
Eigen::Vector3d pendulumAnswer(const Eigen::Vector3d& carried, double weight) {
  return (1.0 + weight * carried.norm()) / (1.0 + weight) * carried.normalized();
}
}  // namespace

TEST(BlockDescent, TissueDragGivesAFloppyParticleOneAnswerTowardsWhereTheTissueCarriesIt) {
  const MassSpringSystem system = pendulum();
  BlockDescentSettings settings;
  settings.tissue_relaxation_s = 0.005;
  BlockDescentSolver solver(system, settings);
  solver.setFrameInterval(0.01);  // w = 0.5 N/m
  ParticleState state = stateAt(system.rest_position);
  const Eigen::Vector3d carried(1.5, 1.0, 0.2);
  state.carried_position = state.position;
  state.carried_position.col(1) = carried;
  const SolveStats stats = solver.solve(state, converging(200, 1e-12));
  EXPECT_TRUE(stats.converged);
  EXPECT_LT((state.position.col(1) - pendulumAnswer(carried, 0.5)).norm(), 1e-9);
  EXPECT_LT(solver.residualOf(state), 1e-9);  // the drag is part of the frame's balance
  ParticleState without_carried = state;
  without_carried.carried_position.resize(3, 0);
  EXPECT_GT(solver.residualOf(without_carried), 0.1);  // spring alone: stretched, so not in balance
}

TEST(BlockDescent, TissueDragWeighsByTheFrameIntervalWithinItsClamp) {
  const MassSpringSystem system = pendulum();
  BlockDescentSettings settings;
  settings.tissue_relaxation_s = 0.005;
  BlockDescentSolver solver(system, settings);
  const Eigen::Vector3d carried(0.2, 2.0, 0.0);
  const auto solveAt = [&](double interval_s) {
    solver.setFrameInterval(interval_s);
    ParticleState state = stateAt(system.rest_position);
    state.carried_position = state.position;
    state.carried_position.col(1) = carried;
    solver.solve(state, converging(200, 1e-12));
    return Eigen::Vector3d(state.position.col(1));
  };
  EXPECT_LT((solveAt(0.02) - pendulumAnswer(carried, 0.25)).norm(), 1e-9);
  EXPECT_LT((solveAt(1e-6) - pendulumAnswer(carried, 5.0)).norm(), 1e-9);   // clamped to 1 ms
  EXPECT_LT((solveAt(10.0) - pendulumAnswer(carried, 0.05)).norm(), 1e-9);  // clamped to 0.1 s
  EXPECT_DOUBLE_EQ(solver.frameInterval(), BlockDescentSolver::kMaxFrameIntervalS);
  BlockDescentSettings bad;
  bad.tissue_relaxation_s = -1;
  EXPECT_FALSE(validate(bad).empty());
}

namespace {
// A fibre of three particles 1 m apart along x, ends fixed, unit springs (1 N/m each): the middle particle's summed
// stiffness is 2 N/m, so with relaxation 0.005 s over 0.01 s its drag weight is w = 1 N/m. Carried along the fibre by
// d, it moves u = a w d / (2 + a w) with a = drag_along_fibre; carried across, the drag across is the same for any a.
MassSpringSystem threeParticleFibre() {
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, 3);
  positions.row(0) << 0, 1, 2;
  MassSpringSystem system = systemFromParticles(positions, {{0, 1}, {1, 2}}, 1.0, 1.0);
  system.is_fixed[0] = system.is_fixed[2] = 1;
  return system;
}
// With the across-fibre tie `tie`, its rest carried to `rest_carried`: the tie's weight on it is tau = 2 x tie N/m.
// With `balance` (not zero): the rest balance force on it (balance_rest_shape).
Eigen::Vector3d fibreMiddleAnswer(double drag_along_fibre, const Eigen::Vector3d& carried, double tie = 0.0,
                                  const Eigen::Vector3d& rest_carried = Eigen::Vector3d(1, 0, 0),
                                  const Eigen::Vector3d& balance = Eigen::Vector3d::Zero()) {
  BlockDescentSettings settings;
  settings.tissue_relaxation_s = 0.005;
  settings.drag_along_fibre = drag_along_fibre;
  settings.across_fibre_tie = tie;
  settings.balance_rest_shape = balance.squaredNorm() > 0;
  const MassSpringSystem system = threeParticleFibre();
  BlockDescentSolver solver(system, settings);
  solver.setFrameInterval(0.01);
  ParticleState state = stateAt(system.rest_position);
  state.carried_position = state.position;
  state.carried_position.col(1) = carried;
  state.rest_carried_position = state.position;
  state.rest_carried_position.col(1) = rest_carried;
  state.rest_balance_force = Eigen::Matrix3Xd::Zero(3, 3);
  state.rest_balance_force.col(1) = balance;
  const SolveStats stats = solver.solve(state, converging(500, 1e-12));
  EXPECT_TRUE(stats.converged) << "drag_along_fibre " << drag_along_fibre << ", tie " << tie;
  EXPECT_LT(solver.residualOf(state), 1e-10);
  return state.position.col(1);
}
}  // namespace

TEST(BlockDescent, DragAlongTheFibreIsItsOwnShareOfTheTissueDrag) {
  const Eigen::Vector3d along(1.3, 0, 0);
  for (const double a : {1.0, 0.25, 0.0}) {
    const Eigen::Vector3d x = fibreMiddleAnswer(a, along);
    EXPECT_NEAR(x.x() - 1.0, a * 0.3 / (2.0 + a), 1e-9) << "drag_along_fibre " << a;
    EXPECT_NEAR(x.tail<2>().norm(), 0.0, 1e-12);
  }
  // Across the fibre the drag is the whole drag whatever its share along.
  const Eigen::Vector3d across(1.0, 0.3, 0);
  const Eigen::Vector3d isotropic = fibreMiddleAnswer(1.0, across);
  EXPECT_GT(isotropic.y(), 0.25);  // the springs at their rest length barely resist a sideways move
  EXPECT_LT((fibreMiddleAnswer(0.0, across) - isotropic).norm(), 1e-9);
  EXPECT_LT((fibreMiddleAnswer(0.5, across) - isotropic).norm(), 1e-9);
  BlockDescentSettings bad;
  bad.drag_along_fibre = 1.5;
  EXPECT_FALSE(validate(bad).empty());
  bad.drag_along_fibre = -0.1;
  EXPECT_FALSE(validate(bad).empty());
}

namespace {
// The y at which the middle particle of threeParticleFibre(), held at x = 1 by symmetry, balances the drag across the
// fibre (weight 1 N/m towards carried_y), the tie (tau N/m towards rest_y) and its two unit springs at rest length 1,
// whose sideways pull is 2 (1 - 1 / sqrt(1 + y^2)) y: by bisection, independent of the solver.
double balancedAcross(double carried_y, double tau, double rest_y) {
  const auto net = [&](double y) {
    return (carried_y - y) + tau * (rest_y - y) - 2.0 * (1.0 - 1.0 / std::sqrt(1.0 + y * y)) * y;
  };
  double low = -1.0, high = 1.0;  // net(low) > 0 > net(high)
  for (int i = 0; i < 200; ++i) (net(0.5 * (low + high)) > 0 ? low : high) = 0.5 * (low + high);
  return 0.5 * (low + high);
}
}  // namespace

TEST(BlockDescent, TheAcrossFibreTiePullsAcrossTheFibreOnlyTowardsTheRestTheBonesCarry) {
  // Carried along the fibre: the tie takes nothing, whatever the drag's share along it.
  for (const double a : {1.0, 0.25}) {
    const Eigen::Vector3d x = fibreMiddleAnswer(a, Eigen::Vector3d(1.3, 0, 0), 0.5, Eigen::Vector3d(1, 0, 0));
    EXPECT_NEAR(x.x() - 1.0, a * 0.3 / (2.0 + a), 1e-9) << "drag_along_fibre " << a;
    EXPECT_NEAR(x.tail<2>().norm(), 0.0, 1e-12);
  }
  // Carried across: the tie (tau = 1 N/m) holds the particle back towards its rest, as the balance of forces says.
  const Eigen::Vector3d across = fibreMiddleAnswer(1.0, Eigen::Vector3d(1, 0.3, 0), 0.5, Eigen::Vector3d(1, 0, 0));
  EXPECT_NEAR(across.y(), balancedAcross(0.3, 1.0, 0.0), 1e-9);
  EXPECT_NEAR(across.x(), 1.0, 1e-9);
  EXPECT_LT(across.y(), 0.8 * fibreMiddleAnswer(1.0, Eigen::Vector3d(1, 0.3, 0)).y());
  // A rest that lies off along the fibre as well as across: only the part across pulls, with a drag of any share.
  for (const double a : {1.0, 0.25, 0.0}) {
    const Eigen::Vector3d x = fibreMiddleAnswer(a, Eigen::Vector3d(1, 0, 0), 2.0, Eigen::Vector3d(1.2, -0.1, 0));
    EXPECT_NEAR(x.x(), 1.0, 1e-9) << "drag_along_fibre " << a;
    EXPECT_NEAR(x.y(), balancedAcross(0.0, 4.0, -0.1), 1e-9) << "drag_along_fibre " << a;
  }
}

TEST(BlockDescent, TheAcrossFibreTieIsRefusedWithoutTheDragAndWithoutTheRestItTiesTo) {
  BlockDescentSettings bad;
  bad.across_fibre_tie = -0.1;
  bad.tissue_relaxation_s = 0.001;
  EXPECT_NE(validate(bad).find("across_fibre_tie"), std::string::npos);
  bad.across_fibre_tie = 0.01;
  bad.tissue_relaxation_s = 0;
  EXPECT_NE(validate(bad).find("across_fibre_tie"), std::string::npos);
  bad.tissue_relaxation_s = 0.001;
  EXPECT_TRUE(validate(bad).empty());
  const MassSpringSystem system = threeParticleFibre();
  BlockDescentSolver solver(system, bad);
  ParticleState state = stateAt(system.rest_position);
  state.carried_position = state.position;  // and no rest_carried_position
  EXPECT_THROW(solver.solve(state, converging(10, 1e-9)), std::invalid_argument);
}

namespace {
// A fibre of kArcParticles particles on an arc (radius 0.1 m about (0, -centre_drop), 1.2 rad), ends fixed, its
// springs' rest lengths 0.8 of their length: a pre-tensioned curved belly.
constexpr int kArcParticles = 9;
MassSpringSystem preTensionedArc(double centre_drop) {
  Eigen::Matrix3Xd arc = Eigen::Matrix3Xd::Zero(3, kArcParticles);
  ParticlePairs springs;
  for (int i = 0; i < kArcParticles; ++i) {
    const double angle = -0.6 + 1.2 * i / (kArcParticles - 1);
    arc.col(i) << 0.1 * std::sin(angle), 0.1 * std::cos(angle) - centre_drop, 0;
  }
  for (int i = 0; i + 1 < kArcParticles; ++i) springs.emplace_back(i, i + 1);
  MassSpringSystem system = systemFromParticles(arc, springs, 1e-3, 10.0);
  system.is_fixed[0] = system.is_fixed[kArcParticles - 1] = 1;
  system.springs.rest_length *= 0.8;
  return system;
}
}  // namespace

TEST(BlockDescent, TheAcrossFibreTieHoldsAPreTensionedCurvedFibreNearItsShapeAtRest) {
  // The pre-tensioned arc, its chord on y = 0 (sagitta 17.5 mm). Held still and solved one sweep a frame with the drag
  // anchored where the frame before ended (the stream at rest), the tension pulls the belly towards its chord and the
  // drag only slows that; the tie stops it where its pull across balances the tension's.
  constexpr int kParticles = kArcParticles;
  const MassSpringSystem system = preTensionedArc(0.1 * std::cos(0.6));
  const double sagitta = system.rest_position(1, kParticles / 2);
  const auto heldStill = [&](double tie, int frames, double& last_change, bool balanced = false) {
    BlockDescentSettings settings;
    settings.tissue_relaxation_s = 0.001;
    settings.across_fibre_tie = tie;
    settings.balance_rest_shape = balanced;
    BlockDescentSolver solver(system, settings);
    solver.setFrameInterval(1.0 / 60.0);
    ParticleState state = stateAt(system.rest_position);
    state.rest_carried_position = system.rest_position;
    state.rest_balance_force = restBalanceForces(system);
    for (int frame = 0; frame < frames; ++frame) {
      const Eigen::Matrix3Xd before = state.position;
      state.carried_position = state.position;
      solver.solve(state, converging(1, 0.0));
      last_change = (state.position - before).colwise().norm().maxCoeff();
    }
    return state.position(1, kParticles / 2);
  };
  double untied_change = 0, tied_change = 0;
  const double untied = heldStill(0.0, 3000, untied_change);
  const double tied = heldStill(0.03, 3000, tied_change);
  std::printf("middle's sagitta after 3000 frames: %.2f mm untied, %.2f mm tied (rest %.2f mm); last frame's change "
              "%.2g / %.2g m\n", 1e3 * untied, 1e3 * tied, 1e3 * sagitta, untied_change, tied_change);
  EXPECT_LT(untied, 0.3 * sagitta) << "the untied fibre creeps towards its chord";
  EXPECT_GT(tied, 0.5 * sagitta) << "the tie holds the belly near its shape";  // 0.70 of it measured
  EXPECT_LT(tied_change, 1e-9) << "and it has stopped moving";
  // With the rest balance the arc is the equilibrium: it does not move at all.
  double balanced_change = 0;
  const double balanced = heldStill(0.03, 100, balanced_change, true);
  EXPECT_NEAR(balanced, sagitta, 1e-12);
  EXPECT_LT(balanced_change, 1e-14);
}

TEST(BlockDescent, TheRestBalanceIsTheSpringsPullAtRestReversed) {
  // The pre-tensioned arc of the test above: each free particle's balance points away from the arc's centre (the
  // tension's pull towards the chord reversed), 2 T sin(half the angle between segments) with T = k (l - l0).
  constexpr int kParticles = kArcParticles;
  const MassSpringSystem system = preTensionedArc(0.0);  // centred on the origin
  const Eigen::Matrix3Xd& arc = system.rest_position;
  const Eigen::Matrix3Xd balance = restBalanceForces(system);
  const double segment = (arc.col(1) - arc.col(0)).norm();
  const double tension = system.springs.stiffness[0] * (segment - system.springs.rest_length[0]);
  const double expected = 2.0 * tension * std::sin(0.5 * 1.2 / (kParticles - 1));
  for (int i = 1; i + 1 < kParticles; ++i) {
    EXPECT_NEAR(balance.col(i).norm(), expected, 1e-9 * expected) << "particle " << i;
    EXPECT_NEAR(balance.col(i).normalized().dot(arc.col(i).normalized()), 1.0, 1e-12) << "outwards, particle " << i;
  }
  EXPECT_EQ(balance.col(0).norm(), 0.0);  // fixed
}

TEST(BlockDescent, TheRestBalanceIsAConstantForceOnTheParticleAlongAndAcrossItsFibre) {
  // The three-particle fibre's middle particle (drag 1 N/m, the tie 1 N/m across) with a balance force b: the balance of
  // forces, solved independently, is the one without b with the carried position moved by b / (drag weight) across
  // (balancedAcross), and along the fibre a (c - 1) + b - 2 (x - 1) = 0.
  for (const double a : {1.0, 0.25}) {
    const Eigen::Vector3d x = fibreMiddleAnswer(a, Eigen::Vector3d(1, 0, 0), 0.5, Eigen::Vector3d(1, 0, 0),
                                                Eigen::Vector3d(0.2, 0, 0));
    EXPECT_NEAR(x.x() - 1.0, 0.2 / (2.0 + a), 1e-9) << "drag_along_fibre " << a;
    EXPECT_NEAR(x.tail<2>().norm(), 0.0, 1e-12);
    const Eigen::Vector3d across = fibreMiddleAnswer(a, Eigen::Vector3d(1, 0.05, 0), 0.5, Eigen::Vector3d(1, 0, 0),
                                                     Eigen::Vector3d(0, 0.1, 0));
    EXPECT_NEAR(across.y(), balancedAcross(0.15, 1.0, 0.0), 1e-9) << "drag_along_fibre " << a;
    EXPECT_NEAR(across.x(), 1.0, 1e-9);
  }
}

TEST(BlockDescent, TheRestBalanceNeedsADragAlongTheFibreToRideOn) {
  BlockDescentSettings settings;
  settings.tissue_relaxation_s = 0.001;
  settings.across_fibre_tie = 0.03;
  settings.balance_rest_shape = true;
  EXPECT_TRUE(validate(settings).empty());
  settings.drag_along_fibre = 0.0;
  EXPECT_NE(validate(settings).find("balance_rest_shape"), std::string::npos);
  settings.across_fibre_tie = 0.0;  // without the tie the balance is not used
  EXPECT_TRUE(validate(settings).empty());
  // Tied and balanced, a state without the balance forces is refused.
  settings.across_fibre_tie = 0.03;
  settings.drag_along_fibre = 1.0;
  const MassSpringSystem system = threeParticleFibre();
  BlockDescentSolver solver(system, settings);
  ParticleState state = stateAt(system.rest_position);
  state.carried_position = state.position;
  state.rest_carried_position = state.position;
  EXPECT_THROW(solver.solve(state, converging(10, 1e-9)), std::invalid_argument);
}

TEST(BlockDescent, SweepCostCountsWhatEachParticleSpringAndContactMoves) {
  // A chain of 11 particles, ends fixed: 9 free particles with 18 packed springs between them, no contacts. Per free
  // particle 144 bytes (position read and written, carried position, seven doubles, four indices) and 71 flops (drag 12,
  // solve 45, residual 5, step 9); per packed spring 24 bytes and 46 flops; the two fixed positions 48 bytes.
  Eigen::Matrix3Xd positions = Eigen::Matrix3Xd::Zero(3, 11);
  ParticlePairs springs;
  for (int i = 0; i < 11; ++i) positions(0, i) = 0.01 * i;
  for (int i = 0; i < 10; ++i) springs.emplace_back(i, i + 1);
  MassSpringSystem system = systemFromParticles(positions, springs, 1.0, 1.0);
  system.is_fixed[0] = system.is_fixed[10] = 1;
  BlockDescentSolver solver(system, BlockDescentSettings{});
  const BlockDescentSolver::SweepCost cost = solver.sweepCost(stateAt(system.rest_position));
  EXPECT_DOUBLE_EQ(cost.bytes, 9 * 144 + 18 * 24 + 2 * 24);
  EXPECT_DOUBLE_EQ(cost.flops, 9 * 71 + 18 * 46);
  // The drag along the fibre reads each particle's fibre direction and costs 34 flops more.
  BlockDescentSettings along;
  along.drag_along_fibre = 0.5;
  BlockDescentSolver anisotropic(system, along);
  const BlockDescentSolver::SweepCost with_direction = anisotropic.sweepCost(stateAt(system.rest_position));
  EXPECT_DOUBLE_EQ(with_direction.bytes - cost.bytes, 9 * 24);
  EXPECT_DOUBLE_EQ(with_direction.flops - cost.flops, 9 * 34);
}

TEST(BlockDescent, ThePredictedStartChangesWhereSweepsBeginNotTheFramesAnswer) {
  const SyntheticScene scene = makeSyntheticThigh(4, 4);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.solver_kind = SolverKind::block_descent;
  settings.block_descent.tissue_relaxation_s = 0.0005;
  const FrameStopping stopping = FrameStopping::of(converging(5000, 1e-9));
  // No prediction; the last correction carried on; and that plus half its last change (predict_extrapolation).
  Eigen::Matrix3Xd answers[3];
  int last_sweeps[3] = {0, 0, 0};
  for (const int variant : {0, 1, 2}) {
    settings.prediction.predict_start = variant > 0;
    settings.prediction.predict_extrapolation = variant == 2 ? 0.5 : 0.0;
    MuscleSimulation simulation(scene.muscles, scene.bones, settings);
    solvePose(simulation, syntheticThighPose(0.0, 0.0), StartMode::cold, stopping);
    for (int frame = 1; frame <= 4; ++frame) {
      const FrameStats stats =
          solvePose(simulation, syntheticThighPose(0.05 * frame, 0.08 * frame), StartMode::warm, stopping);
      ASSERT_TRUE(stats.solver.converged) << "variant " << variant << ", frame " << frame;
      if (frame == 4) last_sweeps[variant] = stats.solver.iterations;
    }
    answers[variant] = simulation.state().position;
  }
  std::printf("sweeps to converge the last frame: no prediction %d, correction carried %d, and half its change %d\n",
              last_sweeps[0], last_sweeps[1], last_sweeps[2]);
  EXPECT_LT((answers[0] - answers[1]).colwise().norm().maxCoeff(), 1e-6);  // metres: one answer
  EXPECT_LT((answers[0] - answers[2]).colwise().norm().maxCoeff(), 1e-6);
  EXPECT_LT(last_sweeps[1], last_sweeps[0]);  // the prediction starts closer to it
}

TEST(BlockDescent, PredictExtrapolationBeyondWhatStaysStableIsRefused) {
  StartPrediction settings;
  settings.predict_extrapolation = 0.75;
  EXPECT_TRUE(validate(settings).empty());
  settings.predict_extrapolation = 1.0;  // linear extrapolation diverged on the bundled gait
  EXPECT_NE(validate(settings).find("predict_extrapolation"), std::string::npos);
  settings.predict_extrapolation = -0.1;
  EXPECT_FALSE(validate(settings).empty());
}

TEST(BlockDescent, AThreadCapIsReadBeforeEverySweepAndMovesNoParticle) {
  const MassSpringSystem system = fixedChain(40);
  ParticleState start = stateAt(system.rest_position);
  start.position(0, 40) = 60.0;
  StoppingSettings stopping = StoppingSettings::afterIterations(50);
  std::atomic<int> cap{0};
  stopping.limits.max_threads = &cap;
  BlockDescentSolver solver(system, {}, 2);
  EXPECT_EQ(solver.sweepThreads(stopping.limits), 2);  // 0: no cap
  cap = 1;
  EXPECT_EQ(solver.sweepThreads(stopping.limits), 1);
  cap = 8;
  EXPECT_EQ(solver.sweepThreads(stopping.limits), 2);  // a cap above the solver's own count changes nothing

  ParticleState capped = start, free_running = start;
  cap = 1;
  solver.solve(capped, stopping);
  cap = 0;
  solver.solve(free_running, stopping);
  EXPECT_TRUE((capped.position.array() == free_running.position.array()).all());  // bit for bit
}

TEST(BlockDescent, WithMeasuredThreadsOneThreadAndEveryCoreAreBothMeasuredAgainAndMoveNoParticle) {
  const MassSpringSystem system = fixedChain(40);
  const StoppingSettings stopping = StoppingSettings::afterIterations(1);  // one sweep per solve: a frame at the
                                                                         // node's budget
  BlockDescentSolver measured(system, {}, BlockDescentSolver::kThreadsMeasured);
  if (measured.threadCount() < 2) GTEST_SKIP() << "one core: nothing to choose";
  BlockDescentSolver single(system, {}, 1);
  ParticleState a = stateAt(system.rest_position), b = a;
  a.position(0, 40) = b.position(0, 40) = 60.0;
  // Every core first, then one thread, then the faster with the slower again every kThreadProbeInterval sweeps.
  EXPECT_EQ(measured.sweepThreads(), measured.threadCount());
  int on_one = 0, on_every = 0;
  const int solves = 2 * BlockDescentSolver::kThreadProbeInterval + 4;
  for (int k = 0; k < solves; ++k) {
    const int threads = measured.sweepThreads();
    if (k == 1) EXPECT_EQ(threads, 1);
    (threads == 1 ? on_one : on_every) += 1;
    measured.solve(a, stopping);
    single.solve(b, stopping);
  }
  EXPECT_GE(std::min(on_one, on_every), 3) << "the slower is measured again";
  EXPECT_TRUE((a.position.array() == b.position.array()).all());  // bit for bit
}

TEST(BlockDescent, AFrameAfterALargePoseJumpStaysFiniteAndOutOfTheBones) {
  const SyntheticScene scene = makeSyntheticThigh(4, 4);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.solver_kind = SolverKind::block_descent;
  const FrameStopping stopping = FrameStopping::of(StoppingSettings::afterIterations(10));
  MuscleSimulation simulation(scene.muscles, scene.bones, settings);
  solvePose(simulation, syntheticThighPose(0, 0), StartMode::cold, stopping);
  const FrameStats stats =
      solvePose(simulation, syntheticThighPose(1.6, 2.0), StartMode::warm, stopping);  // ~90 and ~115 degrees
  EXPECT_TRUE(stats.finite);
  EXPECT_FALSE(stats.solver.diverged);
  EXPECT_TRUE(simulation.state().position.allFinite());
  EXPECT_LE(stats.collision.max_penetration_muscle_bone_m, simulation.system().medianCollisionRadius());
}

TEST(BlockDescent, TimeBudgetNeverStartsASweepPastItButAlwaysTakesOne) {
  const MassSpringSystem system = fixedChain(10);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 10) = 15.0;
  // No time at all: still one sweep, and no second.
  const StoppingSettings stopping = StoppingSettings::withinBudget(0.0, 1000);
  BlockDescentSolver solver(system, {});
  const SolveStats stats = solver.solve(state, stopping);
  EXPECT_EQ(stats.iterations, 1);
  EXPECT_TRUE(stats.stopping_rule_met);
  // A deadline is not convergence: converged is the residual criterion, which one sweep from this start is far from.
  EXPECT_FALSE(stats.converged);
  EXPECT_GT(stats.residual, stopping.residual_tolerance);
}

TEST(BlockDescent, ResidualOfMeasuresAnyStateAndIsSmallAtTheSolversEquilibrium) {
  const MassSpringSystem system = fixedChain(10);
  ParticleState state = stateAt(system.rest_position);
  state.position(0, 10) = 15.0;
  BlockDescentSolver solver(system, {});
  const double before = solver.residualOf(state);
  // Only particle 9 is loaded: its link to the end moved from x = 10 to 15 is 6 m long at rest length 1 m, so it pulls
  // with 5 N (stiffness 1 N/m). The RMS over the 9 free particles is 5 / 3 N, relative to the material constant 1 N.
  EXPECT_NEAR(before, 5.0 / 3.0, 1e-12);
  solver.solve(state, converging(100000, 1e-9));
  EXPECT_LT(solver.residualOf(state), 1e-8);
}

// A fibre of 40 links between fixed ends whose far end is pulled 20 % out: point sweeps see each particle's neighbours
// held, so the uniform stretch travels along the fibre one link per sweep; the coarse step along the fibre (hat
// functions of the position along it) moves the whole fibre at once. Both reach the same equilibrium.
TEST(BlockDescent, TheCoarseStepAlongTheFibresStretchesAWholeFibreAtOnceAndKeepsItsEquilibrium) {
  const int links = 40;
  MassSpringSystem system = fixedChain(links);
  system.fibre_of.assign(static_cast<std::size_t>(links) + 1, 0);
  system.sample_of.resize(static_cast<std::size_t>(links) + 1);
  for (int i = 0; i <= links; ++i) system.sample_of[static_cast<std::size_t>(i)] = i;
  const auto pulled = [&] {
    ParticleState state = stateAt(system.rest_position);
    state.position(0, links) = 1.2 * links;
    return state;
  };
  double residual_after_five[2] = {0, 0};
  for (const int modes : {0, 5}) {
    BlockDescentSettings settings;
    settings.fibre_modes = modes;
    BlockDescentSolver solver(system, settings);
    ParticleState state = pulled();
    const SolveStats five = solver.solve(state, StoppingSettings::afterIterations(5));
    residual_after_five[modes > 0] = five.residual;
    if (modes > 0) EXPECT_GT(five.fibre_steps, 0);
    const SolveStats settled = solver.solve(state, converging(100000, 1e-9));
    EXPECT_TRUE(settled.converged) << modes << " modes";
    for (int i = 0; i <= links; ++i) EXPECT_NEAR(state.position(0, i), 1.2 * i, 1e-6) << modes << " modes";
  }
  std::printf("residual after 5 sweeps: %.3e point sweeps alone, %.3e with the coarse step along the fibre\n",
              residual_after_five[0], residual_after_five[1]);
  EXPECT_LT(residual_after_five[1], 0.1 * residual_after_five[0]);
}

TEST(BlockDescent, FibreModesOutsideTheirRangeAreRefused) {
  BlockDescentSettings settings;
  for (const int modes : {-1, 1, 17}) {
    settings.fibre_modes = modes;
    EXPECT_FALSE(validate(settings).empty()) << modes;
  }
  settings.fibre_modes = 4;
  EXPECT_TRUE(validate(settings).empty());
}

// The hung particle pressed onto a sphere that is another muscle's (fixed) particle instead of a bone's: the pair's
// stiffness follows muscle_contact_stiffness_scale, a bone's keeps contact_stiffness_scale. Here either stiffness is
// scale x 10 N/m (material constant 1 N over the radius 0.1 m, and scale x the particle's summed spring stiffness of
// 10 N/m: the same), and at equilibrium the contact's push, stiffness x depth, balances the springs' pull.
TEST(BlockDescent, AMuscleMuscleContactTakesItsOwnStiffnessScaleAndABonesContactKeepsTheOther) {
  Eigen::Matrix3Xd positions(3, 4);
  positions << -1, 0, 1, 0,  //
      0, 0.8, 0, -0.2,        //
      0, 0, 0, 0;
  MassSpringSystem system = systemFromParticles(positions, {{0, 1}, {1, 2}}, 1.0, 1.0);
  system.springs.rest_length.setConstant(0.2);
  system.springs.stiffness.setConstant(5.0);
  system.is_fixed[0] = system.is_fixed[2] = system.is_fixed[3] = 1;
  system.radius.setConstant(0.1);
  const Eigen::Vector3d centre(0, -0.2, 0);
  const double distance = 0.6;  // the two particles' radii plus 0.4 m: the partner stands for a large sphere
  const StoppingSettings stopping = converging(10000, 1e-10);
  struct Balance {
    double depth, pull;
  };
  const auto solveWith = [&](const BlockDescentSettings& settings, bool pair) {
    BlockDescentSolver solver(system, settings);
    solver.setContactQuery(
        [&](const ParticleState&, double, ContactSet& contacts) {
          contacts.clear();
          if (pair) contacts.pairs.push_back({1, 3, distance});
          else contacts.obstacles.push_back({1, centre, distance});
        },
        false);
    ParticleState state = stateAt(system.rest_position);
    EXPECT_TRUE(solver.solve(state, stopping).converged);
    const Eigen::Vector3d x = state.position.col(1);
    Eigen::Vector3d pull = Eigen::Vector3d::Zero();
    for (const int end : {0, 2}) {
      const Eigen::Vector3d d = state.position.col(end) - x;
      pull += 5.0 * (d.norm() - 0.2) * d.normalized();
    }
    return Balance{distance - (x - centre).norm(), pull.norm()};
  };
  BlockDescentSettings soft_pairs;
  soft_pairs.muscle_contact_stiffness_scale = 10.0;
  const double stiff = 10.0 * soft_pairs.contact_stiffness_scale, soft = 10.0 * 10.0;
  const Balance pair_default = solveWith(BlockDescentSettings{}, true), pair_soft = solveWith(soft_pairs, true);
  ASSERT_GT(pair_default.depth, 0.0);
  EXPECT_NEAR(stiff * pair_default.depth, pair_default.pull, 1e-6 * pair_default.pull);
  EXPECT_NEAR(soft * pair_soft.depth, pair_soft.pull, 1e-6 * pair_soft.pull);
  EXPECT_GT(pair_soft.depth, 9.0 * pair_default.depth);  // softer by 10x, the springs' pull nearly the same
  const Balance obstacle_default = solveWith(BlockDescentSettings{}, false), obstacle_soft = solveWith(soft_pairs, false);
  EXPECT_EQ(obstacle_soft.depth, obstacle_default.depth);
  EXPECT_NEAR(stiff * obstacle_soft.depth, obstacle_soft.pull, 1e-6 * obstacle_soft.pull);
  // 0 means the contact scale: the same answer as setting it equal.
  BlockDescentSettings equal;
  equal.muscle_contact_stiffness_scale = equal.contact_stiffness_scale;
  EXPECT_EQ(solveWith(equal, true).depth, pair_default.depth);
}

TEST(BlockDescent, ANegativeOrNonFiniteMuscleContactScaleIsRefused) {
  BlockDescentSettings settings;
  for (const double scale : {-1.0, std::nan(""), HUGE_VAL}) {
    settings.muscle_contact_stiffness_scale = scale;
    EXPECT_NE(validate(settings).find("muscle_contact_stiffness_scale"), std::string::npos) << scale;
  }
  settings.muscle_contact_stiffness_scale = 0.0;
  EXPECT_TRUE(validate(settings).empty());
  settings.muscle_contact_stiffness_scale = 30.0;
  EXPECT_TRUE(validate(settings).empty());
}
