// Implicit mass-spring solver by local/global iteration (Liu, O'Brien, Zhuang, Kavan, SIGGRAPH Asia 2013, "Fast
// Simulation of Mass-Spring Systems"), with per-tetrahedron volume constraints in the same projective framework
// (Bouaziz et al. 2014, "Projective Dynamics"). A drop-in alternative to VerletSolver: same state, same hook, same
// statistics.
//
// Each iteration minimises, over the free particles x,
//   g(x) = 1/2 (x - y)^T W (x - y) + sum_springs k/2 |x_a - x_b - d_s|^2 + sum_tets w V/2 |F(x) - T_t|^2
// alternately over the auxiliary variables (local step: d_s = rest length times the current spring direction, T_t =
// the nearest deformation gradient whose determinant lies in [1 - e, 1 + e]) and over x (global step: one solve with
// the constant matrix W + L, prefactored once). Dynamic mode: W = M / h^2 and y = x_n + (1 - damping)(x_n - x_{n-1}),
// one implicit Euler step per `iterations_per_step` iterations. Quasi-static mode: W is a tiny proximal
// regularisation and y the current iterate, so the iteration is block-coordinate descent on the elastic energy alone
// and converges to the equilibrium shape without simulating the motion towards it.
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/solvers/soft_body_solver.hpp"

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <Eigen/SparseCholesky>

#include <chrono>

#include <cstdint>
#include <string>
#include <vector>

namespace muscle_deformation {

struct LocalGlobalSettings {
  bool quasi_static = true;         // true: equilibrium only (time_step_s and damping unused)
  double time_step_s = 1.0 / 30.0;  // implicit Euler step h of the dynamic mode
  int iterations_per_step = 1;      // dynamic mode: local/global iterations per time step (y fixed within a step)
  double damping = 0.0;             // dynamic mode: share of the velocity removed per step, in [0, 1]
  // Quasi-static mode: proximal weight pulling towards the previous iterate, relative to the mean diagonal of the
  // stiffness matrix. Keeps the matrix positive definite when a component has no fixed particle; the fixed point is
  // unchanged.
  double quasi_static_regularisation = 1e-6;
  // Proximal weight on the collidable particles (radius > 0), relative to the mean diagonal of the stiffness matrix:
  // pulls each towards its position after the previous collision hook. Without it the global step forgets the
  // hook's corrections (the matrix knows nothing of contacts) and, in quasi-static mode, re-solves the unconstrained
  // shape every iteration, so contacts become spikes of strain. With it a contact acts as a penalty of this
  // stiffness. Where nothing collides the fixed point is unchanged. 0 = off.
  double contact_weight = 1.0;

  // Volume term. Weight relative to the springs' own stiffness: 1 makes a tetrahedron's volume change cost about as
  // much energy per unit volume as the springs' stretch of the same strain (see LocalGlobalSolver::volumeStiffness).
  // 0 disables the term (no tetrahedralisation is built).
  double volume_weight = 0.0;
  double volume_tolerance = 0.01;        // e: each tetrahedron's volume ratio may move freely within [1 - e, 1 + e]
  double min_tetrahedron_quality = 0.1;  // drop slivers: quality = 6 sqrt(2) V / rms_edge^3 (1 for a regular tet)
  double max_edge_over_spring = 3.0;     // drop tetrahedra with an edge longer than this times the muscle's median
                                         // spring rest length (the hull's bridges across concavities)

  // Wang 2015 Chebyshev semi-iterative acceleration of the iterates; 0 = off, otherwise the estimated spectral
  // radius of the plain iteration, in (0, 1). Starts after chebyshev_delay plain iterations.
  double chebyshev_rho = 0.0;
  int chebyshev_delay = 5;

