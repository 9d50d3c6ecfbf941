// What every solver of the mass-spring system shares so they stop, report and fail alike: the stopping rules, the
// limits every solve obeys, the statistics of a solve, divergence detection, spring strain metrics and the hook the
// collision stage plugs into.
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <Eigen/Core>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

namespace muscle_deformation {

enum class StoppingRule {
  iterations,    // exactly max_iterations
  displacement,  // mean free-particle displacement of an iteration < displacement_tolerance_m and no longer growing
                 // (or max_iterations)
  time_budget,   // wall time of the solve reaches time_budget_ms (or max_iterations)
  // RMS net force on the free particles below a tolerance relative to the springs' material constant (or
  // max_iterations); measured by the block descent solver only, the others refuse it.
  force_residual,
};

// Bounds every solve obeys whatever its stopping rule, so that no call can run unbounded: a wall-time ceiling and a
// flag another thread raises to end a solve early (shutdown). Checked after every iteration.
struct SolveLimits {
  double wall_time_limit_ms = 0;            // 0 = no ceiling
  const std::atomic<bool>* cancel = nullptr;  // when set and raised, the solve stops after the current iteration
  // When set and positive, the solve's parallel parts use at most this many threads, read before every sweep: another
  // solve in the process (the node's service beside its stream) holds the other cores. Threads outnumbering the free
  // cores wait at every barrier of a sweep for one that is descheduled, and a frame takes many times longer.
  const std::atomic<int>* max_threads = nullptr;
};

// How one solve stops, passed with every solve call: the caller (a stream frame, a single pose, a benchmark) decides,
// and no solver keeps a rule of its own.
struct StoppingSettings {
  StoppingRule rule = StoppingRule::iterations;
  int max_iterations = 100;                // cap for every rule (exact for `iterations`)
  double displacement_tolerance_m = 1e-6;  // displacement rule: mean free-particle step of an iteration
  // force_residual rule: the RMS net force on the free particles below this times the springs' material constant. It is
  // also what "converged" means for the solvers that measure the residual (block descent, Newton-Krylov), whatever
  // ended their solve.
  double residual_tolerance = 1e-3;
  double time_budget_ms = 16.0;            // time_budget rule: no iteration started that would end past it
  SolveLimits limits;                      // for every rule

  // Exactly `count` iterations (within the limits).
  static StoppingSettings afterIterations(int count) {
    StoppingSettings stopping;
    stopping.rule = StoppingRule::iterations;
    stopping.max_iterations = count;
    return stopping;
  }
  // Until the force residual falls below `tolerance`, at most `max_iterations` iterations.
  static StoppingSettings atResidual(double tolerance, int max_iterations) {
    StoppingSettings stopping;
    stopping.rule = StoppingRule::force_residual;
    stopping.residual_tolerance = tolerance;
    stopping.max_iterations = max_iterations;
    return stopping;
  }
  // Until the mean step falls below `tolerance_m` and stops growing, at most `max_iterations` iterations.
  static StoppingSettings atDisplacement(double tolerance_m, int max_iterations) {
    StoppingSettings stopping;
    stopping.rule = StoppingRule::displacement;
    stopping.displacement_tolerance_m = tolerance_m;
    stopping.max_iterations = max_iterations;
    return stopping;
  }
  // Within `budget_ms` of wall time, at most `max_iterations` iterations.
  static StoppingSettings withinBudget(double budget_ms, int max_iterations) {
    StoppingSettings stopping;
    stopping.rule = StoppingRule::time_budget;
    stopping.time_budget_ms = budget_ms;
    stopping.max_iterations = max_iterations;
    return stopping;
  }
};

// Empty when the settings are usable, otherwise what is wrong (a negative cap or tolerance).
std::string validate(const StoppingSettings& stopping);

// `stopping` for a solve that starts `spent_ms` into its caller's time: the budget and the wall-time ceiling are the
// caller's, so what was spent is gone from both. A budget used up still leaves the one iteration every solve runs; a
// ceiling used up stops the solve after it (it stays a ceiling: 0 would mean none).
StoppingSettings afterTimeSpent(StoppingSettings stopping, double spent_ms);

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
  // L-BFGS: no step along the search direction lowers the energy at machine precision, whatever the stopping rule: the
  // solve is at a minimum (of what the collision hook allows) and says so as convergence.
  bool no_descent_left = false;
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
  // Block descent: RMS net force on the free particles in the last sweep over the springs' material constant (k l0);
  // negative when the solver does not measure it.
  double residual = -1;
  int contacts = 0;                   // reported by the collision hook, last iteration
  double peak_mean_displacement_m = 0;  // largest mean free-particle displacement of any iteration (all attempts)
  // Divergence (see DivergenceMonitor): each recovery restored the entry state and retried with half the step.
  int divergence_recoveries = 0;
  int fibre_steps = 0;  // block descent: coarse steps along the fibres kept (BlockDescentSettings::fibre_modes)
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

// Spring figures against each spring's length in the segmented shape (l0 below: its rest length, or for a belly under
// passive tension the length it rests longer than, SpringSet::prestretch_factor).
struct SpringMetrics {
  double deviation_ratio = 0, mean_strain = 0, max_strain = 0, strain_p99 = 0;
};
// l0 above for spring e.
inline double segmentedLength(const SpringSet& springs, Eigen::Index e) {
  const bool with_prestretch = springs.prestretch_factor.size() == static_cast<Eigen::Index>(springs.size());
  return with_prestretch ? springs.rest_length[e] / springs.prestretch_factor[e] : springs.rest_length[e];
}
// On `threads` threads; the figures are the same for any thread count.
SpringMetrics measureSprings(const SpringSet& springs, const Eigen::Matrix3Xd& position, int threads = 1);
// Fills the spring fields of `stats` (deviation ratio, mean and max strain, strain percentile) at `position`.
void recordSpringMetrics(const SpringSet& springs, const Eigen::Matrix3Xd& position, SolveStats& stats,
                         int threads = 1);

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

}  // namespace muscle_deformation
