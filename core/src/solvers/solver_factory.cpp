#include "muscle_deformation/core/solvers/solver_factory.hpp"

#include <stdexcept>

namespace muscle_deformation {

std::unique_ptr<SoftBodySolver> makeSolver(const SolverChoice& choice, const MassSpringSystem& system) {
  switch (choice.kind) {
    case SolverKind::verlet:
      return std::make_unique<VerletSolver>(system, choice.verlet);
    case SolverKind::local_global:
      return std::make_unique<LocalGlobalSolver>(system, choice.local_global);
    case SolverKind::block_descent:
      return std::make_unique<BlockDescentSolver>(system, choice.block_descent, choice.threads);
    case SolverKind::newton_krylov:
      return std::make_unique<NewtonKrylovSolver>(system, choice.block_descent, choice.newton_krylov, choice.threads);
  }
  throw std::invalid_argument("unknown solver kind " + std::to_string(static_cast<int>(choice.kind)));
}

}  // namespace muscle_deformation
