// Newton's method on the block-descent frame energy (springs, contacts, tissue drag: block_descent_solver.hpp), each
// step solved by conjugate gradients preconditioned with the particles' own 3 x 3 blocks: a global solver of the same
// problem the sweeps solve locally. It moves every particle at once along the Newton direction, so it shows that a
// frame's answer does not depend on how it is reached, and it converges a frame to a force residual the sweeps take
// far longer to reach (the reference the benchmarks measure against).
#pragma once

#include "muscle_deformation/core/solvers/block_descent_solver.hpp"
#include "muscle_deformation/core/solvers/soft_body_solver.hpp"

#include <Eigen/Core>

#include <vector>

namespace muscle_deformation {

struct NewtonKrylovSettings {
  int max_cg_iterations = 300;  // per Newton step
  // A Newton step's linear solve stops at this fraction of its starting residual. The residual of a frame is dominated
  // by a few stiff contacts, which the block preconditioner settles in one iteration: a loose tolerance would stop
  // there, before the smooth part of the step is solved.
  double cg_relative_tolerance = 1e-3;
};

// Returns an empty string when the settings are usable, otherwise what is wrong.
std::string validate(const NewtonKrylovSettings& settings);

class NewtonKrylovSolver final : public SoftBodySolver {
 public:
  // `energy` settings: the block-descent settings that define the frame energy (contact stiffness and margin, tissue
  // drag); `threads` as BlockDescentSolver's. Throws std::invalid_argument on invalid settings.
  NewtonKrylovSolver(const MassSpringSystem& system, const BlockDescentSettings& energy, NewtonKrylovSettings settings,
                     int threads = 0);

  SolverKind kind() const override { return SolverKind::newton_krylov; }
  // Newton steps until `stopping` is met (force_residual, iterations, displacement or time_budget; caps and limits as
  // the other solvers); `converged` when the force residual where it ended lies below stopping.residual_tolerance. Each step: contacts gathered at the current state, the projected Hessian solved by
  // preconditioned CG, then a backtracking line search on the frame energy with the contacts listed again within the
  // step's reach when it carries a collidable particle beyond the sweeps' margin. A non-finite result
  // puts the entry state back and reports `diverged`.
  SolveStats solve(ParticleState& state, const StoppingSettings& stopping,
                   const AfterUpdateHook& after_update = {}) override;
  bool solvesContacts() const override { return true; }
  bool dragsTissue() const override { return energy_.dragsTissue(); }
  bool tiesToRestShape() const override { return energy_.tiesToRestShape(); }
  bool balancesRestShape() const override { return energy_.balancesRestShape(); }
  bool keepsVolume() const override { return true; }
  void restLengthsChanged() override { energy_.restLengthsChanged(); }
  void setVolumeTerm(VolumeTerm term) override { energy_.setVolumeTerm(std::move(term)); }
  void setVolumeTargets(const std::vector<double>& target_volume_m3) override {
    energy_.setVolumeTargets(target_volume_m3);
  }
  std::vector<double> dragShareOfVolumeTargets(const ParticleState& state) override {
    return energy_.dragShareOfVolumeTargets(state);
  }
  void setContactQuery(ContactQuery query, bool every_particle_collides) override;
  void setFrameInterval(double seconds) override { energy_.setFrameInterval(seconds); }

  // Conjugate-gradient iterations of the last solve, over all its Newton steps.
  int lastCgIterations() const { return last_cg_iterations_; }
  double lastResidual() const { return last_residual_; }

 private:
  const MassSpringSystem& system_;
  BlockDescentSolver energy_;  // the frame energy and its contacts; its sweeps are not used
  NewtonKrylovSettings settings_;
  double material_constant_n_ = 1.0;
  int last_cg_iterations_ = 0;
  double last_residual_ = 0;
};

}  // namespace muscle_deformation
