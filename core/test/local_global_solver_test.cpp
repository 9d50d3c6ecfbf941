// Local/global implicit mass-spring solver (Liu et al. 2013) with the Projective Dynamics volume term, on small
// analytic systems.
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/core/model/spring_layout.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "../src/pipeline/muscle_simulation.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

using namespace muscle_deformation;
using muscle_deformation::testing::stateAt;
using muscle_deformation::testing::solvePose;

namespace {

double springEnergy(const MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
  double energy = 0;
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    const double length = (position.col(system.springs.second[s]) - position.col(system.springs.first[s])).norm();
    energy += 0.5 * system.springs.stiffness[e] * std::pow(length - system.springs.rest_length[e], 2);
  }
  return energy;
}

// A straight chain of `links` unit springs along x, both ends fixed.
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

// A side x side x side grid of unit spacing, jittered (so that its Delaunay tetrahedralisation is not degenerate),
// joined by the Delaunay edges; the bottom (z = 0) and top layers are fixed.
MassSpringSystem jitteredCube(int side) {
  std::mt19937 random(7);
  std::uniform_real_distribution<double> jitter(-0.15, 0.15);
  Eigen::Matrix3Xd positions(3, side * side * side);
  int i = 0;
  for (int z = 0; z < side; ++z)
    for (int y = 0; y < side; ++y)
      for (int x = 0; x < side; ++x, ++i) {
        const bool face = z == 0 || z == side - 1;
        positions.col(i) = Eigen::Vector3d(x + jitter(random), y + jitter(random), face ? z : z + jitter(random));
      }
  MassSpringSystem system = systemFromParticles(positions, delaunayPairs(positions), 1.0, 10.0);
  for (Eigen::Index p = 0; p < system.particleCount(); ++p)
    if (positions(2, p) == 0 || positions(2, p) == side - 1) system.is_fixed[static_cast<std::size_t>(p)] = 1;
  return system;
}

// The cube with its top layer pushed down to `height` (the squeeze the pose imposes on the fixed particles).
ParticleState squeezedCube(const MassSpringSystem& system, int side, double height) {
  ParticleState state = stateAt(system.rest_position);
  for (Eigen::Index p = 0; p < system.particleCount(); ++p)
    state.position(2, p) *= height / (side - 1);
  state.previous_position = state.position;
  return state;
}

// A length x 3 x 3 jittered grid along x joined by its Delaunay edges, the particles of both end layers fixed; the
// far end's fixed particles turned by `angle_rad` about z through the near end: a bent beam, the soft mode along
// which plain local/global iterations crawl.
std::pair<MassSpringSystem, ParticleState> bentBeam(int length, double angle_rad) {
  std::mt19937 random(11);
  std::uniform_real_distribution<double> jitter(-0.15, 0.15);
  Eigen::Matrix3Xd positions(3, length * 9);
  int i = 0;
  for (int x = 0; x < length; ++x)
    for (int y = 0; y < 3; ++y)
      for (int z = 0; z < 3; ++z, ++i) {
        const bool end = x == 0 || x == length - 1;
        positions.col(i) = Eigen::Vector3d(end ? x : x + jitter(random), y + jitter(random), z + jitter(random));
      }
  MassSpringSystem system = systemFromParticles(positions, delaunayPairs(positions), 1.0, 10.0);
  ParticleState state = stateAt(system.rest_position);
  const Eigen::AngleAxisd turn(angle_rad, Eigen::Vector3d::UnitZ());
  for (Eigen::Index p = 0; p < system.particleCount(); ++p) {
    if (positions(0, p) == 0) system.is_fixed[static_cast<std::size_t>(p)] = 1;
    if (positions(0, p) == length - 1) {
      system.is_fixed[static_cast<std::size_t>(p)] = 1;
      state.position.col(p) = turn * positions.col(p);
    }
  }
  state.previous_position = state.position;
  return {system, state};
}

LocalGlobalSettings quasiStatic() {
  LocalGlobalSettings settings;
  settings.quasi_static = true;
  return settings;
}

// Until the mean step falls below `tolerance_m` (and stops growing), at most `max_iterations` iterations.
StoppingSettings settling(int max_iterations, double tolerance_m) {
  return StoppingSettings::atDisplacement(tolerance_m, max_iterations);
}

}  // namespace