  // Quasi-static mode only: quasi-Newton (L-BFGS) on the same energy, with the prefactored matrix as the initial
  // inverse Hessian (Liu, Bouaziz, Kavan 2017). Each local/global step is a gradient step preconditioned by that
  // matrix; the curvature pairs of the last `lbfgs_history` steps correct it along the soft shape changes (bending of
  // long muscles) where the plain iteration crawls. 0 = plain local/global iterations. Excludes Chebyshev.
  int lbfgs_history = 0;
};

// Checks settings; returns an empty string when valid, otherwise what is wrong.
std::string validate(const LocalGlobalSettings& settings);

// Tetrahedra over each muscle's particles (Delaunay of the rest positions, slivers and long bridges dropped), with
// their rest volumes. Shared by the solver's volume term and by volume measurements.
struct MuscleTetrahedra {
  std::vector<Eigen::Vector4i> tetrahedra;  // particle indices, positively oriented at rest
  std::vector<std::int32_t> muscle_of;      // per tetrahedron
  Eigen::VectorXd rest_volume;              // m^3, per tetrahedron
  int muscle_count = 0;
};
MuscleTetrahedra buildMuscleTetrahedra(const MassSpringSystem& system, double min_quality = 0.1,
                                       double max_edge_over_spring = 3.0);

// Relative change of each muscle's summed tetrahedron volume, (V - V0) / V0, at `position`.
Eigen::VectorXd muscleVolumeChange(const MuscleTetrahedra& tetrahedra, const Eigen::Matrix3Xd& position);

class LocalGlobalSolver final : public SoftBodySolver {
 public:
  SolverKind kind() const override { return SolverKind::local_global; }
  // Builds and factorises the system matrix (once). Throws std::invalid_argument on invalid settings and
  // std::runtime_error if the factorisation fails.
  LocalGlobalSolver(const MassSpringSystem& system, LocalGlobalSettings settings);

  // Iterates until `stopping` is met; `after_update` is called after every global step (collision). Fixed
  // particles keep the positions `state` holds on entry (the pose): only the right-hand side depends on them, so the
  // factorisation is reused across solves. Allocates nothing per iteration. The iteration is implicit and needs no
  // step control; should it still produce a non-finite position, the state is put back as it was on entry and the
  // stats say `diverged`.
  void restLengthsChanged() override;
  // Any stopping rule but force_residual, which this solver does not measure.
  SolveStats solve(ParticleState& state, const StoppingSettings& stopping,
                   const AfterUpdateHook& after_update = {}) override;

  const LocalGlobalSettings& settings() const { return settings_; }
  int factorisations() const { return factorisations_; }
  double factorisationMilliseconds() const { return factorisation_ms_; }
  Eigen::Index freeParticleCount() const { return free_count_; }
  Eigen::Index factorNonZeros() const;  // non-zeros of the Cholesky factor L
  const MuscleTetrahedra& tetrahedra() const { return tetrahedra_; }
  // Absolute volume weight per muscle (Pa): volume_weight times the springs' effective modulus
  // sum_s k_s l0_s^2 / V_muscle (V_muscle = summed tetrahedron rest volume).
  const Eigen::VectorXd& volumeStiffness() const { return volume_stiffness_; }

 private:
  struct Spring {
    std::int32_t a, b;  // particle indices
    std::int32_t fa, fb;  // free indices (-1 for fixed particles)
    double stiffness, rest_length;
  };
  struct VolumeTerm {
    std::int32_t vertex[4];  // particle indices
    std::int32_t free[4];    // free indices, -1 if fixed
    Eigen::Matrix3d rest_inverse;  // Dm^-1, Dm = [x1 - x0, x2 - x0, x3 - x0] at rest
    double weight;           // w V0 (N m)
  };

