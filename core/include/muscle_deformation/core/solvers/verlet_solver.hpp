// Damped Verlet integration of the mass-spring system with the seeds' stopping rules and time-step rules.
#pragma once

#include "muscle_deformation/core/solvers/soft_body_solver.hpp"

#include <Eigen/Core>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

namespace muscle_deformation {

enum class TimeStepRule {
  fixed,     // dt = VerletSettings::dt_s every iteration
  adaptive,  // thesis eq. 5.1: largest dt keeping every boundary particle's step within its radius,
             // clamped to [dt_min_s, dt_s]
};

enum class MassRule {
  uniform,           // the seeds: every particle of a muscle has the same mass
  stiffness_scaled,  // particles on unusually stiff (short) springs made heavier, see stiffnessScaledMass()
};

struct VerletSettings {
  MassRule mass_rule = MassRule::stiffness_scaled;
  TimeStepRule dt_rule = TimeStepRule::fixed;
  double dt_s = 0.0;           // fixed step, and the upper clamp of the adaptive one; 0 = auto (0.9 x stability bound)
  double dt_min_s = 0.0;       // lower clamp of the adaptive step; 0 = auto (dt_s / 10, as the thesis' 0.04 vs 0.4)
  double damping_ns_per_m = 0; // viscous damping c of eq. 2.14, N s/m; 0 = critical-damping rule (eq. 2.11)
  double damping_scale = 1.0;  // multiplies the critical-damping rule's value
};

// Critical-damping rule (thesis eq. 2.11 without its unit-dependent 6-neighbour constant): c = sqrt(4 * k_a * 2m)
// with k_a the mean spring stiffness and m the mean particle mass. For two free particles joined by one spring this
// is exactly critical.
double criticalDamping(const MassSpringSystem& system);

// Largest stable explicit step, from a Gershgorin bound on the spring stiffness: dt = 2 / sqrt(max_i 2 sum_j k_ij / m_i).
double stabilityTimeStep(const MassSpringSystem& system);

// Masses the solver integrates with under MassRule::stiffness_scaled: each particle's mass raised, where needed, so
// that its 2 * sum_j k_ij / m is no larger than the median particle's. Equilibrium shapes do not depend on masses.
Eigen::VectorXd stiffnessScaledMass(const MassSpringSystem& system);

class VerletSolver final : public SoftBodySolver {
 public:
  SolverKind kind() const override { return SolverKind::verlet; }
  static constexpr int kMaxRecoveries = 8;  // halvings: a step up to 256 x too long is still brought back

  VerletSolver(const MassSpringSystem& system, VerletSettings settings);

  // Advances `state` until `stopping` is met (any rule but force_residual, which Verlet does not measure). Fixed
  // particles keep the positions `state` holds on entry. Allocates nothing per iteration. On divergence
  // (DivergenceMonitor) the state is put back as it was on entry, the step halved for this and every later solve, and
  // the solve run again, up to kMaxRecoveries times; if every attempt diverges the state is left as on entry and the
  // stats say so.
  SolveStats solve(ParticleState& state, const StoppingSettings& stopping,
                   const AfterUpdateHook& after_update = {}) override;

  void restLengthsChanged() override;

  // One MSS update (forces, time step, integration) without collision, for benchmarks. Returns the dt used.
  double step(ParticleState& state);

  const VerletSettings& settings() const { return settings_; }
  double damping() const { return damping_; }
  double timeStep() const { return dt_; }
  // Heap bytes the solver keeps (packed springs, forces, inverse masses, particle lists), excluding the state.
  std::size_t solverBytes() const;

 private:
  struct PackedSpring {
    std::int32_t second_times_3;  // index of the second particle's x in the position array
    float stiffness;              // N/m
    double rest_length;           // m; double so that a spring at its rest length exerts exactly no force
  };
  struct SpringRun {
    std::int32_t first_times_3;  // shared first particle
    std::int32_t begin;          // first spring of the run; the run ends where the next begins
  };

  void packSprings();
  void computeForces(const Eigen::Matrix3Xd& position);
  double adaptiveTimeStep(const ParticleState& state) const;
  struct Integration {
    double displacement_sum = 0;  // summed |x_new - x| of free particles
    double step_correlation = 0;  // summed (x_new - x) . (x - x_prev) of free particles
  };
  Integration integrate(ParticleState& state, double dt);
  // One attempt at the solve from the current state; returns false if it diverged.
  bool attempt(ParticleState& state, const StoppingSettings& stopping, const AfterUpdateHook& after_update,
               SolveStats& stats, std::chrono::steady_clock::time_point solve_start);

  const MassSpringSystem& system_;
  VerletSettings settings_;
  double damping_ = 0;
  double dt_ = 0, dt_min_ = 0;
  double previous_dt_ = 0;
  double damping_step_limit_ = 0;  // m_min / c
  std::vector<PackedSpring> packed_springs_;
  std::vector<SpringRun> spring_runs_;  // plus a sentinel run marking the end
  Eigen::Matrix3Xd force_;
  Eigen::VectorXd inverse_mass_;
  std::vector<std::int32_t> free_particles_;
  std::vector<std::int32_t> boundary_free_particles_;
  double mean_rest_length_ = 0;  // m, scale of the divergence bound
  Eigen::Matrix3Xd entry_position_, entry_previous_position_;  // the state a solve started from, for recovery
};

}  // namespace muscle_deformation