TEST(LocalGlobalSolver, ImplicitSolveOfSingleSpringConvergesToRestLength) {
  Eigen::Matrix3Xd positions(3, 2);
  positions << 0, 1, 0, 0, 0, 0;
  const MassSpringSystem system = systemFromParticles(positions, {{0, 1}}, 1.0, 1.0);
  for (const bool quasi_static : {true, false}) {
    LocalGlobalSettings settings = quasiStatic();
    settings.quasi_static = quasi_static;
    settings.time_step_s = 0.1;
    settings.damping = 0.2;
    LocalGlobalSolver solver(system, settings);
    ParticleState state = stateAt(positions);
    state.position(0, 1) = 1.5;  // stretched by half its rest length
    state.previous_position = state.position;
    const SolveStats stats = solver.solve(state, settling(2000, 1e-12));
    EXPECT_TRUE(stats.stopping_rule_met) << "quasi_static " << quasi_static;
    EXPECT_NEAR((state.position.col(1) - state.position.col(0)).norm(), 1.0, 1e-6) << "quasi_static " << quasi_static;
    // Equal masses, no external force: the centre stays where it was.
    EXPECT_NEAR(0.5 * (state.position(0, 0) + state.position(0, 1)), 0.75, 1e-6);
  }
}

TEST(LocalGlobalSolver, ChainBetweenTwoFixedParticlesReachesUniformStrain) {
  const int links = 10;
  const MassSpringSystem system = fixedChain(links);
  LocalGlobalSolver solver(system, quasiStatic());
  ParticleState state = stateAt(system.rest_position);
  state.position(0, links) = 15.0;  // the end pulled from 10 to 15: every link strained by 0.5 at equilibrium
  state.position(1, 3) = 0.3;       // and a sideways kink the springs must straighten
  const SolveStats stats = solver.solve(state, settling(5000, 1e-13));
  EXPECT_TRUE(stats.stopping_rule_met);
  for (int i = 0; i <= links; ++i) {
    EXPECT_NEAR(state.position(0, i), 1.5 * i, 1e-6) << "particle " << i;
    EXPECT_NEAR(state.position(1, i), 0.0, 1e-6) << "particle " << i;
  }
  EXPECT_NEAR(stats.mean_strain, 0.5, 1e-6);
  EXPECT_NEAR(stats.max_strain, 0.5, 1e-6);
}

TEST(LocalGlobalSolver, LargeTimeStepsStayStableWhereVerletBlowsUp) {
  const int side = 5;
  const MassSpringSystem system = jitteredCube(side);
  const double bound = stabilityTimeStep(system);
  const ParticleState start = squeezedCube(system, side, 3.0);
  const double start_energy = springEnergy(system, start.position);

  for (const double factor : {10.0, 100.0}) {
    VerletSettings verlet_settings;
    verlet_settings.mass_rule = MassRule::uniform;
    verlet_settings.dt_s = factor * bound;
    VerletSolver verlet(system, verlet_settings);
    ParticleState verlet_state = start;
    // Verlet diverges at these steps; it now notices, restores its start and retries with halved steps.
    const SolveStats verlet_stats = verlet.solve(verlet_state, StoppingSettings::afterIterations(200));
    EXPECT_GT(verlet_stats.divergence_recoveries, 0) << "Verlet at " << factor << "x its stability bound";
    EXPECT_LT(verlet_stats.time_step_s, bound * 2) << "Verlet at " << factor << "x its stability bound";

    LocalGlobalSettings settings;
    settings.quasi_static = false;
    settings.time_step_s = factor * bound;
    LocalGlobalSolver solver(system, settings);
    ParticleState state = start;
    // Step by step: the energy must never exceed the start's (implicit Euler only dissipates from rest).
    double max_energy = 0;
    const AfterUpdateHook watch = [&](ParticleState& s) {
      max_energy = std::max(max_energy, springEnergy(system, s.position));
      return 0;
    };
    const SolveStats stats = solver.solve(state, settling(2000, 1e-9), watch);
    EXPECT_TRUE(state.position.allFinite()) << factor << "x";
    EXPECT_LE(max_energy, start_energy) << factor << "x";
    EXPECT_TRUE(stats.stopping_rule_met) << factor << "x: " << stats.iterations << " iterations";
    EXPECT_LT(springEnergy(system, state.position), start_energy) << factor << "x";
  }
}

