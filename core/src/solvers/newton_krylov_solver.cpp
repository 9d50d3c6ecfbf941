#include "muscle_deformation/core/solvers/newton_krylov_solver.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace muscle_deformation {

namespace {
using Clock = std::chrono::steady_clock;
// Sum over the free particles of a . b.
double dot(const std::vector<std::int32_t>& free, const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  double sum = 0;
  for (const std::int32_t p : free) sum += a.col(p).dot(b.col(p));
  return sum;
}
}  // namespace

std::string validate(const NewtonKrylovSettings& settings) {
  if (settings.max_cg_iterations < 1) return "max_cg_iterations must be >= 1";
  if (!(settings.cg_relative_tolerance > 0 && settings.cg_relative_tolerance < 1))
    return "cg_relative_tolerance must lie in (0, 1)";
  return {};
}

NewtonKrylovSolver::NewtonKrylovSolver(const MassSpringSystem& system, const BlockDescentSettings& energy,
                                       NewtonKrylovSettings settings, int threads)
    : system_(system), energy_(system, energy, threads), settings_(settings) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("Newton-Krylov settings: " + problem);
  material_constant_n_ = energy_.materialConstant();
}

void NewtonKrylovSolver::setContactQuery(ContactQuery query, bool every_particle_collides) {
  energy_.setContactQuery(std::move(query), every_particle_collides);
}

