#include "muscle_deformation/core/solvers/soft_body_solver.hpp"

#include <stdexcept>

namespace muscle_deformation {

std::string toString(SolverKind kind) { return kind == SolverKind::verlet ? "verlet" : "local_global"; }

SolverKind solverKindFromString(const std::string& name) {
  if (name == "verlet") return SolverKind::verlet;
  if (name == "local_global") return SolverKind::local_global;
  throw std::invalid_argument("unknown solver kind '" + name + "' (expected verlet or local_global)");
}

}  // namespace muscle_deformation