TEST(LocalGlobalSolver, QuasiStaticAndDynamicModesReachTheSameEquilibrium) {
  const int side = 4;
  const MassSpringSystem system = jitteredCube(side);
  const ParticleState start = squeezedCube(system, side, 2.2);
  ParticleState quasi_state = start, dynamic_state = start;
  LocalGlobalSolver quasi(system, quasiStatic());
  LocalGlobalSettings dynamic_settings = quasiStatic();
  dynamic_settings.quasi_static = false;
  dynamic_settings.time_step_s = 0.5;
  dynamic_settings.damping = 0.3;
  LocalGlobalSolver dynamic(system, dynamic_settings);
  EXPECT_TRUE(quasi.solve(quasi_state, settling(20000, 1e-12)).stopping_rule_met);
  EXPECT_TRUE(dynamic.solve(dynamic_state, settling(20000, 1e-12)).stopping_rule_met);
  EXPECT_LT((quasi_state.position - dynamic_state.position).cwiseAbs().maxCoeff(), 1e-4);
}

TEST(LocalGlobalSolver, VolumeTermKeepsCompressedCubeVolumeWithinFourPercent) {
  // A 6 x 6 x 6 cube squeezed to 70 % of its height between its fixed bottom and top layers (which cannot spread).
  // Springs alone lose about a third of the volume (the Delaunay spring network barely bulges); the volume term
  // (weight 20 relative to the springs, tolerance 0.5 %) must keep the summed tetrahedron volume within 4 % of the
  // rest volume, and below an eighth of the springs-only error.
  const int side = 6;
  const MassSpringSystem system = jitteredCube(side);
  const ParticleState start = squeezedCube(system, side, 0.7 * (side - 1));
  const MuscleTetrahedra tetrahedra = buildMuscleTetrahedra(system);
  ASSERT_GT(tetrahedra.tetrahedra.size(), 100u);

  auto volumeError = [&](double weight) {
    LocalGlobalSettings settings = quasiStatic();
    settings.volume_weight = weight;
    settings.volume_tolerance = 0.005;
    LocalGlobalSolver solver(system, settings);
    ParticleState state = start;
    const SolveStats stats = solver.solve(state, settling(3000, 1e-9));
    EXPECT_TRUE(state.position.allFinite());
    EXPECT_GT(stats.iterations, 0);
    return std::abs(muscleVolumeChange(tetrahedra, state.position)[0]);
  };
  const double without = volumeError(0.0);
  const double with = volumeError(20.0);
  RecordProperty("volume_error_without", std::to_string(without));
  RecordProperty("volume_error_with", std::to_string(with));
  EXPECT_GT(without, 0.25);  // the squeeze does cost volume without the term
  EXPECT_LT(with, 0.04);
  EXPECT_LT(with, without / 8);
}

TEST(LocalGlobalSolver, PrefactoredMatrixIsReusedAcrossIterationsAndFrames) {
  const int side = 4;
  const MassSpringSystem system = jitteredCube(side);
  LocalGlobalSettings settings = quasiStatic();
  settings.volume_weight = 1.0;
  LocalGlobalSolver solver(system, settings);
  EXPECT_EQ(solver.factorisations(), 1);
  int total_iterations = 0;
  for (int frame = 0; frame < 20; ++frame) {
    // Every frame a different pose of the fixed particles: only the right-hand side changes.
    ParticleState state = squeezedCube(system, side, 3.0 - 0.05 * frame);
    total_iterations += solver.solve(state, settling(50, 1e-9)).iterations;
  }
  EXPECT_GT(total_iterations, 100);
  EXPECT_EQ(solver.factorisations(), 1);
}

