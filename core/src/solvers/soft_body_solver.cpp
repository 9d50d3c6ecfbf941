#include "muscle_deformation/core/solvers/soft_body_solver.hpp"

#include <stdexcept>

namespace muscle_deformation {

std::string toString(SolverKind kind) {
  switch (kind) {
    case SolverKind::verlet: return "verlet";
    case SolverKind::local_global: return "local_global";
    case SolverKind::block_descent: return "block_descent";
    case SolverKind::newton_krylov: return "newton_krylov";
  }
  return "unknown";
}

SolverKind solverKindFromString(const std::string& name) {
  if (name == "verlet") return SolverKind::verlet;
  if (name == "local_global") return SolverKind::local_global;
  if (name == "block_descent") return SolverKind::block_descent;
  if (name == "newton_krylov") return SolverKind::newton_krylov;
  throw std::invalid_argument("unknown solver kind '" + name +
                              "' (expected verlet, local_global, block_descent or newton_krylov)");
}

}  // namespace muscle_deformation