  void buildTerms();
  void buildAndFactorise();
  void localGlobalIteration(const ParticleState& state);  // fills free_next_ from free_current_
  // Local step at `position`: adds each term's projection force to `rhs` (free particles x 3); returns the energy
  // sum of 1/2 w |current - projection|^2 over the terms (springs and volume). Its gradient with respect to the free
  // particles is stiffness_free_ x_free - fixed_rhs_ - (what this adds). Without kWithEnergy (the plain iteration,
  // which never reads it) the energy is not summed and 0 is returned.
  template <bool kWithEnergy>
  double addProjections(const Eigen::Matrix3Xd& position, Eigen::MatrixXd& rhs) const;
  // The quasi-Newton iteration loop of solve(); fixed_rhs_ must be set for the pose.
  void quasiNewtonIterations(ParticleState& state, const StoppingSettings& stopping,
                             const AfterUpdateHook& after_update, SolveStats& stats,
                             std::chrono::steady_clock::time_point solve_start);
  // (L + W)^-1 rhs with the prefactored LDL^T, the three coordinates carried through one pass over the factor
  // (Eigen's solve makes one pass per right-hand side, and the passes are bound by reading the factor).
  void solvePrefactored(const Eigen::MatrixXd& rhs, Eigen::MatrixXd& result);
  // Common end of a solve: stopping flag, time, spring metrics.
  SolveStats finishSolve(ParticleState& state, const StoppingSettings& stopping, SolveStats& stats,
                         std::chrono::steady_clock::time_point solve_start) const;
  // Free particles' rows of `free` written into `position`.
  void scatterFree(const Eigen::MatrixXd& free, Eigen::Matrix3Xd& position) const;
  void gatherFree(const Eigen::Matrix3Xd& position, Eigen::MatrixXd& free) const;
  // Energy at `position` (whose free rows are `free`), and its gradient with respect to the free particles.
  double energyAndGradient(const Eigen::Matrix3Xd& position, const Eigen::MatrixXd& free, Eigen::MatrixXd& gradient);

  const MassSpringSystem& system_;
  LocalGlobalSettings settings_;
  Eigen::Index free_count_ = 0;
  std::vector<std::int32_t> free_index_;    // per particle: index among free particles or -1
  std::vector<std::int32_t> free_particle_;  // free index -> particle
  std::vector<Spring> springs_;
  std::vector<std::int32_t> spring_entry_;  // per spring of the system: its index in springs_ (-1: none)
  std::vector<VolumeTerm> volume_terms_;
  MuscleTetrahedra tetrahedra_;
  Eigen::VectorXd volume_stiffness_;
  Eigen::VectorXd inertia_weight_;  // diagonal of W per free particle: towards y (dynamic) or the iterate (quasi-static)
  Eigen::VectorXd contact_weight_;  // proximal weight towards the current iterate, collidable particles only
  Eigen::SparseMatrix<double> free_fixed_;  // coupling block of W + L, free rows x all-particle columns (fixed only)
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> factor_;
  Eigen::SparseMatrix<double> stiffness_free_;  // the free-free block of L alone (no proximal weights): the Hessian's
                                                // constant part, for exact gradients in quasi-Newton mode
  int factorisations_ = 0;
  double factorisation_ms_ = 0;

  // Per-solve and per-iteration buffers (free particles x 3, column-major: one column per coordinate).
  Eigen::MatrixXd fixed_rhs_, rhs_, free_current_, free_previous_, free_next_, chebyshev_older_, inertial_target_,
      inertial_prediction_;
  Eigen::MatrixXd fixed_position_;  // all particles x 3, only fixed rows used
  Eigen::Matrix3Xd permuted_solution_;  // solvePrefactored's work: one column per free particle, in factor order
  // Quasi-Newton buffers (free particles x 3 each), allocated once when lbfgs_history > 0.
  Eigen::MatrixXd gradient_, previous_gradient_, trial_gradient_, direction_, trial_;
  std::vector<Eigen::MatrixXd> history_step_, history_gradient_change_;  // s_i, y_i of the last lbfgs_history steps
  std::vector<double> history_inverse_curvature_, history_alpha_;        // 1 / (s_i . y_i), two-loop coefficients
  Eigen::Matrix3Xd entry_position_, entry_previous_position_;  // the state a solve started from, for recovery
};

}  // namespace muscle_deformation