TEST(LocalGlobalSolver, FixedParticlesNeverMove) {
  const int side = 4;
  const MassSpringSystem system = jitteredCube(side);
  for (const bool quasi_static : {true, false}) {
    LocalGlobalSettings settings = quasiStatic();
    settings.quasi_static = quasi_static;
    settings.volume_weight = 2.0;
    LocalGlobalSolver solver(system, settings);
    ParticleState state = squeezedCube(system, side, 2.0);
    state.position.array() += 0.25;  // the pose moved everything, fixed particles included
    const Eigen::Matrix3Xd entry = state.position;
    solver.solve(state, settling(100, 0));
    for (Eigen::Index p = 0; p < system.particleCount(); ++p)
      if (system.is_fixed[static_cast<std::size_t>(p)]) {
        EXPECT_EQ(state.position.col(p), entry.col(p)) << "particle " << p;
      }
  }
}

TEST(LocalGlobalSolver, CollisionHookIsCalledAfterEveryGlobalStep) {
  // The hook keeps every particle above the plane z = 1.6 (a stand-in for the sphere projection). It is called once
  // per global step, and its corrections are kept: the result respects the plane.
  const int side = 4;
  const MassSpringSystem system = jitteredCube(side);
  LocalGlobalSolver solver(system, quasiStatic());
  ParticleState state = squeezedCube(system, side, 3.0);
  int calls = 0;
  const AfterUpdateHook plane = [&](ParticleState& s) {
    ++calls;
    int contacts = 0;
    for (Eigen::Index p = 0; p < s.position.cols(); ++p)
      if (!system.is_fixed[static_cast<std::size_t>(p)] && s.position(2, p) < 1.6) {
        s.position(2, p) = 1.6;
        s.previous_position.col(p) = s.position.col(p);
        ++contacts;
      }
    return contacts;
  };
  const SolveStats stats = solver.solve(state, StoppingSettings::afterIterations(40), plane);
  EXPECT_EQ(stats.iterations, 40);
  EXPECT_EQ(calls, 40);
  for (Eigen::Index p = 0; p < system.particleCount(); ++p)
    if (!system.is_fixed[static_cast<std::size_t>(p)]) {
      EXPECT_GE(state.position(2, p), 1.6);
    }
}

TEST(LocalGlobalSolver, ChebyshevAccelerationReachesTheSameShape) {
  const int side = 5;
  const MassSpringSystem system = jitteredCube(side);
  const ParticleState start = squeezedCube(system, side, 3.0);
  LocalGlobalSettings plain_settings = quasiStatic();
  LocalGlobalSettings fast_settings = plain_settings;
  fast_settings.chebyshev_rho = 0.9;
  ParticleState plain = start, fast = start;
  LocalGlobalSolver plain_solver(system, plain_settings), fast_solver(system, fast_settings);
  const SolveStats plain_stats = plain_solver.solve(plain, settling(5000, 1e-11));
  const SolveStats fast_stats = fast_solver.solve(fast, settling(5000, 1e-11));
  EXPECT_TRUE(plain_stats.stopping_rule_met);
  EXPECT_TRUE(fast_stats.stopping_rule_met);
  EXPECT_LT((plain.position - fast.position).cwiseAbs().maxCoeff(), 1e-5);
  RecordProperty("plain_iterations", plain_stats.iterations);
  RecordProperty("chebyshev_iterations", fast_stats.iterations);
}

TEST(LocalGlobalSolver, QuasiNewtonReachesTheSameShapeInFarFewerIterations) {
  const auto [system, start] = bentBeam(16, 1.0);
  LocalGlobalSettings plain_settings = quasiStatic();
  LocalGlobalSettings newton_settings = plain_settings;
  newton_settings.lbfgs_history = 8;
  ParticleState plain = start, newton = start;
  LocalGlobalSolver plain_solver(system, plain_settings), newton_solver(system, newton_settings);
  const SolveStats plain_stats = plain_solver.solve(plain, settling(50000, 1e-10));
  const SolveStats newton_stats = newton_solver.solve(newton, settling(50000, 1e-10));
  ASSERT_TRUE(plain_stats.stopping_rule_met);
  ASSERT_TRUE(newton_stats.stopping_rule_met);
  // Same minimum: positions agree far below the particle spacing (1), and the energy is no higher.
  EXPECT_LT((plain.position - newton.position).colwise().norm().maxCoeff(), 1e-4);
  EXPECT_LE(springEnergy(system, newton.position), springEnergy(system, plain.position) * (1 + 1e-9));
  // The point of it: the curvature pairs remove most of the iterations on this bending problem.
  EXPECT_LT(newton_stats.iterations * 5, plain_stats.iterations);
  EXPECT_EQ(newton_solver.factorisations(), 1);
  RecordProperty("plain_iterations", plain_stats.iterations);
  RecordProperty("lbfgs_iterations", newton_stats.iterations);
}

