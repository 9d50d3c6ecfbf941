// Every solver behind the one interface: the factory builds the kind asked, and MuscleSimulation's answer is exactly
// the factory solver's answer from the same start.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/solver_factory.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "../src/pipeline/muscle_simulation.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

using namespace muscle_deformation;
using muscle_deformation::testing::solvePose;

namespace {

SimulationSettings smallSettings(SolverKind kind) {
  SimulationSettings settings;
  settings.model.particles_per_fibre = 10;
  settings.model.nearest_neighbours = 8;
  settings.solver_kind = kind;
  settings.collisions = false;  // the solver alone
  return settings;
}

// Verlet: 25 iterations; local/global: its displacement rule, at most 6 iterations.
StoppingSettings smallStopping(SolverKind kind) {
  return kind == SolverKind::verlet ? StoppingSettings::afterIterations(25)
                                    : StoppingSettings::atDisplacement(1e-6, 6);
}

}  // namespace

TEST(SolverFactory, BuildsTheKindAskedAndNamesIt) {
  const SyntheticScene scene = makeSyntheticThigh(1, 4);
  const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, ModelSettings{});
  for (const SolverKind kind :
       {SolverKind::verlet, SolverKind::local_global, SolverKind::block_descent, SolverKind::newton_krylov}) {
    const std::unique_ptr<SoftBodySolver> solver = makeSolver(SolverChoice{kind, {}, {}, {}, {}}, system);
    ASSERT_NE(solver, nullptr);
    EXPECT_EQ(solver->kind(), kind);
    EXPECT_EQ(solverKindFromString(toString(kind)), kind);
  }
  EXPECT_THROW(solverKindFromString("pbd"), std::invalid_argument);
}

TEST(SolverFactory, TheSimulationAnswersExactlyAsTheFactorySolverFromTheSameStart) {
  for (const SolverKind kind : {SolverKind::verlet, SolverKind::local_global}) {
    const SimulationSettings settings = smallSettings(kind);
    SyntheticScene scene = makeSyntheticThigh(2, 4);
    const Pose pose = syntheticThighPose(0.35, 0.25);

    const MassSpringSystem system = buildMassSpringSystem(scene.muscles, scene.bones, settings.model);
    ParticleState state = restState(system);
    rigidPretransform(system, boneTransformsOf(scene.bones, pose), state);
    const std::unique_ptr<SoftBodySolver> solver =
        makeSolver(SolverChoice{kind, settings.verlet, settings.local_global, {}, {}}, system);
    const SolveStats direct = solver->solve(state, smallStopping(kind));

    MuscleSimulation simulation(std::move(scene.muscles), std::move(scene.bones), settings);
    const FrameStats through_simulation =
        solvePose(simulation, pose, StartMode::cold, FrameStopping::of(smallStopping(kind)));
    EXPECT_EQ(through_simulation.solver.iterations, direct.iterations) << toString(kind);
    EXPECT_EQ(simulation.state().position, state.position) << toString(kind);
  }
}

TEST(SolverFactory, NewStoppingReachesWhicheverSolverRuns) {
  for (const SolverKind kind : {SolverKind::verlet, SolverKind::local_global}) {
    SyntheticScene scene = makeSyntheticThigh(1, 4);
    MuscleSimulation simulation(std::move(scene.muscles), std::move(scene.bones), smallSettings(kind));
    const FrameStopping three = FrameStopping::of(StoppingSettings::afterIterations(3));
    EXPECT_EQ(solvePose(simulation, syntheticThighPose(0.3, 0.0), StartMode::cold, three).solver.iterations, 3)
        << toString(kind);
    // The next solve stops as its own stopping says, on the same simulation.
    const FrameStopping five = FrameStopping::of(StoppingSettings::afterIterations(5));
    EXPECT_EQ(solvePose(simulation, syntheticThighPose(0.3, 0.0), StartMode::cold, five).solver.iterations, 5)
        << toString(kind);
  }
}
