// The one interface the pipeline drives a solver of the mass-spring system through. A new solver implements it and
// registers in solver_factory.cpp; MuscleSimulation and everything above it stay unchanged.
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/collision/contact_set.hpp"
#include "muscle_deformation/core/solvers/solve_control.hpp"
#include "muscle_deformation/core/solvers/volume_term.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

// The interval between frames when nothing else is known (a cold start, a single pose): the bundled gait's 60 Hz.
constexpr double kNominalFrameIntervalS = 1.0 / 60.0;

enum class SolverKind {
  verlet,        // damped Verlet (verlet_solver.hpp)
  local_global,  // local/global projective iterations (local_global_solver.hpp)
  block_descent, // per-particle Newton sweeps with contacts in the solve (block_descent_solver.hpp)
  newton_krylov, // Newton steps on the same frame energy, solved by conjugate gradients (newton_krylov_solver.hpp)
};
std::string toString(SolverKind kind);
// Solvers that measure the force residual (the force_residual stopping rule, SolveStats::residual): block descent and
// Newton-Krylov, on the same frame energy.
inline bool measuresForceResidual(SolverKind kind) {
  return kind == SolverKind::block_descent || kind == SolverKind::newton_krylov;
}
// Accepts "verlet", "local_global", "block_descent", "newton_krylov"; throws std::invalid_argument otherwise.
SolverKind solverKindFromString(const std::string& name);

class SoftBodySolver {
 public:
  virtual ~SoftBodySolver() = default;

  virtual SolverKind kind() const = 0;
  // Advances `state` until `stopping` (its rule, or a bound of its limits) is met; `after_update` (the collision stage)
  // runs after every update. Fixed particles keep the positions `state` holds on entry (the pose). Throws
  // std::invalid_argument for a rule the solver cannot evaluate (a force residual it does not measure) or invalid
  // stopping settings.
  virtual SolveStats solve(ParticleState& state, const StoppingSettings& stopping,
                           const AfterUpdateHook& after_update = {}) = 0;
  // Solvers that keep contacts as energy inside their solve (rather than through `after_update`) say so here and take
  // the collision stage's contact query; the others ignore it. `every_particle_collides`: the query lists contacts of
  // interior particles too (a bone distance field), not only of boundary particles with a sphere radius.
  virtual bool solvesContacts() const { return false; }
  // The time since the frame the solve continues (s). Solvers whose answer depends on it (block descent's tissue drag)
  // weigh by it; the others ignore it.
  virtual void setFrameInterval(double /*seconds*/) {}
  virtual void setContactQuery(ContactQuery, bool /*every_particle_collides*/) {}
  // Whether the answer of a solve includes tissue drag towards state.carried_position (block descent's energy with a
  // relaxation time): the simulation then sets the carried positions and may predict a start.
  virtual bool dragsTissue() const { return false; }
  // Whether the solve ties particles to where the bones carry their rest positions (state.rest_carried_position, which
  // the simulation then sets every frame).
  virtual bool tiesToRestShape() const { return false; }
  // Whether the tie also carries the force that holds the rest shape in balance (state.rest_balance_force, which the
  // simulation then sets every frame).
  virtual bool balancesRestShape() const { return false; }
  // Solvers that minimise a frame energy take the muscles' volume term into it (volume_term.hpp); the others ignore it
  // and say so here.
  virtual bool keepsVolume() const { return false; }
  // The rest lengths of the system's tendon springs with a path (MassSpringSystem::tendon_paths) changed with the
  // pose: the solver reads them again before its next solve.
  virtual void restLengthsChanged() = 0;
  virtual void setVolumeTerm(VolumeTerm) {}
  // New per-muscle targets of the volume term (VolumeTerm::target_volume_m3: the muscles' pressures, carried from
  // frame to frame by the simulation); ignored without a volume term.
  virtual void setVolumeTargets(const std::vector<double>& /*target_volume_m3*/) {}
  // Per muscle, how far the volume target would move if the tissue drag's pull on `state` (towards
  // state.carried_position) were taken out of the balance that the muscle's pressure holds: D_m / (k_m |g_m|^2), with
  // D_m the drag's force projected on the gradient g_m of the muscle's volume over its particles (m^3; negative where
  // the drag squeezes the muscle). Empty for a solver without both the drag and the volume term.
  virtual std::vector<double> dragShareOfVolumeTargets(const ParticleState& /*state*/) { return {}; }
};

}  // namespace muscle_deformation
