// The one interface the pipeline drives a solver of the mass-spring system through. A new solver implements it and
// registers in solver_factory.cpp; MuscleSimulation and everything above it stay unchanged.
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/solvers/contact_set.hpp"
#include "muscle_deformation/core/solvers/solve_control.hpp"

#include <string>

namespace muscle_deformation {

enum class SolverKind {
  verlet,        // damped Verlet (verlet_solver.hpp)
  local_global,  // local/global projective iterations (local_global_solver.hpp)
  block_descent, // per-particle Newton sweeps with contacts in the solve (block_descent_solver.hpp)
};
std::string toString(SolverKind kind);
// Accepts "verlet", "local_global", "block_descent"; throws std::invalid_argument otherwise.
SolverKind solverKindFromString(const std::string& name);

class SoftBodySolver {
 public:
  virtual ~SoftBodySolver() = default;

  virtual SolverKind kind() const = 0;
  // Advances `state` until the stopping rule or a SolveLimits bound is met; `after_update` (the collision stage) runs
  // after every update. Fixed particles keep the positions `state` holds on entry (the pose).
  virtual SolveStats solve(ParticleState& state, const AfterUpdateHook& after_update = {}) = 0;
  // Changes how later solves stop (rule, iteration cap, tolerances, limits) without rebuilding anything.
  virtual void setStopping(StoppingRule rule, int max_iterations, double displacement_tolerance_m,
                           double time_budget_ms, const SolveLimits& limits) = 0;
  // Solvers that keep contacts as energy inside their solve (rather than through `after_update`) say so here and take
  // the collision stage's contact query; the others ignore it. `every_particle_collides`: the query lists contacts of
  // interior particles too (a bone distance field), not only of boundary particles with a sphere radius.
  virtual bool solvesContacts() const { return false; }
  virtual void setContactQuery(ContactQuery, bool /*every_particle_collides*/) {}
};

}  // namespace muscle_deformation
