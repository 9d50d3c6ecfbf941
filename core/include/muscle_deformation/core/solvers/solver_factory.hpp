// Builds the solver a SolverKind names from the settings of every solver (each reads only its own).
#pragma once

#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/core/solvers/local_global_solver.hpp"
#include "muscle_deformation/core/solvers/newton_krylov_solver.hpp"
#include "muscle_deformation/core/solvers/soft_body_solver.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"

#include <memory>

namespace muscle_deformation {

// The settings of every solver, so that switching the kind needs nothing else.
struct SolverChoice {
  SolverKind kind = SolverKind::verlet;
  VerletSettings verlet;
  LocalGlobalSettings local_global;
  BlockDescentSettings block_descent;  // also the frame energy of newton_krylov
  NewtonKrylovSettings newton_krylov;
  // Worker threads of block descent and Newton-Krylov (BlockDescentSolver: 0 = every core, -1 = measured choice).
  int threads = 0;
};

// Keeps a reference to `system`, which must outlive the solver. Build it after everything that changes the model
// (collision radii): solvers precompute from it (the local/global factorisation, the adaptive step's particle lists).
// Throws std::invalid_argument on invalid settings.
std::unique_ptr<SoftBodySolver> makeSolver(const SolverChoice& choice, const MassSpringSystem& system);

}  // namespace muscle_deformation
