#include "muscle_deformation/core/solvers/verlet_solver.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <stdexcept>

namespace muscle_deformation {

namespace {
using Clock = std::chrono::steady_clock;
}  // namespace


double criticalDamping(const MassSpringSystem& system) {
  if (system.springs.size() == 0 || system.mass.size() == 0) return 0;
  const double mean_stiffness = system.springs.stiffness.mean();
  const double mean_mass = system.mass.mean();
  return std::sqrt(4.0 * mean_stiffness * 2.0 * mean_mass);
}

namespace {
double stabilityTimeStep(const MassSpringSystem& system, const Eigen::VectorXd& mass) {
  const Eigen::VectorXd stiffness_sum = springStiffnessSums(system);
  double omega_squared = 0;
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    if (!system.is_fixed[i]) omega_squared = std::max(omega_squared, 2.0 * stiffness_sum[i] / mass[i]);
  return omega_squared > 0 ? 2.0 / std::sqrt(omega_squared) : std::numeric_limits<double>::infinity();
}
}  // namespace

double stabilityTimeStep(const MassSpringSystem& system) { return stabilityTimeStep(system, system.mass); }

Eigen::VectorXd stiffnessScaledMass(const MassSpringSystem& system) {
  // Random sampling along fibres leaves a few very short, very stiff springs (k = material / rest length). With
  // uniform masses they alone dictate the explicit step for every particle. Raising the mass of those particles
  // until no particle is stiffer than the median one changes the dynamics only, not the equilibrium the solver
  // converges to (there are no external forces), and lets the step follow the median particle.
  const Eigen::VectorXd stiffness_sum = springStiffnessSums(system);
  std::vector<double> omega_squared;
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    if (!system.is_fixed[i] && stiffness_sum[i] > 0) omega_squared.push_back(2.0 * stiffness_sum[i] / system.mass[i]);
  Eigen::VectorXd mass = system.mass;
  if (omega_squared.empty()) return mass;
  std::nth_element(omega_squared.begin(), omega_squared.begin() + omega_squared.size() / 2, omega_squared.end());
  const double median = omega_squared[omega_squared.size() / 2];
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    mass[i] = std::max(mass[i], 2.0 * stiffness_sum[i] / median);
  return mass;
}

VerletSolver::VerletSolver(const MassSpringSystem& system, VerletSettings settings)
    : system_(system), settings_(settings) {
  if (!(settings_.dt_s >= 0) || !(settings_.dt_min_s >= 0) || !(settings_.damping_ns_per_m >= 0) ||
      !(settings_.damping_scale >= 0))
    throw std::invalid_argument("solver settings must be finite and non-negative");

  const Eigen::Index n = system_.particleCount();
  force_.setZero(3, n);
  entry_position_.setZero(3, n);
  entry_previous_position_.setZero(3, n);
  packSprings();
  const Eigen::VectorXd mass =
      settings_.mass_rule == MassRule::stiffness_scaled ? stiffnessScaledMass(system_) : system_.mass;
  inverse_mass_ = mass.cwiseInverse();
  for (Eigen::Index i = 0; i < n; ++i) {
    if (system_.is_fixed[i]) continue;
    free_particles_.push_back(static_cast<std::int32_t>(i));
    if (system_.is_boundary[i] && system_.radius[i] > 0) boundary_free_particles_.push_back(static_cast<std::int32_t>(i));
  }
  damping_ = settings_.damping_ns_per_m > 0 ? settings_.damping_ns_per_m
                                            : settings_.damping_scale * criticalDamping(system_);

  // Auto step: below the spring stability bound and below m / c, where the explicit damping term would start to
  // reverse velocities instead of reducing them (eq. 5.1 also assumes c dt / m <= 1).
  double limit = stabilityTimeStep(system_, mass);
  damping_step_limit_ = damping_ > 0 && n > 0 ? mass.minCoeff() / damping_ : std::numeric_limits<double>::infinity();
  limit = std::min(limit, damping_step_limit_);
  if (!std::isfinite(limit)) limit = 1e-3;  // nothing free or no springs: any step is stable
  dt_ = settings_.dt_s > 0 ? settings_.dt_s : 0.9 * limit;
  dt_min_ = settings_.dt_min_s > 0 ? std::min(settings_.dt_min_s, dt_) : dt_ / 10.0;
  previous_dt_ = dt_;
  if (system_.springs.size() > 0) mean_rest_length_ = system_.springs.rest_length.mean();
}

std::size_t VerletSolver::solverBytes() const {
  return packed_springs_.size() * sizeof(PackedSpring) + spring_runs_.size() * sizeof(SpringRun) +
         static_cast<std::size_t>(force_.size() + inverse_mass_.size()) * sizeof(double) +
         (free_particles_.size() + boundary_free_particles_.size()) * sizeof(std::int32_t) +
         static_cast<std::size_t>(entry_position_.size() + entry_previous_position_.size()) * sizeof(double);
}

void VerletSolver::restLengthsChanged() {
  // Packed in spring order (packSprings): the tendon's spring is entry `spring`.
  if (!system_.belly_tone.empty()) {
    for (std::size_t s = 0; s < packed_springs_.size(); ++s)
      packed_springs_[s].rest_length = system_.springs.rest_length[static_cast<Eigen::Index>(s)];
    return;
  }
  for (const TendonPath& tendon : system_.tendon_paths)
    packed_springs_[static_cast<std::size_t>(tendon.spring)].rest_length = system_.springs.rest_length[tendon.spring];
}

void VerletSolver::packSprings() {
  // The solver's own compact copy of the springs: 16 bytes each, grouped in runs that share their first particle, to
  // cut the memory traffic of the force loop, which is what bounds it. Stiffness in single precision only scales a
  // force by 1 + 6e-8; the rest length stays double so the rest shape stays exactly force-free.
  const SpringSet& springs = system_.springs;
  packed_springs_.clear();
  spring_runs_.clear();
  packed_springs_.reserve(springs.size());
  for (std::size_t s = 0; s < springs.size(); ++s) {
    if (spring_runs_.empty() || spring_runs_.back().first_times_3 != 3 * springs.first[s])
      spring_runs_.push_back({3 * springs.first[s], static_cast<std::int32_t>(s)});
    packed_springs_.push_back({3 * springs.second[s], static_cast<float>(springs.stiffness[static_cast<Eigen::Index>(s)]),
                               springs.rest_length[static_cast<Eigen::Index>(s)]});
  }
  spring_runs_.push_back({0, static_cast<std::int32_t>(springs.size())});  // sentinel: end of the last run
}

void VerletSolver::computeForces(const Eigen::Matrix3Xd& position) {
  force_.setZero();
  const double* x = position.data();
  double* f = force_.data();
  const PackedSpring* spring = packed_springs_.data();
  // The first particle's force is summed in registers over its run and stored once; adding into memory spring by
  // spring would chain every addition through a store and a reload.
  for (std::size_t run = 0; run + 1 < spring_runs_.size(); ++run) {
    const std::int32_t a = spring_runs_[run].first_times_3;
    const double ax = x[a], ay = x[a + 1], az = x[a + 2];
    double fx_a = 0, fy_a = 0, fz_a = 0;
    const std::int32_t end = spring_runs_[run + 1].begin;
    for (std::int32_t s = spring_runs_[run].begin; s < end; ++s) {
      const std::int32_t b = spring[s].second_times_3;
      const double dx = x[b] - ax, dy = x[b + 1] - ay, dz = x[b + 2] - az;
      const double length = std::sqrt(dx * dx + dy * dy + dz * dz);
      // Hooke (eq. 2.7): pulls a towards b when stretched, pushes apart when compressed. Coincident particles give
      // no direction to push along and are left alone.
      const double scale = length > 0 ? spring[s].stiffness * (length - spring[s].rest_length) / length : 0.0;
      const double fx = scale * dx, fy = scale * dy, fz = scale * dz;
      fx_a += fx;
      fy_a += fy;
      fz_a += fz;
      f[b] -= fx;
      f[b + 1] -= fy;
      f[b + 2] -= fz;
    }
    f[a] += fx_a;
    f[a + 1] += fy_a;
    f[a + 2] += fz_a;
  }
}

double VerletSolver::adaptiveTimeStep(const ParticleState& state) const {
  // Eq. 5.1 solved as an equality for each boundary particle: LenF dt^2 - c LenX dt + m (LenX - r) = 0; the largest
  // root is the longest step that keeps the particle's move within its radius. The equation assumes c dt / m <= 1.
  double dt = std::min(dt_, damping_step_limit_);
  for (const std::int32_t i : boundary_free_particles_) {
    const double len_f = force_.col(i).norm();
    const double len_x = (state.position.col(i) - state.previous_position.col(i)).norm();
    const double radius = system_.radius[i];
    const double m = 1.0 / inverse_mass_[i];
    const double b = damping_ * len_x;
    const double c = m * (len_x - radius);
    double particle_dt;
    if (len_f > 0) {
      const double discriminant = b * b - 4.0 * len_f * c;
      particle_dt = discriminant >= 0 ? (b + std::sqrt(discriminant)) / (2.0 * len_f) : 0.0;
    } else {
      particle_dt = c <= 0 ? dt_ : 0.0;
    }
    dt = std::min(dt, particle_dt);
  }
  return std::max(dt, dt_min_);
}

VerletSolver::Integration VerletSolver::integrate(ParticleState& state, double dt) {
  // Damped Verlet (eq. 2.14): x' = x + (1 - c dt / m)(x - x_prev) + F dt^2 / m.
  double* x = state.position.data();
  double* x_prev = state.previous_position.data();
  const double* f = force_.data();
  const double* inverse_mass = inverse_mass_.data();
  Integration result;
  for (const std::int32_t i : free_particles_) {
    const std::int32_t k = 3 * i;
    const double keep = 1.0 - damping_ * dt * inverse_mass[i];
    const double acceleration_scale = dt * dt * inverse_mass[i];
    double moved_squared = 0;
    for (int d = 0; d < 3; ++d) {
      const double current = x[k + d];
      const double previous_step = current - x_prev[k + d];
      const double next = current + keep * previous_step + acceleration_scale * f[k + d];
      x_prev[k + d] = current;
      x[k + d] = next;
      moved_squared += (next - current) * (next - current);
      result.step_correlation += (next - current) * previous_step;
    }
    result.displacement_sum += std::sqrt(moved_squared);
  }
  return result;
}

double VerletSolver::step(ParticleState& state) {
  computeForces(state.position);
  const double dt = settings_.dt_rule == TimeStepRule::adaptive ? adaptiveTimeStep(state) : dt_;
  integrate(state, dt);
  previous_dt_ = dt;
  return dt;
}

bool VerletSolver::attempt(ParticleState& state, const StoppingSettings& stopping,
                           const AfterUpdateHook& after_update, SolveStats& stats, Clock::time_point solve_start) {
  const double free_count = std::max<double>(1.0, static_cast<double>(free_particles_.size()));
  StoppingMonitor monitor(stopping.rule, stopping.displacement_tolerance_m, stopping.time_budget_ms);
  DivergenceMonitor divergence(mean_rest_length_);
  for (int iteration = 0; iteration < stopping.max_iterations; ++iteration) {
    const auto mss_start = Clock::now();
    computeForces(state.position);
    const double dt = settings_.dt_rule == TimeStepRule::adaptive ? adaptiveTimeStep(state) : dt_;
    const Integration moved = integrate(state, dt);
    stats.mss_ms += millisecondsSince(mss_start);

    runAfterUpdateHook(after_update, state, stats);
    ++stats.iterations;
    stats.last_dt_s = dt;
    stats.min_dt_s = std::min(stats.min_dt_s, dt);
    stats.max_dt_s = std::max(stats.max_dt_s, dt);
    stats.mean_displacement_m = moved.displacement_sum / free_count;
    stats.peak_mean_displacement_m = std::max(stats.peak_mean_displacement_m, stats.mean_displacement_m);

    if (divergence.diverged(stats.mean_displacement_m, moved.step_correlation)) return false;
    const double elapsed_ms = millisecondsSince(solve_start);
    if (monitor.met(iteration, stats.mean_displacement_m, elapsed_ms)) {
      stats.stopping_rule_met = true;
      stats.converged = stopping.rule == StoppingRule::displacement;
      break;
    }
    if (solveLimitReached(stopping.limits, elapsed_ms, stats)) break;
  }
  // The collision hook of the last iteration runs after the last integration, so check what it left too.
  return state.position.allFinite();
}

SolveStats VerletSolver::solve(ParticleState& state, const StoppingSettings& stopping,
                               const AfterUpdateHook& after_update) {
  if (const std::string problem = validate(stopping); !problem.empty())
    throw std::invalid_argument("stopping settings: " + problem);
  if (stopping.rule == StoppingRule::force_residual)
    throw std::invalid_argument("the verlet solver does not measure a force residual (stopping rule force_residual "
                                "needs solver block_descent or newton_krylov)");
  if (state.position.cols() != system_.particleCount() || state.previous_position.cols() != system_.particleCount())
    throw std::invalid_argument("particle state does not match the mass-spring system (" +
                                std::to_string(state.position.cols()) + " particles given, " +
                                std::to_string(system_.particleCount()) + " expected)");
  SolveStats stats;
  stats.min_dt_s = std::numeric_limits<double>::infinity();
  const auto solve_start = Clock::now();
  entry_position_ = state.position;
  entry_previous_position_ = state.previous_position;

  // Retries share the solve's time budget (StoppingRule::time_budget): a budget spent on a diverged attempt leaves
  // the retry little time, which keeps the frame's cost bounded.
  while (!attempt(state, stopping, after_update, stats, solve_start)) {
    state.position = entry_position_;
    state.previous_position = entry_previous_position_;
    // The diverged attempt's steps (possibly infinite) describe nothing that is left in the state.
    stats.stopping_rule_met = false;
    stats.converged = false;
    stats.mean_displacement_m = 0;
    stats.peak_mean_displacement_m = 0;
    if (stats.divergence_recoveries == kMaxRecoveries) {
      stats.diverged = true;
      break;
    }
    // The step proved unstable for this model: keep the halved one for later solves too.
    ++stats.divergence_recoveries;
    dt_ /= 2.0;
    dt_min_ /= 2.0;
  }
  if (stopping.rule == StoppingRule::iterations && !stats.diverged && !stats.time_limit_reached &&
      !stats.cancelled)
    stats.stopping_rule_met = true;
  if (stats.iterations == 0) stats.min_dt_s = 0;
  stats.time_step_s = dt_;
  stats.total_ms = millisecondsSince(solve_start);
  recordSpringMetrics(system_.springs, state.position, stats);
  return stats;
}

}  // namespace muscle_deformation
