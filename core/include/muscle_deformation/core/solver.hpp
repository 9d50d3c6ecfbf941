// Damped Verlet integration of the mass-spring system with the seeds' stopping rules and time-step rules.
#pragma once

#include "muscle_deformation/core/mass_spring_system.hpp"

#include <Eigen/Core>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

namespace muscle_deformation {

enum class TimeStepRule {
  fixed,     // dt = SolverSettings::dt_s every iteration
  adaptive,  // thesis eq. 5.1: largest dt keeping every boundary particle's step within its radius,
             // clamped to [dt_min_s, dt_s]
};

enum class StoppingRule {
  iterations,    // exactly max_iterations
  displacement,  // mean free-particle displacement of an iteration < displacement_tolerance_m and no longer growing
                 // (or max_iterations)
  time_budget,   // wall time of the solve reaches time_budget_ms (or max_iterations)
};

enum class MassRule {
  uniform,           // the seeds: every particle of a muscle has the same mass
  stiffness_scaled,  // particles on unusually stiff (short) springs made heavier, see stiffnessScaledMass()
};

// Bounds every solve obeys whatever its stopping rule, so that no call can run unbounded: a wall-time ceiling and a
// flag another thread raises to end a solve early (shutdown). Checked after every iteration.
struct SolveLimits {
  double wall_time_limit_ms = 0;            // 0 = no ceiling
  const std::atomic<bool>* cancel = nullptr;  // when set and raised, the solve stops after the current iteration
};

struct SolverSettings {
  MassRule mass_rule = MassRule::stiffness_scaled;
  TimeStepRule dt_rule = TimeStepRule::fixed;
  double dt_s = 0.0;           // fixed step, and the upper clamp of the adaptive one; 0 = auto (0.9 x stability bound)
  double dt_min_s = 0.0;       // lower clamp of the adaptive step; 0 = auto (dt_s / 10, as the thesis' 0.04 vs 0.4)
  double damping_ns_per_m = 0; // viscous damping c of eq. 2.14, N s/m; 0 = critical-damping rule (eq. 2.11)
  double damping_scale = 1.0;  // multiplies the critical-damping rule's value
  StoppingRule stopping_rule = StoppingRule::iterations;
  int max_iterations = 100;                 // cap for every rule
  double displacement_tolerance_m = 1e-6;   // for StoppingRule::displacement
  double time_budget_ms = 16.0;             // for StoppingRule::time_budget
  SolveLimits limits;                       // for every rule
};

// The seeds' stopping rules, evaluated after every iteration; shared by the solvers so they stop alike.
class StoppingMonitor {
 public:
  StoppingMonitor(StoppingRule rule, double displacement_tolerance_m, double time_budget_ms)
      : rule_(rule), tolerance_m_(displacement_tolerance_m), budget_ms_(time_budget_ms) {}
  // True when the rule is met after this iteration. A solve that starts at rest moves little in its first iterations
  // and speeds up, so only a small displacement that is no longer growing counts as settled.
  bool met(int iteration, double mean_displacement_m, double elapsed_ms) {
    const bool settling = iteration > 0 && mean_displacement_m <= previous_displacement_m_;
    previous_displacement_m_ = mean_displacement_m;
    if (rule_ == StoppingRule::displacement) return settling && mean_displacement_m < tolerance_m_;
    if (rule_ == StoppingRule::time_budget) return elapsed_ms >= budget_ms_;
    return false;
  }

 private:
  StoppingRule rule_;
  double tolerance_m_, budget_ms_;
  double previous_displacement_m_ = std::numeric_limits<double>::infinity();
};

struct SolveStats {
  int iterations = 0;
  bool stopping_rule_met = false;     // false when max_iterations ended a displacement/time-budget solve
  // A convergence criterion was met: the displacement rule's tolerance, or (L-BFGS) no descent left. Running out of
  // iterations or time is never convergence, whatever the rule.
  bool converged = false;
  bool time_limit_reached = false;    // SolveLimits::wall_time_limit_ms ended the solve
  bool cancelled = false;             // SolveLimits::cancel ended the solve
  double mss_ms = 0;                  // time in spring forces and integration
  double collision_ms = 0;            // time in the collision hook
  double total_ms = 0;
  double last_dt_s = 0;
  double min_dt_s = 0, max_dt_s = 0;  // over the solve (adaptive rule)
  double mean_displacement_m = 0;     // mean |x - x_prev| over free particles, last iteration
  double spring_deviation_ratio = 0;  // sum |l - l0| / sum l0 at the end
  double mean_strain = 0;             // mean |l - l0| / l0
  double max_strain = 0;              // max |l - l0| / l0
  // 99th percentile of |l - l0| / l0: a robust alarm where max_strain is dominated by a few micrometre springs.
  // Read from a histogram with 16 bins per octave: an upper bound, at most 6.25 % above the exact value.
  double strain_p99 = 0;
  int contacts = 0;                   // reported by the collision hook, last iteration
  double peak_mean_displacement_m = 0;  // largest mean free-particle displacement of any iteration (all attempts)
  // Divergence (see DivergenceMonitor): each recovery restored the entry state and retried with half the step.
  int divergence_recoveries = 0;
  bool diverged = false;              // every attempt diverged: the state is the one the solve started from
  double time_step_s = 0;             // the solver's fixed step (upper clamp of the adaptive one) at the end, s
};

// Tells a diverging explicit solve from a legitimate one, iteration by iteration. For a mode of frequency w, damped
// Verlet (x' = x + keep (x - x_prev) + F dt^2 / m, keep = 1 - c dt / m <= 1) has the characteristic polynomial
// l^2 - (1 + keep - w^2 dt^2) l + keep: it is w^2 dt^2 >= 0 at l = 1 and its roots multiply to keep <= 1, so no root
// lies beyond +1 and complex roots have |l|^2 = keep <= 1. Whatever makes the step too long (stiffness or damping), the
// growing mode has a real eigenvalue below -1: every particle reverses its direction of motion each iteration while
// the steps grow. A solve that is merely moving a lot (a cold start accelerating from
// the pre-transform, a collision push) keeps its direction or grows only once. Divergence is declared when the step
// is non-finite, or when for `kGrowingReversals` consecutive iterations the mean step grew and reversed direction
// (negative summed dot product of successive steps) and it now exceeds `kStepFraction` of the mean rest spring
// length: an oscillation of that size at the step's own frequency is no physical motion of a muscle at rest.
class DivergenceMonitor {
 public:
  static constexpr int kGrowingReversals = 3;
  static constexpr double kStepFraction = 0.25;