SolveStats NewtonKrylovSolver::solve(ParticleState& state, const StoppingSettings& rule,
                                     const AfterUpdateHook& after_update) {
  const auto solve_start = Clock::now();
  if (const std::string problem = validate(rule); !problem.empty())
    throw std::invalid_argument("stopping settings: " + problem);
  SolveStats stats;
  const Eigen::Index n = system_.particleCount();
  if (state.position.cols() != n)
    throw std::invalid_argument("NewtonKrylovSolver: state has " + std::to_string(state.position.cols()) +
                                " particles, the system " + std::to_string(n));
  const std::vector<std::int32_t>& free = energy_.freeParticles();
  const double free_count = std::max<double>(1.0, static_cast<double>(free.size()));
  const Eigen::Matrix3Xd entry = state.position;
  StoppingMonitor stopping(rule.rule, rule.displacement_tolerance_m, rule.time_budget_ms);
  Eigen::Matrix3Xd force, step, residual, preconditioned, search, product, trial;
  std::vector<Eigen::Matrix3d> inverse_blocks;
  last_cg_iterations_ = 0;
  last_residual_ = 0;

  for (int iteration = 0; iteration < rule.max_iterations; ++iteration) {
    auto phase_start = Clock::now();
    energy_.beginFrame(state);  // contacts at the current state; drag towards state.carried_position
    stats.contacts = static_cast<int>(energy_.frameContacts().size());
    stats.collision_ms += millisecondsSince(phase_start);
    phase_start = Clock::now();
    energy_.frameForces(state.position, force, inverse_blocks);
    const double force_norm = std::sqrt(dot(free, force, force));
    last_residual_ = force_norm / std::sqrt(free_count) / material_constant_n_;
    if (!std::isfinite(last_residual_)) {
      stats.diverged = true;
      energy_.endFrame();
      break;
    }
    if (rule.rule == StoppingRule::force_residual && last_residual_ < rule.residual_tolerance) {
      stats.stopping_rule_met = true;
      energy_.endFrame();
      break;
    }

    // Newton: H step = force by block-preconditioned CG.
    const double tolerance = settings_.cg_relative_tolerance;
    step.setZero(3, n);
    residual = force;
    preconditioned.setZero(3, n);
    for (const std::int32_t p : free) preconditioned.col(p) = inverse_blocks[static_cast<std::size_t>(p)] * residual.col(p);
    search = preconditioned;
    double rz = dot(free, residual, preconditioned);
    for (int cg = 0; cg < settings_.max_cg_iterations; ++cg) {
      energy_.frameHessianTimes(state.position, search, product);
      const double curvature = dot(free, search, product);
      ++last_cg_iterations_;
      if (!(curvature > 0)) break;  // the projected Hessian is positive definite; guard against round-off
      const double alpha = rz / curvature;
      for (const std::int32_t p : free) {
        step.col(p) += alpha * search.col(p);
        residual.col(p) -= alpha * product.col(p);
      }
      if (std::sqrt(dot(free, residual, residual)) <= tolerance * force_norm) break;
      for (const std::int32_t p : free) preconditioned.col(p) = inverse_blocks[static_cast<std::size_t>(p)] * residual.col(p);
      const double rz_next = dot(free, residual, preconditioned);
      const double beta = rz_next / rz;
      rz = rz_next;
      for (const std::int32_t p : free) search.col(p) = preconditioned.col(p) + beta * search.col(p);
    }

    // Contacts were listed within the sweeps' margin of touching. A step that carries a collidable particle further
    // could cross a contact nobody listed: the contacts are listed again within the longest such step, so that the
    // line search sees every contact the step can reach.
    double longest = 0;
    for (const std::int32_t p : free)
      if (energy_.boundedStep(p)) longest = std::max(longest, step.col(p).norm());
    if (longest > energy_.contactMargin()) {
      const auto gather_start = Clock::now();
      energy_.endFrame();
      energy_.beginFrame(state, longest + energy_.contactMargin());
      stats.collision_ms += millisecondsSince(gather_start);
    }
    // Backtracking line search on the frame energy.
    const double energy_before = energy_.frameEnergy(state.position);
    const double slope = dot(free, force, step);  // = -gradient . step > 0 for a descent direction
    double accepted = 0;
    double scale = 1.0;
    for (int halving = 0; halving < 30; ++halving, scale *= 0.5) {
      trial = state.position;
      for (const std::int32_t p : free) trial.col(p) += scale * step.col(p);
      if (energy_.frameEnergy(trial) <= energy_before - 1e-4 * scale * slope) {
        accepted = scale;
        break;
      }
    }
    energy_.endFrame();
    double displacement_sum = 0;
    if (accepted > 0) {
      for (const std::int32_t p : free) displacement_sum += accepted * step.col(p).norm();
      state.position = trial;
    }
    state.previous_position = state.position;
    stats.mss_ms += millisecondsSince(phase_start);
    runAfterUpdateHook(after_update, state, stats);
    stats.iterations = iteration + 1;
    stats.mean_displacement_m = displacement_sum / free_count;
    stats.peak_mean_displacement_m = std::max(stats.peak_mean_displacement_m, stats.mean_displacement_m);
    if (accepted == 0) {  // no step lowers the energy at machine precision: at its minimum
      stats.no_descent_left = true;
      break;
    }
    const double elapsed_ms = millisecondsSince(solve_start);
    if (rule.rule != StoppingRule::force_residual && stopping.met(iteration, stats.mean_displacement_m, elapsed_ms)) {
      stats.stopping_rule_met = true;
      break;
    }
    if (solveLimitReached(rule.limits, elapsed_ms, stats)) break;
  }
  if (!stats.diverged && !state.position.allFinite()) stats.diverged = true;
  if (stats.diverged) {
    state.position = entry;
    state.previous_position = entry;
  } else if (stats.iterations > 0 && !stats.stopping_rule_met) {
    // The last residual was taken before the last step: measure where the solve ended, which "converged" judges.
    energy_.beginFrame(state);
    energy_.frameForces(state.position, force, inverse_blocks);
    energy_.endFrame();
    last_residual_ = std::sqrt(dot(free, force, force)) / std::sqrt(free_count) / material_constant_n_;
  }
  stats.residual = last_residual_;
  stats.converged = !stats.diverged && stats.iterations > 0 && last_residual_ < rule.residual_tolerance;
  if (rule.rule == StoppingRule::iterations && !stats.diverged && !stats.time_limit_reached && !stats.cancelled)
    stats.stopping_rule_met = true;
  stats.total_ms = millisecondsSince(solve_start);
  recordSpringMetrics(system_.springs, state.position, stats);
  return stats;
}

}  // namespace muscle_deformation