TEST(LocalGlobalSolver, InvalidSettingsAreRejected) {
  const MassSpringSystem system = fixedChain(3);
  LocalGlobalSettings settings;
  settings.time_step_s = 0;
  EXPECT_THROW(LocalGlobalSolver(system, settings), std::invalid_argument);
  settings = LocalGlobalSettings{};
  settings.chebyshev_rho = 1.0;
  EXPECT_THROW(LocalGlobalSolver(system, settings), std::invalid_argument);
  settings = LocalGlobalSettings{};
  settings.lbfgs_history = -1;
  EXPECT_THROW(LocalGlobalSolver(system, settings), std::invalid_argument);
  settings.lbfgs_history = 4;
  settings.quasi_static = false;
  EXPECT_CONTAINS(validate(settings), "quasi-static");
  settings.quasi_static = true;
  settings.chebyshev_rho = 0.5;
  EXPECT_CONTAINS(validate(settings), "exclude");
  EXPECT_EQ(solverKindFromString("local_global"), SolverKind::local_global);
  EXPECT_EQ(toString(SolverKind::verlet), "verlet");
  EXPECT_THROW(solverKindFromString("euler"), std::invalid_argument);
}

TEST(LocalGlobalSolver, MuscleSimulationFactorisesWithTheRadiiTheCollisionSetUpLeaves) {
  // The contact weights come from the sphere radii, which clearRestOverlaps shrinks (to 0 for particles inside a bone
  // sphere). A solver built before that set-up weighted particles that never collide.
  const SyntheticScene scene = makeSyntheticThigh(2, 3);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.solver_kind = SolverKind::local_global;
  const StoppingSettings forty = StoppingSettings::afterIterations(40);
  MuscleSimulation simulation(scene.muscles, scene.bones, settings);
  ASSERT_GT(simulation.restOverlaps().spheres_removed + simulation.restOverlaps().muscle_bone_pairs, 0)
      << "the scene must have rest overlaps for this test to mean anything";
  const Pose pose = syntheticThighPose(0.4, 0.6);
  solvePose(simulation, pose, StartMode::cold, FrameStopping::of(forty));

  // The same solve from public pieces, every one built on the final system.
  const MassSpringSystem& system = simulation.system();
  std::vector<SphereSet> bone_spheres;
  std::vector<std::string> bone_names;
  for (const Bone& bone : simulation.bones()) {
    bone_spheres.push_back(boneSpheresOneRing(bone.surface, settings.collision.bone_sphere_rule));
    bone_names.push_back(bone.name);
  }
  CollisionWorld world(system, bone_spheres, settings.collision, bone_names);
  const BoneTransforms transforms = boneTransformsOf(simulation.bones(), pose);
  world.setBoneTransforms(transforms);
  ParticleState state;
  rigidPretransform(system, transforms, state);
  LocalGlobalSolver solver(system, settings.local_global);
  solver.solve(state, forty, [&](ParticleState& s) { return world.resolve(s); });
  EXPECT_EQ((state.position - simulation.state().position).cwiseAbs().maxCoeff(), 0.0);
}

TEST(LocalGlobalSolver, MuscleSimulationRunsTheChosenSolver) {
  const SyntheticScene scene = makeSyntheticThigh(2, 3);
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.solver_kind = SolverKind::local_global;
  const FrameStopping stopping = FrameStopping::of(settling(300, 1e-6));
  MuscleSimulation simulation(scene.muscles, scene.bones, settings);
  for (const double hip : {0.2, 0.4}) {
    const FrameStats stats = solvePose(simulation, syntheticThighPose(hip, 0.5), StartMode::warm, stopping);
    EXPECT_TRUE(stats.finite);
    EXPECT_GT(stats.solver.iterations, 0);
    EXPECT_LT(stats.solver.max_strain, 0.6);  // the Verlet solver leaves up to 0.5 on this coarse model
  }
}