  explicit DivergenceMonitor(double mean_rest_length_m) : bound_m_(kStepFraction * mean_rest_length_m) {}
  // `step_correlation` = sum over free particles of (x_new - x) . (x - x_prev) of this iteration.
  bool diverged(double mean_displacement_m, double step_correlation) {
    if (!std::isfinite(mean_displacement_m) || !std::isfinite(step_correlation)) return true;
    const bool growing_reversal = mean_displacement_m > previous_m_ && step_correlation < 0;
    growing_reversals_ = growing_reversal ? growing_reversals_ + 1 : 0;
    previous_m_ = mean_displacement_m;
    return growing_reversals_ >= kGrowingReversals && mean_displacement_m > bound_m_;
  }

 private:
  double bound_m_;
  double previous_m_ = std::numeric_limits<double>::infinity();
  int growing_reversals_ = 0;
};

// True when `limits` end the solve now (elapsed wall time since the solve started); records why in `stats`.
inline bool solveLimitReached(const SolveLimits& limits, double elapsed_ms, SolveStats& stats) {
  if (limits.cancel && limits.cancel->load(std::memory_order_relaxed)) {
    stats.cancelled = true;
    return true;
  }
  if (limits.wall_time_limit_ms > 0 && elapsed_ms >= limits.wall_time_limit_ms) {
    stats.time_limit_reached = true;
    return true;
  }
  return false;
}

struct SpringMetrics {
  double deviation_ratio = 0, mean_strain = 0, max_strain = 0, strain_p99 = 0;
};
SpringMetrics measureSprings(const SpringSet& springs, const Eigen::Matrix3Xd& position);
// Fills the spring fields of `stats` (deviation ratio, mean and max strain) at `position`.
void recordSpringMetrics(const SpringSet& springs, const Eigen::Matrix3Xd& position, SolveStats& stats);

// Critical-damping rule (thesis eq. 2.11 without its unit-dependent 6-neighbour constant): c = sqrt(4 * k_a * 2m)
// with k_a the mean spring stiffness and m the mean particle mass. For two free particles joined by one spring this
// is exactly critical.
double criticalDamping(const MassSpringSystem& system);

// Largest stable explicit step, from a Gershgorin bound on the spring stiffness: dt = 2 / sqrt(max_i 2 sum_j k_ij / m_i).
double stabilityTimeStep(const MassSpringSystem& system);

// Masses the solver integrates with under MassRule::stiffness_scaled: each particle's mass raised, where needed, so
// that its 2 * sum_j k_ij / m is no larger than the median particle's. Equilibrium shapes do not depend on masses.
Eigen::VectorXd stiffnessScaledMass(const MassSpringSystem& system);

// Called after every MSS update with the new state; returns the number of contacts resolved. The collision stage
// plugs in here so the solver stays free of collision code.
using AfterUpdateHook = std::function<int(ParticleState& state)>;

// Runs the collision hook (if any) on the state just integrated, recording its contacts and time in `stats`.
// Both solvers call it after every update.
inline void runAfterUpdateHook(const AfterUpdateHook& after_update, ParticleState& state, SolveStats& stats) {
  if (!after_update) return;
  const auto start = std::chrono::steady_clock::now();
  stats.contacts = after_update(state);
  stats.collision_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

class VerletSolver {
 public:
  static constexpr int kMaxRecoveries = 8;  // halvings: a step up to 256 x too long is still brought back

  VerletSolver(const MassSpringSystem& system, SolverSettings settings);

  // Advances `state` until the stopping rule is met. Fixed particles keep the positions `state` holds on entry.
  // Allocates nothing per iteration. On divergence (DivergenceMonitor) the state is put back as it was on entry, the
  // step halved for this and every later solve, and the solve run again, up to kMaxRecoveries times; if every
  // attempt diverges the state is left as on entry and the stats say so.
  SolveStats solve(ParticleState& state, const AfterUpdateHook& after_update = {});

  // Changes how later solves stop (rule, iteration cap, tolerances, limits) without rebuilding anything.
  void setStopping(StoppingRule rule, int max_iterations, double displacement_tolerance_m, double time_budget_ms,
                   const SolveLimits& limits);

  // One MSS update (forces, time step, integration) without collision, for benchmarks. Returns the dt used.
  double step(ParticleState& state);

  const SolverSettings& settings() const { return settings_; }
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
  bool attempt(ParticleState& state, const AfterUpdateHook& after_update, SolveStats& stats,
               std::chrono::steady_clock::time_point solve_start);

  const MassSpringSystem& system_;
  SolverSettings settings_;
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
