#include "muscle_deformation/core/solvers/block_descent_solver.hpp"

#include "muscle_deformation/core/base/median.hpp"
#include "muscle_deformation/core/base/stopwatch.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <stdexcept>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace muscle_deformation {

namespace {
using Clock = std::chrono::steady_clock;
// Below this many elements a pass outside the sweep stays on one thread (not worth the threads' start; a small
// analytic model never splits).
constexpr std::int32_t kParallelMinimum = 4096;

int everyCore() {
#ifdef _OPENMP
  return omp_get_num_procs();
#else
  return 1;
#endif
}

// A particle's force and symmetric 3 x 3 Hessian, accumulated in scalars (the sweep's inner loop).
struct Block {
  double fx = 0, fy = 0, fz = 0;
  double hxx = 0, hxy = 0, hxz = 0, hyy = 0, hyz = 0, hzz = 0;

  void addIsotropic(double k) {
    hxx += k;
    hyy += k;
    hzz += k;
  }
  // Adds a d d^T to the Hessian.
  void addOuter(double a, double dx, double dy, double dz) {
    hxx += a * dx * dx;
    hxy += a * dx * dy;
    hxz += a * dx * dz;
    hyy += a * dy * dy;
    hyz += a * dy * dz;
    hzz += a * dz * dz;
  }
  double forceSquared() const { return fx * fx + fy * fy + fz * fz; }
  // H^-1 f by cofactors (H is symmetric positive definite: the regularisation sees to it).
  Eigen::Vector3d step() const { return solve(fx, fy, fz); }
  // H^-1 r for any right-hand side r.
  Eigen::Vector3d solve(double rx, double ry, double rz) const {
    const double c00 = hyy * hzz - hyz * hyz, c01 = hxz * hyz - hxy * hzz, c02 = hxy * hyz - hxz * hyy;
    const double c11 = hxx * hzz - hxz * hxz, c12 = hxy * hxz - hxx * hyz, c22 = hxx * hyy - hxy * hxy;
    const double inverse_det = 1.0 / (hxx * c00 + hxy * c01 + hxz * c02);
    return inverse_det * Eigen::Vector3d(c00 * rx + c01 * ry + c02 * rz, c01 * rx + c11 * ry + c12 * rz,
                                         c02 * rx + c12 * ry + c22 * rz);
  }
};

// The tissue drag's force D (c - x) and Hessian D on a particle at x carried to c, D = w (I - (1 - along) t t^T) for
// the unit fibre direction t (t = 0: w I).
inline void addDrag(double w, double along, const Eigen::Vector3d& t, const Eigen::Vector3d& x,
                    const Eigen::Vector3d& carried, Block& block) {
  const Eigen::Vector3d pull = carried - x;
  block.fx += w * pull.x();
  block.fy += w * pull.y();
  block.fz += w * pull.z();
  block.addIsotropic(w);
  if (along >= 1.0) return;  // isotropic: nothing taken off along the fibre (the sweep's common case)
  const double cut = w * (1.0 - along) * t.dot(pull);
  block.fx -= cut * t.x();
  block.fy -= cut * t.y();
  block.fz -= cut * t.z();
  block.addOuter(-w * (1.0 - along), t.x(), t.y(), t.z());
}

// The volume term's force and curvature on particle p (volume_term.hpp): -k (V - V_rest) g and k g g^T.
inline void addVolumeForce(const VolumeTerm& term, const std::vector<double>& volumes, const Eigen::Matrix3Xd& gradients,
                           std::int32_t muscle, std::int32_t p, Block& block) {
  if (!term.active() || gradients.cols() <= p) return;
  const std::size_t m = static_cast<std::size_t>(muscle);
  const double k = term.stiffness[m];
  if (k <= 0) return;
  const Eigen::Vector3d g = gradients.col(p);
  const double pressure = k * (volumes[m] - term.target(m));
  block.fx -= pressure * g.x();
  block.fy -= pressure * g.y();
  block.fz -= pressure * g.z();
  block.addOuter(k, g.x(), g.y(), g.z());
}

// Force and projected Hessian of one spring on particle `x` (the other end at `other`). The Hessian
// k [u u^T + max(0, 1 - l0 / l) (I - u u^T)] drops the negative transverse part of a compressed spring, so every
// block is positive semi-definite and the Newton step is a descent step. With u = d / l it is
// k t I + k (1 - t) / l^2 d d^T, t = max(0, 1 - l0 / l).
inline void addSpring(const double* x, const double* other, double stiffness, double rest_length, Block& block) {
  const double dx = x[0] - other[0], dy = x[1] - other[1], dz = x[2] - other[2];
  const double length_squared = dx * dx + dy * dy + dz * dz;
  if (!(length_squared > 0.0)) {
    // Coincident ends: no direction to push along; the isotropic stiffness keeps the block invertible.
    block.addIsotropic(stiffness);
    return;
  }
  const double inverse_length = 1.0 / std::sqrt(length_squared);
  const double rest_over_length = rest_length * inverse_length;
  const double pull = stiffness * (1.0 - rest_over_length);  // force per unit of d, towards `other`
  block.fx -= pull * dx;
  block.fy -= pull * dy;
  block.fz -= pull * dz;
  // max(0, t) as (t + |t|) / 2: the same value bit for bit (both operations are exact), without the branch the
  // compiler made of std::max, which a spring that is as often stretched as compressed mispredicts.
  const double stretch = 1.0 - rest_over_length;
  const double transverse = 0.5 * (stretch + std::abs(stretch));
  block.addIsotropic(stiffness * transverse);
  block.addOuter(stiffness * (1.0 - transverse) * inverse_length * inverse_length, dx, dy, dz);
}

}  // namespace

double BlockDescentSolver::ContactEntry::depth(const Eigen::Vector3d& x, Eigen::Vector3d& direction) const {
  if (partner == kHalfSpace) {
    direction = normal;
    return -normal.dot(x - centre);
  }
  const Eigen::Vector3d away = x - centre;
  const double length = away.norm();
  direction = length > 0.0 ? Eigen::Vector3d(away / length) : Eigen::Vector3d::UnitX();
  return distance - length;
}

namespace {

using ContactEntry = BlockDescentSolver::ContactEntry;

// One-sided contact spring of stiffness kc pushing `x` out of a contact it is inside of (a sphere it must keep its
// distance from, or a half-space). `curvature_scale` multiplies the Hessian only: 2 for a partner that moves in the same
// parallel step (see sweep()).
inline void addContact(const Eigen::Vector3d& x, const ContactEntry& entry, double stiffness, double curvature_scale,
                       Block& block) {
  Eigen::Vector3d direction;
  const double depth = entry.depth(x, direction);
  if (depth <= 0) return;
  const double push = stiffness * depth;
  block.fx += push * direction.x();
  block.fy += push * direction.y();
  block.fz += push * direction.z();
  block.addOuter(curvature_scale * stiffness, direction.x(), direction.y(), direction.z());
}

inline double springEnergy(const Eigen::Vector3d& x, const Eigen::Vector3d& other, double stiffness, double rest_length) {
  const double stretch = (x - other).norm() - rest_length;
  return 0.5 * stiffness * stretch * stretch;
}

inline double contactEnergy(const Eigen::Vector3d& x, const ContactEntry& entry, double stiffness) {
  const double depth = entry.depth(x);
  return depth > 0 ? 0.5 * stiffness * depth * depth : 0.0;
}

}  // namespace

std::string validate(const BlockDescentSettings& settings) {
  if (!(settings.contact_stiffness_scale > 0) || !std::isfinite(settings.contact_stiffness_scale))
    return "contact_stiffness_scale must be a positive number";
  if (!(settings.muscle_contact_stiffness_scale >= 0) || !std::isfinite(settings.muscle_contact_stiffness_scale))
    return "muscle_contact_stiffness_scale must be 0 (the contact scale) or a positive number";
  if (!(settings.chebyshev_rho >= 0 && settings.chebyshev_rho < 1)) return "chebyshev_rho must lie in [0, 1)";
  if (settings.chebyshev_delay < 0) return "chebyshev_delay must be >= 0";
  if (!(settings.contact_margin_scale >= 0) || !std::isfinite(settings.contact_margin_scale))
    return "contact_margin_scale must be a non-negative number";
  if (settings.contact_newton_steps < 1) return "contact_newton_steps must be >= 1";
  if (!(settings.tissue_relaxation_s >= 0) || !std::isfinite(settings.tissue_relaxation_s))
    return "tissue_relaxation_s must be a finite number >= 0";
  if (!(settings.volume_stiffness >= 0) || !std::isfinite(settings.volume_stiffness))
    return "volume_stiffness must be a finite number >= 0";
  if (settings.fibre_modes < 0 || settings.fibre_modes > 16) return "fibre_modes must lie in [0, 16]";
  if (settings.fibre_modes == 1) return "fibre_modes must be 0 (none) or at least 2 (hat functions along the fibre)";
  if (!(settings.volume_pressure_gain >= 0 && settings.volume_pressure_gain <= 1))
    return "volume_pressure_gain must lie in [0, 1]";
  if (!(settings.drag_along_fibre >= 0 && settings.drag_along_fibre <= 1))
    return "drag_along_fibre must lie in [0, 1]";
  if (!(settings.across_fibre_tie >= 0) || !std::isfinite(settings.across_fibre_tie))
    return "across_fibre_tie must be a finite number >= 0";
  if (settings.across_fibre_tie > 0 && !(settings.tissue_relaxation_s > 0))
    return "across_fibre_tie needs the tissue drag (tissue_relaxation_s > 0): the tie shares its frame anchor";
  if (settings.across_fibre_tie > 0 && settings.balance_rest_shape && !(settings.drag_along_fibre > 0))
    return "balance_rest_shape needs drag_along_fibre > 0: the balance along the fibre rides on the drag there";
  return {};
}

double relativeSpringResidual(const MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
  const Eigen::Index n = system.particleCount();
  Eigen::Matrix3Xd force = Eigen::Matrix3Xd::Zero(3, n);
  std::vector<double> material;
  material.reserve(system.springs.size());
  for (std::size_t s = 0; s < system.springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    const Eigen::Vector3d d = position.col(system.springs.first[s]) - position.col(system.springs.second[s]);
    const double length = d.norm();
    material.push_back(system.springs.stiffness[e] * system.springs.rest_length[e]);
    if (length == 0.0) continue;
    const Eigen::Vector3d f = system.springs.stiffness[e] * (length - system.springs.rest_length[e]) / length * d;
    force.col(system.springs.first[s]) -= f;
    force.col(system.springs.second[s]) += f;
  }
  double sum = 0;
  Eigen::Index free_count = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (system.is_fixed[static_cast<std::size_t>(i)]) continue;
    sum += force.col(i).squaredNorm();
    ++free_count;
  }
  const double constant = material.empty() ? 0.0 : upperMedian(std::move(material));
  if (free_count == 0 || constant <= 0) return 0.0;
  return std::sqrt(sum / static_cast<double>(free_count)) / constant;
}

BlockDescentSolver::BlockDescentSolver(const MassSpringSystem& system, BlockDescentSettings settings, int threads)
    : system_(system), settings_(settings), threads_setting_(threads) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("block descent settings: " + problem);
  if (threads < kThreadsMeasured)
    throw std::invalid_argument("block descent: threads must be >= -1 (0 = every core, -1 = one or every core as "
                                "measured), not " + std::to_string(threads));
  thread_count_ = threads > 0 ? threads : everyCore();
  const Eigen::Index n = system_.particleCount();
  const SpringSet& springs = system_.springs;

  // Each particle's springs, packed contiguously: a sweep reads them in visiting order.
  neighbour_begin_.assign(static_cast<std::size_t>(n) + 1, 0);
  for (std::size_t s = 0; s < springs.size(); ++s) {
    ++neighbour_begin_[static_cast<std::size_t>(springs.first[s]) + 1];
    ++neighbour_begin_[static_cast<std::size_t>(springs.second[s]) + 1];
  }
  for (std::size_t i = 0; i < static_cast<std::size_t>(n); ++i) neighbour_begin_[i + 1] += neighbour_begin_[i];
  neighbours_.resize(static_cast<std::size_t>(neighbour_begin_.back()));
  std::vector<std::int32_t> spring_of_entry(neighbours_.size());
  std::vector<std::int32_t> fill(neighbour_begin_.begin(), neighbour_begin_.end() - 1);
  std::vector<double> material;
  material.reserve(springs.size());
  double rest_sum = 0;
  for (std::size_t s = 0; s < springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    const double k = springs.stiffness[e], l0 = springs.rest_length[e];
    const NeighbourSpring packed_to_second{springs.second[s], k};
    const NeighbourSpring packed_to_first{springs.first[s], k};
    spring_of_entry[static_cast<std::size_t>(fill[static_cast<std::size_t>(springs.first[s])])] = static_cast<std::int32_t>(s);
    neighbours_[static_cast<std::size_t>(fill[static_cast<std::size_t>(springs.first[s])]++)] = packed_to_second;
    spring_of_entry[static_cast<std::size_t>(fill[static_cast<std::size_t>(springs.second[s])])] = static_cast<std::int32_t>(s);
    neighbours_[static_cast<std::size_t>(fill[static_cast<std::size_t>(springs.second[s])]++)] = packed_to_first;
    material.push_back(k * l0);
    rest_sum += l0;
  }
  material_constant_n_ = springs.size() > 0 ? upperMedian(std::move(material)) : 1.0;
  mean_rest_length_ = springs.size() > 0 ? rest_sum / static_cast<double>(springs.size()) : 1.0;

  const double median_radius = system_.medianCollisionRadius();
  const double typical_radius = median_radius > 0 ? median_radius : mean_rest_length_;
  contact_stiffness_ = settings_.contact_stiffness_scale * material_constant_n_ / typical_radius;
  contact_margin_m_ = settings_.contact_margin_scale * typical_radius;

  // A tiny isotropic term (1e-9 of the particle's summed spring stiffness) keeps a block invertible when all of a
  // particle's springs are compressed along one line; it changes no equilibrium, only the length of a step.
  // Each particle's contact stiffness is also at least contact_stiffness_scale times its summed spring stiffness:
  // random sampling leaves springs a few micrometres long (k = material / rest length up to 10^4 x the median), and a
  // free particle tied by one to an attachment inside a bone sphere would otherwise stay inside with it.
  regularisation_.setZero(n);
  spring_stiffness_sum_.setZero(n);
  particle_contact_stiffness_.setZero(n);
  particle_pair_stiffness_.setZero(n);
  const double pair_scale = settings_.pairStiffnessScale();
  const double pair_floor = pair_scale * material_constant_n_ / typical_radius;
  for (Eigen::Index i = 0; i < n; ++i) {
    double sum = 0;
    for (std::int32_t k = neighbour_begin_[static_cast<std::size_t>(i)]; k < neighbour_begin_[static_cast<std::size_t>(i) + 1]; ++k)
      sum += neighbours_[static_cast<std::size_t>(k)].stiffness;
    regularisation_[i] = 1e-9 * sum + 1e-12;
    spring_stiffness_sum_[i] = sum;
    particle_contact_stiffness_[i] = std::max(contact_stiffness_, settings_.contact_stiffness_scale * sum);
    particle_pair_stiffness_[i] = std::max(pair_floor, pair_scale * sum);
  }
  for (Eigen::Index i = 0; i < n; ++i)
    if (!system_.is_fixed[static_cast<std::size_t>(i)]) free_particles_.push_back(static_cast<std::int32_t>(i));
  buildColouring();
  updateDragWeights();
  if (settings_.fibre_modes > 0) buildFibreModes();
  // Springs repacked in visiting order: a sweep then reads them front to back, instead of jumping through the
  // particle-ordered lists colour by colour (the sweep's cost is mostly reading them).
  std::vector<NeighbourSpring> visit_order;
  visit_order.reserve(neighbours_.size());
  neighbour_rest_length_.clear();
  neighbour_rest_length_.reserve(neighbours_.size());
  slot_spring_begin_.assign(coloured_particles_.size() + 1, 0);
  std::vector<char> tendon_spring(springs.size(), 0);
  for (const TendonPath& tendon : system_.tendon_paths) tendon_spring[static_cast<std::size_t>(tendon.spring)] = 1;
  for (std::size_t slot = 0; slot < coloured_particles_.size(); ++slot) {
    const std::size_t p = static_cast<std::size_t>(coloured_particles_[slot]);
    for (std::int32_t k = neighbour_begin_[p]; k < neighbour_begin_[p + 1]; ++k) {
      const std::int32_t spring = spring_of_entry[static_cast<std::size_t>(k)];
      if (tendon_spring[static_cast<std::size_t>(spring)] || !system_.belly_tone.empty())
        pose_dependent_entries_.emplace_back(spring, static_cast<std::int32_t>(visit_order.size()));
      visit_order.push_back(neighbours_[static_cast<std::size_t>(k)]);
      neighbour_rest_length_.push_back(springs.rest_length[spring]);
    }
    slot_spring_begin_[slot + 1] = static_cast<std::int32_t>(visit_order.size());
  }
  neighbours_ = std::move(visit_order);
  neighbour_begin_.clear();
  residual_squared_.setZero(n);
  step_length_.setZero(n);
  step_bound_.setZero(n);
  volume_change_.setZero(n);
  contact_begin_.assign(static_cast<std::size_t>(n) + 1, 0);
  bounded_step_.assign(static_cast<std::size_t>(n), 0);
  for (Eigen::Index i = 0; i < system_.radius.size(); ++i) bounded_step_[static_cast<std::size_t>(i)] = system_.radius[i] > 0;
}

void BlockDescentSolver::setVolumeTerm(VolumeTerm term) {
  if (term.active() && (static_cast<int>(term.stiffness.size()) != system_.muscleCount() ||
                        term.rest_volume_m3.size() != term.stiffness.size() ||
                        (!term.target_volume_m3.empty() && term.target_volume_m3.size() != term.stiffness.size())))
    throw std::invalid_argument("block descent: a volume term of " + std::to_string(term.stiffness.size()) +
                                " muscles for a system of " + std::to_string(system_.muscleCount()));
  volume_ = std::move(term);
  volume_gradient_.resize(3, 0);
  const Eigen::Index n = system_.particleCount();
  volume_step_.setZero(3, n);
  volume_inverse_gradient_.setZero(3, n);
  volume_pending_.assign(static_cast<std::size_t>(n), 0);
  volume_direct_.assign(static_cast<std::size_t>(n), 0);
}

void BlockDescentSolver::limitStep(std::int32_t p, const Eigen::Vector3d& start, Eigen::Vector3d& x) const {
  const double bound = step_bound_[p];
  if (bound < 0) return;
  const double length = (x - start).norm();
  if (length > bound) x = start + (bound / length) * (x - start);
}

void BlockDescentSolver::applyVolumeSteps(Eigen::Matrix3Xd& position, const std::int32_t* slots, std::int32_t begin,
                                          std::int32_t end, int threads) {
  const auto slot = [slots](std::int32_t i) { return static_cast<std::size_t>(slots ? slots[i] : i); };
  // The colour's particles of one muscle minimise, together, their own quadratic models (step a_p = H_p^-1 f_p without
  // the volume) plus k/2 (V + sum g_p . d_p - V_rest)^2, which couples them through one scalar: with b_p = H_p^-1 g_p,
  // d_p = a_p - mu b_p and mu = k (V - V_rest + sum g.a) / (1 + k sum g.b) (Sherman-Morrison). Each particle taking the
  // whole volume change for itself would overshoot it once per particle of the colour.
  const std::size_t muscles = volume_now_.size();
  // Particles in contact took the volume term in their own step (their volume change is known): the others of the
  // colour see the volume after them.
  for (std::int32_t i = begin; i < end; ++i) {
    const std::int32_t p = coloured_particles_[slot(i)];
    if (!volume_direct_[static_cast<std::size_t>(p)]) continue;
    volume_now_[static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(p)])] += volume_change_[p];
    volume_direct_[static_cast<std::size_t>(p)] = 0;
  }
  colour_a_.assign(muscles, 0.0);
  colour_b_.assign(muscles, 0.0);
  for (std::int32_t i = begin; i < end; ++i) {
    const std::int32_t p = coloured_particles_[slot(i)];
    if (!volume_pending_[static_cast<std::size_t>(p)]) continue;
    const std::size_t m = static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(p)]);
    colour_a_[m] += volume_gradient_.col(p).dot(volume_step_.col(p));
    colour_b_[m] += volume_gradient_.col(p).dot(volume_inverse_gradient_.col(p));
  }
  for (std::size_t m = 0; m < muscles; ++m) {
    const double k = volume_.stiffness[m];
    colour_a_[m] = k * (volume_now_[m] - volume_.target(m) + colour_a_[m]) / (1.0 + k * colour_b_[m]);  // mu
  }
  // Each particle alone, split over the sweep's threads (the same result).
#pragma omp parallel for num_threads(threads) schedule(static) if (end - begin > kParallelMinimum)
  for (std::int32_t i = begin; i < end; ++i) {
    const std::int32_t p = coloured_particles_[slot(i)];
    if (!volume_pending_[static_cast<std::size_t>(p)]) continue;
    const double mu = colour_a_[static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(p)])];
    const Eigen::Vector3d start = position.col(p);
    Eigen::Vector3d x = start + volume_step_.col(p) - mu * volume_inverse_gradient_.col(p);
    limitStep(p, start, x);
    step_length_[p] = (x - start).norm();
    volume_change_[p] = volume_gradient_.col(p).dot(x - start);
    position.col(p) = x;
  }
  // The steps changed the muscles' volumes by sum g . d (each exact on its own, V being linear in one particle; the
  // cross terms of particles moved together are second order), added in particle order so that the result does not
  // depend on the thread count.
  for (std::int32_t i = begin; i < end; ++i) {
    const std::int32_t p = coloured_particles_[slot(i)];
    if (!volume_pending_[static_cast<std::size_t>(p)]) continue;
    volume_now_[static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(p)])] += volume_change_[p];
    volume_pending_[static_cast<std::size_t>(p)] = 0;
  }
}

void BlockDescentSolver::setVolumeTargets(const std::vector<double>& target_volume_m3) {
  if (!volume_.active()) return;
  if (target_volume_m3.size() != volume_.stiffness.size())
    throw std::invalid_argument("block descent: " + std::to_string(target_volume_m3.size()) +
                                " volume targets for a volume term of " + std::to_string(volume_.stiffness.size()) +
                                " muscles");
  volume_.target_volume_m3 = target_volume_m3;
}

void BlockDescentSolver::evaluateVolume(const Eigen::Matrix3Xd& position) {
  if (!volume_.active()) return;
  volume_.evaluate(position, volume_now_, volume_gradient_);
}

double BlockDescentSolver::volumeEnergy() const { return volumeEnergyOf(volume_now_); }

double BlockDescentSolver::volumeEnergyOf(const std::vector<double>& volumes) const {
  double energy = 0;
  if (!volume_.active()) return energy;
  for (std::size_t m = 0; m < volumes.size(); ++m) {
    const double excess = volumes[m] - volume_.target(m);
    energy += 0.5 * volume_.stiffness[m] * excess * excess;
  }
  return energy;
}

void BlockDescentSolver::restLengthsChanged() {
  // With the belly's tone every entry changes every frame: the gather writes only the rest lengths' own array, in
  // entry order, split over the cores (each entry is written once, so the result does not depend on the split).
  const std::int32_t count = static_cast<std::int32_t>(pose_dependent_entries_.size());
  const Eigen::VectorXd& rest_length = system_.springs.rest_length;
#pragma omp parallel for num_threads(thread_count_) schedule(static) if (count > kParallelMinimum)
  for (std::int32_t k = 0; k < count; ++k) {
    const auto& [spring, entry] = pose_dependent_entries_[static_cast<std::size_t>(k)];
    neighbour_rest_length_[static_cast<std::size_t>(entry)] = rest_length[spring];
  }
}

void BlockDescentSolver::updateDragWeights() {
  const double factor = settings_.tissue_relaxation_s / frame_interval_s_;
  const double tie = tiesAcrossFibres() ? settings_.across_fibre_tie : 0.0;
  drag_weight_.setZero(system_.particleCount());
  for (const std::int32_t p : free_particles_) drag_weight_[p] = (factor + tie) * spring_stiffness_sum_[p];
  // Weighted shares along the fibre (the tie has none there): a' = w a / (w + tau), the same for every particle, and the
  // tie's share of the merged anchor, tau / (w + tau).
  drag_along_ = tie > 0 ? factor * settings_.drag_along_fibre / (factor + tie) : settings_.drag_along_fibre;
  tie_share_ = tie > 0 ? tie / (factor + tie) : 0.0;
}

const Eigen::Matrix3Xd& BlockDescentSolver::frameDragAnchor(const ParticleState& state, const Eigen::Matrix3Xd& carried,
                                                            Eigen::Matrix3Xd& merged) {
  if (!tiesAcrossFibres()) {
    updateDragDirections(carried);
    return carried;
  }
  if (state.rest_carried_position.cols() != carried.cols())
    throw std::invalid_argument("block descent: across_fibre_tie needs state.rest_carried_position (" +
                                std::to_string(state.rest_carried_position.cols()) + " columns for " +
                                std::to_string(carried.cols()) + " particles)");
  // The fibres' directions in the rest shape as the bones carry it: for a held pose the tie is then one fixed energy
  // from frame to frame. Taken from where the tissue carries the particles, a fibre that folds turns its particles'
  // directions from frame to frame and the tie with them, and a held stream kept moving (0.5 mm a frame with every
  // frame converged). The drag shares the direction (one quadratic per particle).
  updateDragDirections(state.rest_carried_position);
  // m = c + tau / (w + tau) (I - t t^T)(h - c): the tie's pull across the fibre joins the drag's anchor.
  merged = carried;
  const auto free_count = static_cast<std::int32_t>(free_particles_.size());
  // Each particle alone: split over the cores, the same result.
#pragma omp parallel for num_threads(thread_count_) schedule(static) if (free_count > kParallelMinimum)
  for (std::int32_t k = 0; k < free_count; ++k) {
    const std::int32_t p = free_particles_[static_cast<std::size_t>(k)];
    const Eigen::Vector3d t = drag_direction_.col(p);
    Eigen::Vector3d towards_rest = state.rest_carried_position.col(p) - carried.col(p);
    towards_rest -= t.dot(towards_rest) * t;
    merged.col(p) += tie_share_ * towards_rest;
  }
  if (balancesRest()) {
    if (state.rest_balance_force.cols() != carried.cols())
      throw std::invalid_argument("block descent: balance_rest_shape needs state.rest_balance_force (" +
                                  std::to_string(state.rest_balance_force.cols()) + " columns for " +
                                  std::to_string(carried.cols()) + " particles)");
    // A constant force b is the energy -b^T x; with the quadratic W about m it is W about m + W^-1 b, up to a constant.
    // W^-1 = ((I - t t^T) + t t^T / a') / w, a' > 0 (validated).
#pragma omp parallel for num_threads(thread_count_) schedule(static) if (free_count > kParallelMinimum)
    for (std::int32_t k = 0; k < free_count; ++k) {
      const std::int32_t p = free_particles_[static_cast<std::size_t>(k)];
      if (!(drag_weight_[p] > 0)) continue;
      const Eigen::Vector3d t = drag_direction_.col(p);
      const Eigen::Vector3d b = state.rest_balance_force.col(p);
      const double along = t.dot(b);
      merged.col(p) += (b - along * t + (along / drag_along_) * t) / drag_weight_[p];
    }
  }
  return merged;
}

void BlockDescentSolver::updateDragDirections(const Eigen::Matrix3Xd& anchor) {
  if (anisotropicDrag()) drag_direction_ = fibreDirections(system_, anchor);
}

double BlockDescentSolver::dragEnergy(std::int32_t p, const Eigen::Vector3d& x, const Eigen::Vector3d& carried) const {
  const Eigen::Vector3d d = x - carried;
  double squared = d.squaredNorm();
  if (anisotropicDrag()) {
    const double along = drag_direction_.col(p).dot(d);
    squared -= (1.0 - drag_along_) * along * along;
  }
  return 0.5 * drag_weight_[p] * squared;
}

void BlockDescentSolver::setFrameInterval(double seconds) {
  if (!std::isfinite(seconds)) seconds = kNominalFrameIntervalS;
  const double clamped = std::clamp(seconds, kMinFrameIntervalS, kMaxFrameIntervalS);
  if (clamped == frame_interval_s_) return;
  frame_interval_s_ = clamped;
  updateDragWeights();
}

void BlockDescentSolver::setContactQuery(ContactQuery query, bool every_particle_collides) {
  contact_query_ = std::move(query);
  for (Eigen::Index i = 0; i < system_.radius.size(); ++i)
    bounded_step_[static_cast<std::size_t>(i)] = every_particle_collides || system_.radius[i] > 0;
}

void BlockDescentSolver::buildColouring() {
  // Greedy colouring of the free particles in index order: the smallest colour no spring neighbour has. Particles of
  // one colour share no spring, so their steps are independent.
  const std::size_t n = static_cast<std::size_t>(system_.particleCount());
  std::vector<std::int32_t> colour(n, -1);
  std::vector<std::int32_t> taken_by;  // per colour: the last particle that saw it taken
  int colours = 0;
  for (const std::int32_t p : free_particles_) {
    for (std::int32_t k = neighbour_begin_[static_cast<std::size_t>(p)]; k < neighbour_begin_[static_cast<std::size_t>(p) + 1]; ++k) {
      const std::int32_t c = colour[static_cast<std::size_t>(neighbours_[static_cast<std::size_t>(k)].other)];
      if (c >= 0) taken_by[static_cast<std::size_t>(c)] = p;
    }
    int chosen = 0;
    while (chosen < colours && taken_by[static_cast<std::size_t>(chosen)] == p) ++chosen;
    if (chosen == colours) {
      taken_by.push_back(-1);
      ++colours;
    }
    colour[static_cast<std::size_t>(p)] = chosen;
  }
  colour_of_ = colour;
  colour_begin_.assign(static_cast<std::size_t>(colours) + 1, 0);
  for (const std::int32_t p : free_particles_) ++colour_begin_[static_cast<std::size_t>(colour[static_cast<std::size_t>(p)]) + 1];
  for (int c = 0; c < colours; ++c) colour_begin_[static_cast<std::size_t>(c) + 1] += colour_begin_[static_cast<std::size_t>(c)];
  coloured_particles_.resize(free_particles_.size());
  std::vector<std::int32_t> fill(colour_begin_.begin(), colour_begin_.end() - 1);
  for (const std::int32_t p : free_particles_)
    coloured_particles_[static_cast<std::size_t>(fill[static_cast<std::size_t>(colour[static_cast<std::size_t>(p)])]++)] = p;
}

void BlockDescentSolver::gatherContacts(const ParticleState& state, double margin_m) {
  contacts_.clear();
  if (contact_query_) contact_query_(state, margin_m < 0 ? contact_margin_m_ : margin_m, contacts_);
  // Counting sort of the contacts by particle; a pair is entered at both ends with the partner's index (the sweep
  // copies the partner's position before each colour).
  std::fill(contact_begin_.begin(), contact_begin_.end(), 0);
  for (const auto& o : contacts_.obstacles) ++contact_begin_[static_cast<std::size_t>(o.particle) + 1];
  for (const auto& h : contacts_.half_spaces) ++contact_begin_[static_cast<std::size_t>(h.particle) + 1];
  for (const auto& p : contacts_.pairs) {
    ++contact_begin_[static_cast<std::size_t>(p.first) + 1];
    ++contact_begin_[static_cast<std::size_t>(p.second) + 1];
  }
  for (std::size_t i = 0; i + 1 < contact_begin_.size(); ++i) contact_begin_[i + 1] += contact_begin_[i];
  contact_entries_.resize(static_cast<std::size_t>(contact_begin_.back()));
  std::vector<std::int32_t> fill(contact_begin_.begin(), contact_begin_.end() - 1);
  for (const auto& o : contacts_.obstacles)
    contact_entries_[static_cast<std::size_t>(fill[static_cast<std::size_t>(o.particle)]++)] = {
        o.centre, Eigen::Vector3d::Zero(), o.distance, ContactEntry::kObstacle, false};
  for (const auto& h : contacts_.half_spaces)
    contact_entries_[static_cast<std::size_t>(fill[static_cast<std::size_t>(h.particle)]++)] = {
        h.point, h.normal, 0.0, ContactEntry::kHalfSpace, false};
  for (const auto& p : contacts_.pairs) {
    const std::int32_t first_colour = colour_of_[static_cast<std::size_t>(p.first)];
    const bool same_colour = first_colour >= 0 && first_colour == colour_of_[static_cast<std::size_t>(p.second)];
    contact_entries_[static_cast<std::size_t>(fill[static_cast<std::size_t>(p.first)]++)] = {
        Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), p.distance, p.second, same_colour};
    contact_entries_[static_cast<std::size_t>(fill[static_cast<std::size_t>(p.second)]++)] = {
        Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), p.distance, p.first, same_colour};
  }
}

void BlockDescentSolver::listContactSlots() {
  // The visiting slots with a contact, colour by colour: all that the closing contact pass visits.
  const int colours = colourCount();
  contact_slots_.clear();
  contact_slot_begin_.assign(static_cast<std::size_t>(colours) + 1, 0);
  for (int c = 0; c < colours; ++c) {
    for (std::int32_t k = colour_begin_[static_cast<std::size_t>(c)]; k < colour_begin_[static_cast<std::size_t>(c) + 1];
         ++k) {
      const std::size_t p = static_cast<std::size_t>(coloured_particles_[static_cast<std::size_t>(k)]);
      if (contact_begin_[p + 1] > contact_begin_[p]) contact_slots_.push_back(k);
    }
    contact_slot_begin_[static_cast<std::size_t>(c) + 1] = static_cast<std::int32_t>(contact_slots_.size());
  }
}

int BlockDescentSolver::sweepThreads(const SolveLimits& limits) const {
  const int threads =
      threads_setting_ == kThreadsMeasured && thread_count_ > 1 ? measuredThreadChoice() : thread_count_;
  return cappedThreads(threads, limits);
}

int cappedThreads(int threads, const SolveLimits& limits) {
  if (limits.max_threads == nullptr) return threads;
  const int cap = limits.max_threads->load(std::memory_order_relaxed);
  return cap > 0 ? std::min(cap, threads) : threads;
}

int parallelThreads(int threads, const SolveLimits& limits) {
  return cappedThreads(threads > 0 ? threads : everyCore(), limits);
}

int BlockDescentSolver::measuredThreadChoice() const {
  const double one = sweep_ms_[0], every = sweep_ms_[1];
  if (every <= 0) return thread_count_;  // every core first
  if (one <= 0) return 1;
  const int faster = one < every ? 1 : thread_count_;
  const int slower = faster == 1 ? thread_count_ : 1;
  return sweeps_since_probe_ >= kThreadProbeInterval ? slower : faster;
}

void BlockDescentSolver::recordSweepTime(int threads, double milliseconds) {
  if (threads_setting_ != kThreadsMeasured || thread_count_ == 1) return;
  if (threads != 1 && threads != thread_count_) return;  // capped in between: neither estimate
  const bool probe = threads != (sweep_ms_[0] > 0 && sweep_ms_[0] < sweep_ms_[1] ? 1 : thread_count_);
  double& estimate = sweep_ms_[threads == 1 ? 0 : 1];
  // A running mean that follows the load within a few sweeps and forgets a single interrupted one.
  estimate = estimate > 0 ? 0.7 * estimate + 0.3 * milliseconds : milliseconds;
  sweeps_since_probe_ = probe ? 0 : sweeps_since_probe_ + 1;
}

void BlockDescentSolver::sweep(Eigen::Matrix3Xd& position, double& residual_squared_sum, double& displacement_sum,
                               int threads, bool touching_only) {
  const int colours = colourCount();
  // Partners of a muscle-muscle contact may share a colour (no spring joins them): they are read from a copy taken
  // before the colour, so the sweep's result does not depend on which thread moves first. Both then move at once, each
  // as if the other stood still, and together would overshoot the overlap twice (and chatter); doubling the contact's
  // curvature for such pairs makes each take half, which together is the whole overlap.
  // The closing contact pass (touching_only) visits only the slots with a contact (contact_slots_): the others would
  // be passed over; the full sweep visits every slot. `slot(i)` is the i-th visited slot of the colour.
  const std::vector<std::int32_t>& visit_begin = touching_only ? contact_slot_begin_ : colour_begin_;
  const std::int32_t* visit_slot = touching_only ? contact_slots_.data() : nullptr;
  const auto slot = [visit_slot](std::int32_t i) { return visit_slot ? visit_slot[i] : i; };
  for (int c = 0; c < colours; ++c) {
    const std::int32_t begin = visit_begin[static_cast<std::size_t>(c)], end = visit_begin[static_cast<std::size_t>(c) + 1];
    for (std::int32_t i = begin; i < end; ++i) {
      const std::int32_t p = coloured_particles_[static_cast<std::size_t>(slot(i))];
      for (std::int32_t e = contact_begin_[static_cast<std::size_t>(p)]; e < contact_begin_[static_cast<std::size_t>(p) + 1]; ++e) {
        ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
        if (entry.partner >= 0) entry.centre = position.col(entry.partner);
      }
    }
    // Guided chunks, at least 16: on the gait (all 26 muscles, 2 threads) a static split of each colour swept slower, as
    // particles with contacts cost several times the others and lie together in index order, so one half of a colour
    // can carry most of them; chunks of a fixed 32 (dynamic) took 1.13x as long as guided ones (7 paired rounds,
    // 2026-11-28), whose large first chunks cost fewer hand-outs and whose small last ones still even out the colour's
    // end (at least 64: the same). Each particle of a colour reads only other colours' positions (or a copy), so the
    // result does not depend on which thread takes which chunk.
#pragma omp parallel for num_threads(threads) schedule(guided, 16)
    for (std::int32_t i = begin; i < end; ++i) {
      const std::int32_t k = slot(i);
      const std::int32_t p = coloured_particles_[static_cast<std::size_t>(k)];
      const std::int32_t contact_begin = contact_begin_[static_cast<std::size_t>(p)];
      const std::int32_t contact_end = contact_begin_[static_cast<std::size_t>(p) + 1];
      if (touching_only) {
        bool touching = false;
        for (std::int32_t e = contact_begin; e < contact_end && !touching; ++e) {
          const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
          touching = entry.depth(position.col(p)) > 0;
        }
        if (!touching) {
          residual_squared_[p] = 0;
          step_length_[p] = 0;
          volume_change_[p] = 0;
          continue;
        }
      }
      const std::int32_t spring_begin = slot_spring_begin_[static_cast<std::size_t>(k)];
      const std::int32_t spring_end = slot_spring_begin_[static_cast<std::size_t>(k) + 1];
      const bool has_contacts = contact_end > contact_begin;
      const double drag = drag_weight_[p];
      const double drag_along = drag_along_;
      const Eigen::Vector3d carried = drag_anchor_->col(p);
      const Eigen::Vector3d fibre_direction = dragDirection(p);
      // The muscle's volume term: V is linear in this particle's position (volume_term.hpp), V = V_now + g . (x - start).
      const std::int32_t muscle = system_.muscle_of[static_cast<std::size_t>(p)];
      const bool volume_on = volume_.active() && volume_.stiffness[static_cast<std::size_t>(muscle)] > 0 &&
                             volume_gradient_.col(p).squaredNorm() > 0;
      const double volume_k = volume_on ? volume_.stiffness[static_cast<std::size_t>(muscle)] : 0.0;
      const Eigen::Vector3d volume_g = volume_on ? Eigen::Vector3d(volume_gradient_.col(p)) : Eigen::Vector3d::Zero();
      const double volume_excess =
          volume_on ? volume_now_[static_cast<std::size_t>(muscle)] - volume_.target(static_cast<std::size_t>(muscle))
                    : 0.0;
      const Eigen::Vector3d start = position.col(p);
      // A particle with contacts takes the volume term into its own step, so that the step's halving minds it: the
      // colour's joint volume step (applyVolumeSteps) moves a particle along H^-1 g without looking at the contacts,
      // and pushed particles into the bones that the next sweep pushed out again; the residual then stopped falling.
      const bool volume_inline = volume_on && has_contacts;
      const auto volume_excess_at = [&](const Eigen::Vector3d& at) { return volume_excess + volume_g.dot(at - start); };
      // The particle's own energy with every other particle held: what its step must decrease.
      const auto local_energy = [&](const Eigen::Vector3d& at) {
        double energy = 0;
        for (std::int32_t s = spring_begin; s < spring_end; ++s) {
          const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
          energy += springEnergy(at, position.col(spring.other), spring.stiffness,
                                 neighbour_rest_length_[static_cast<std::size_t>(s)]);
        }
        for (std::int32_t e = contact_begin; e < contact_end; ++e) {
          const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
          energy += contactEnergy(at, entry, contactStiffnessOf(p, entry));
        }
        if (volume_inline) energy += 0.5 * volume_k * volume_excess_at(at) * volume_excess_at(at);
        return energy + dragEnergy(p, at, carried);
      };
      Eigen::Vector3d x = start;
      const int newton_steps = has_contacts ? settings_.contact_newton_steps : 1;
      for (int newton = 0; newton < newton_steps; ++newton) {
        Block block;
        const double* xp = x.data();
        const double* positions = position.data();
        for (std::int32_t s = spring_begin; s < spring_end; ++s) {
          const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
          addSpring(xp, positions + 3 * static_cast<std::ptrdiff_t>(spring.other), spring.stiffness,
                    neighbour_rest_length_[static_cast<std::size_t>(s)], block);
        }
        for (std::int32_t e = contact_begin; e < contact_end; ++e) {
          const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
          addContact(x, entry, contactStiffnessOf(p, entry), entry.same_colour ? 2.0 : 1.0, block);
        }
        addDrag(drag, drag_along, fibre_direction, x, carried, block);
        if (newton == 0) {
          // The residual counts the volume term's force too, as the muscle's volume stands now.
          const Eigen::Vector3d pressure = volume_k * volume_excess * volume_g;
          residual_squared_[p] = (Eigen::Vector3d(block.fx, block.fy, block.fz) - pressure).squaredNorm();
        }
        if (volume_inline) {
          const Eigen::Vector3d pressure = volume_k * volume_excess_at(x) * volume_g;
          block.fx -= pressure.x();
          block.fy -= pressure.y();
          block.fz -= pressure.z();
          block.addOuter(volume_k, volume_g.x(), volume_g.y(), volume_g.z());
        }
        block.addIsotropic(regularisation_[p]);
        if (volume_on) volume_inverse_gradient_.col(p) = block.solve(volume_g.x(), volume_g.y(), volume_g.z());
        Eigen::Vector3d step = block.step();
        // Where no contact touches at either end of the step the energy is smooth along it and the Newton step stands
        // (most particles near a contact: the margin lists pairs before they touch).
        const auto touching = [&](const Eigen::Vector3d& at) {
          for (std::int32_t e = contact_begin; e < contact_end; ++e) {
            const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
            if (entry.depth(at) > 0) return true;
          }
          return false;
        };
        if (has_contacts && (touching(x) || touching(x + step))) {
          // A contact switching on or off within the step makes the energy piecewise: Newton can overshoot and cycle
          // between the sides of a pinch, so the step is halved until the energy decreases.
          const double energy = local_energy(x);
          int halvings = 0;
          while (local_energy(x + step) > energy && halvings < 12) {
            step *= 0.5;
            ++halvings;
          }
          if (halvings == 12) break;
        } else {
          x += step;
          break;
        }
        x += step;
        if (step.squaredNorm() < 1e-24) break;
      }
      // Contacts are known only within the detection margin: a collidable particle that stepped further could cross a
      // sphere nobody listed (after a pose jump a first step can be centimetres). Its step is cut to the margin, as
      // Vertex Block Descent bounds its steps for the same reason, plus the depth it starts at inside a listed sphere,
      // so that a particle the warm start carried deep into a bone gets out in one sweep. The next sweep finds what
      // lies beyond.
      double start_depth = 0;
      if (contact_query_ && bounded_step_[p])
        for (std::int32_t e = contact_begin; e < contact_end; ++e) {
          const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
          start_depth = std::max(start_depth, entry.depth(start));
        }
      step_bound_[p] = contact_query_ && bounded_step_[p] ? contact_margin_m_ + start_depth : -1.0;
      if (volume_on && !volume_inline) {
        // The volume term's share of the step waits for the colour (below): every particle of the colour in the
        // muscle moves at once, each on the same volume.
        volume_step_.col(p) = x - start;
        volume_pending_[static_cast<std::size_t>(p)] = 1;
        continue;
      }
      limitStep(p, start, x);
      step_length_[p] = (x - start).norm();
      volume_change_[p] = volume_inline ? volume_g.dot(x - start) : 0.0;
      if (volume_inline) volume_direct_[static_cast<std::size_t>(p)] = 1;
      position.col(p) = x;
    }
    if (volume_.active()) applyVolumeSteps(position, visit_slot, begin, end, threads);
  }
  // Sums in particle order, so they do not depend on the thread count either (in locals: the references might alias
  // the arrays as far as the compiler knows).
  double residual_sum = 0, step_sum = 0;
  for (const std::int32_t p : free_particles_) {
    residual_sum += residual_squared_[p];
    step_sum += step_length_[p];
  }
  residual_squared_sum = residual_sum;
  displacement_sum = step_sum;
}

std::vector<double> BlockDescentSolver::dragShareOfVolumeTargets(const ParticleState& state) {
  const Eigen::Matrix3Xd& position = state.position;
  if (!volume_.active() || !dragsTissue() || state.carried_position.cols() != position.cols()) return {};
  Eigen::Matrix3Xd merged;
  frameDragAnchor(state, state.carried_position, merged);  // the fibres' directions the drag takes this frame
  evaluateVolume(position);
  const std::size_t muscles = volume_.stiffness.size();
  std::vector<double> projected(muscles, 0.0), gradient_squared(muscles, 0.0);
  for (const std::int32_t p : free_particles_) {
    if (volume_gradient_.cols() <= p) break;
    // The drag's own force: the merged quadratic W (m - x) less the same with the tissue carrying the particle where it
    // stands, W (I - tie_share (I - t t^T)) (c - x), with W = w' ((I - t t^T) + a' t t^T) (frameDragAnchor).
    const Eigen::Vector3d t = dragDirection(p);  // zero for an isotropic drag
    const Eigen::Vector3d pull = state.carried_position.col(p) - position.col(p);
    const double along = t.dot(pull);
    const Eigen::Vector3d across = pull - along * t;
    const Eigen::Vector3d force = drag_weight_[p] * ((1.0 - tie_share_) * across + drag_along_ * along * t);
    const std::size_t m = static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(p)]);
    const Eigen::Vector3d g = volume_gradient_.col(p);
    projected[m] += g.dot(force);
    gradient_squared[m] += g.squaredNorm();
  }
  std::vector<double> shift(muscles, 0.0);
  for (std::size_t m = 0; m < muscles; ++m)
    if (volume_.stiffness[m] > 0 && gradient_squared[m] > 0)
      shift[m] = projected[m] / (volume_.stiffness[m] * gradient_squared[m]);
  return shift;
}

double BlockDescentSolver::residualOf(const ParticleState& state) {
  gatherContacts(state);
  evaluateVolume(state.position);
  const Eigen::Matrix3Xd& position = state.position;
  const bool with_drag = state.carried_position.cols() == position.cols();
  Eigen::Matrix3Xd merged;
  const Eigen::Matrix3Xd& anchor = with_drag ? frameDragAnchor(state, state.carried_position, merged) : position;
  double sum = 0;
  for (std::size_t slot = 0; slot < coloured_particles_.size(); ++slot) {
    const std::int32_t p = coloured_particles_[slot];
    Block block;
    const double* xp = position.data() + 3 * static_cast<std::ptrdiff_t>(p);
    for (std::int32_t s = slot_spring_begin_[slot]; s < slot_spring_begin_[slot + 1]; ++s) {
      const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
      addSpring(xp, position.data() + 3 * static_cast<std::ptrdiff_t>(spring.other), spring.stiffness,
                neighbour_rest_length_[static_cast<std::size_t>(s)], block);
    }
    for (std::int32_t e = contact_begin_[static_cast<std::size_t>(p)]; e < contact_begin_[static_cast<std::size_t>(p) + 1]; ++e) {
      const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
      ContactEntry current = entry;
      if (entry.partner >= 0) current.centre = position.col(entry.partner);
      addContact(Eigen::Vector3d(position.col(p)), current, contactStiffnessOf(p, entry), 1.0, block);
    }
    if (with_drag)
      addDrag(drag_weight_[p], drag_along_, dragDirection(p), position.col(p), anchor.col(p), block);
    addVolumeForce(volume_, volume_now_, volume_gradient_, system_.muscle_of[static_cast<std::size_t>(p)], p, block);
    sum += block.forceSquared();
  }
  const double free_count = std::max<double>(1.0, static_cast<double>(coloured_particles_.size()));
  return std::sqrt(sum / free_count) / material_constant_n_;
}

// The counting is of the least a sweep must do, so the floor it gives is a lower bound and a sweep's time over it an
// upper bound of how far the sweep is from what the machine allows:
// - bytes: every array the sweep reads streamed once and every array it writes written once (a neighbour's position
//   read again from cache is not counted again): per free particle its position read and written, where the tissue
//   carries it, its drag weight, regularisation, contact stiffness, step bound, residual, step length and volume
//   change, its index in the visiting order and its offsets into the spring and contact lists; per packed spring its
//   entry (the other end, stiffness, rest length); per listed contact its entry; the fixed particles' positions once.
//   With the drag along the fibre its direction, with the volume term the gradient, per particle.
// - flops: one Newton step per particle (a particle with contacts may take up to contact_newton_steps and halve them):
//   46 per spring (addSpring: the difference 3, squared length 5, square root and inverse 2, pull 3, force 6,
//   transverse share 1, isotropic part 4, outer product 4 + 18), 42 per contact entry (its depth 13 at the start and
//   at the end of the step, the push 7, the outer product 22; counted once), 12 for the drag (46 along a fibre: the share
//   taken off along it 8, its force 6, its outer product 20), 45
//   for the 3 x 3 solve by cofactors, 5 for the residual and 9 for the step's length and update; the volume term's
//   share is not counted.
BlockDescentSolver::SweepCost BlockDescentSolver::sweepCost(const ParticleState& state) {
  gatherContacts(state);
  constexpr double kVector = 3 * sizeof(double);
  const double free_count = static_cast<double>(free_particles_.size());
  const double fixed_count = static_cast<double>(system_.particleCount()) - free_count;
  const double springs = static_cast<double>(neighbours_.size());
  const double contacts = static_cast<double>(contact_entries_.size());
  double per_particle_bytes = 3 * kVector + 7 * sizeof(double) + 4 * sizeof(std::int32_t);
  if (anisotropicDrag()) per_particle_bytes += kVector;
  if (volume_.active()) per_particle_bytes += kVector;
  SweepCost cost;
  cost.bytes = free_count * per_particle_bytes + springs * (sizeof(NeighbourSpring) + sizeof(double)) +
               contacts * sizeof(ContactEntry) + fixed_count * kVector;
  const double drag_flops = anisotropicDrag() ? 46 : 12;
  cost.flops = 46 * springs + 42 * contacts + free_count * (drag_flops + 45 + 5 + 9);
  return cost;
}

void BlockDescentSolver::beginFrame(const ParticleState& state, double margin_m) {
  entry_position_ = state.position;
  drag_anchor_ = &frameDragAnchor(
      state, state.carried_position.cols() == state.position.cols() ? state.carried_position : entry_position_,
      tied_anchor_);
  gatherContacts(state, margin_m);
}

namespace {
inline ContactEntry atPositions(const ContactEntry& entry, const Eigen::Matrix3Xd& position) {
  ContactEntry current = entry;
  if (entry.partner >= 0) current.centre = position.col(entry.partner);
  return current;
}
}  // namespace

double BlockDescentSolver::frameEnergy(const Eigen::Matrix3Xd& position) const {
  double energy = energyWithoutVolume(position);
  if (volume_.active()) {
    std::vector<double> volumes;
    Eigen::Matrix3Xd unused;
    volume_.evaluate(position, volumes, unused);
    energy += volumeEnergyOf(volumes);
  }
  return energy;
}

double BlockDescentSolver::energyWithoutVolume(const Eigen::Matrix3Xd& position) const {
  // Summed in fixed chunks of the visiting order, the chunks' sums then in order: the same bits on any number of
  // threads (a line search compares energies, and 1 and 2 threads must take the same steps).
  const std::size_t slots = coloured_particles_.size();
  const std::size_t chunk = (slots + kEnergyChunks - 1) / kEnergyChunks;
  std::array<double, kEnergyChunks> chunk_energy{};
#pragma omp parallel for num_threads(thread_count_) schedule(static)
  for (int c = 0; c < kEnergyChunks; ++c) {
    double energy = 0;
    const std::size_t end = std::min(slots, (static_cast<std::size_t>(c) + 1) * chunk);
    for (std::size_t slot = static_cast<std::size_t>(c) * chunk; slot < end; ++slot) {
      const std::int32_t p = coloured_particles_[slot];
      energy += springEnergyAtSlot(slot, position) + contactAndDragEnergy(p, position);
    }
    chunk_energy[static_cast<std::size_t>(c)] = energy;
  }
  double energy = 0;
  for (const double part : chunk_energy) energy += part;
  return energy;
}

double BlockDescentSolver::contactAndDragEnergy(std::int32_t p, const Eigen::Matrix3Xd& position) const {
  const Eigen::Vector3d x = position.col(p);
  double energy = 0;
  for (std::int32_t e = contact_begin_[static_cast<std::size_t>(p)]; e < contact_begin_[static_cast<std::size_t>(p) + 1]; ++e) {
    const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
    const double share = entry.partner >= 0 && !system_.is_fixed[static_cast<std::size_t>(entry.partner)] ? 0.5 : 1.0;
    energy += share * contactEnergy(x, atPositions(entry, position), contactStiffnessOf(p, entry));
  }
  return energy + dragEnergy(p, x, drag_anchor_->col(p));
}

double BlockDescentSolver::springEnergyAtSlot(std::size_t slot, const Eigen::Matrix3Xd& position) const {
  const std::int32_t p = coloured_particles_[slot];
  double energy = 0;
  for (std::int32_t s = slot_spring_begin_[slot]; s < slot_spring_begin_[slot + 1]; ++s) {
    const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
    // A spring between two free particles is listed at both ends.
    const double share = system_.is_fixed[static_cast<std::size_t>(spring.other)] ? 1.0 : 0.5;
    energy += share * springEnergy(position.col(p), position.col(spring.other), spring.stiffness,
                                   neighbour_rest_length_[static_cast<std::size_t>(s)]);
  }
  return energy;
}

void BlockDescentSolver::buildFibreModes() {
  const Eigen::Index n = system_.particleCount();
  fibre_parameter_.setZero(n);
  slot_of_.assign(static_cast<std::size_t>(n), -1);
  for (std::size_t slot = 0; slot < coloured_particles_.size(); ++slot)
    slot_of_[static_cast<std::size_t>(coloured_particles_[slot])] = static_cast<std::int32_t>(slot);
  if (system_.fibre_of.size() != static_cast<std::size_t>(n) || system_.sample_of.size() != static_cast<std::size_t>(n))
    return;
  // The last sample of each (muscle, fibre): a particle's parameter is its sample over it.
  std::map<std::pair<std::int32_t, std::int32_t>, std::int32_t> last_sample;
  for (Eigen::Index i = 0; i < n; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    if (system_.fibre_of[k] == kTendonAnchor) continue;
    std::int32_t& last = last_sample[{system_.muscle_of[k], system_.fibre_of[k]}];
    last = std::max(last, system_.sample_of[k]);
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    if (system_.fibre_of[k] == kTendonAnchor) continue;
    const std::int32_t last = last_sample[{system_.muscle_of[k], system_.fibre_of[k]}];
    fibre_parameter_[i] = last > 0 ? static_cast<double>(system_.sample_of[k]) / last : 0.5;
  }
}

bool BlockDescentSolver::fibreModeStep(Eigen::Matrix3Xd& position) {
  const int modes = settings_.fibre_modes;
  const int muscles = system_.muscleCount();
  const Eigen::Matrix3Xd along = fibreDirections(system_, position);
  if (along.cols() != position.cols()) return false;
  // Hat functions of the position u along the fibre, knots spread evenly over [0, 1]: at most two are non-zero, the
  // knot below u (weight 1 - fraction) and the one above (fraction).
  struct Hat {
    int below;
    double weight[2];
  };
  const auto hat = [modes](double u) {
    const double scaled = std::clamp(u, 0.0, 1.0) * (modes - 1);
    const int below = std::min(static_cast<int>(scaled), modes - 2);
    const double fraction = scaled - below;
    return Hat{below, {1.0 - fraction, fraction}};
  };
  const auto quadratic = [](const Block& b, const Eigen::Vector3d& u, const Eigen::Vector3d& v) {
    return u.x() * (b.hxx * v.x() + b.hxy * v.y() + b.hxz * v.z()) +
           u.y() * (b.hxy * v.x() + b.hyy * v.y() + b.hyz * v.z()) +
           u.z() * (b.hxz * v.x() + b.hyz * v.y() + b.hzz * v.z());
  };
  // Per muscle: the subspace Hessian (modes x modes, row-major), the force and the volume gradient along the modes,
  // accumulated per fixed chunk of the free particles (in parallel) and the chunks then summed in order, so that any
  // number of threads gives the same bits.
  const std::size_t per_muscle = static_cast<std::size_t>(modes * modes + 2 * modes);
  const std::size_t frees = free_particles_.size();
  const std::size_t chunk = (frees + kEnergyChunks - 1) / kEnergyChunks;
  fibre_accumulator_.assign(static_cast<std::size_t>(kEnergyChunks) * static_cast<std::size_t>(muscles) * per_muscle, 0.0);
  const bool with_volume = volume_.active() && volume_gradient_.cols() == position.cols();
#pragma omp parallel for num_threads(thread_count_) schedule(dynamic, 1)
  for (int c = 0; c < kEnergyChunks; ++c) {
    double* chunk_sums = fibre_accumulator_.data() + static_cast<std::size_t>(c) * static_cast<std::size_t>(muscles) * per_muscle;
    const std::size_t end = std::min(frees, (static_cast<std::size_t>(c) + 1) * chunk);
    double energy = 0;  // the frame energy without the volume term, at the step's start
    for (std::size_t f = static_cast<std::size_t>(c) * chunk; f < end; ++f) {
      const std::int32_t p = free_particles_[f];
      const std::size_t pk = static_cast<std::size_t>(p);
      const Eigen::Vector3d t = along.col(p);
      energy += contactAndDragEnergy(p, position);
      if (t.squaredNorm() == 0) {
        energy += springEnergyAtSlot(static_cast<std::size_t>(slot_of_[pk]), position);
        continue;
      }
      const std::size_t m = static_cast<std::size_t>(system_.muscle_of[pk]);
      double* hessian = chunk_sums + m * per_muscle;
      double* force = hessian + modes * modes;
      double* volume_along = force + modes;
      const Hat phi = hat(fibre_parameter_[p]);
      // H += value x (phi_a phi_b^T + phi_b phi_a^T) over the two hats' non-zeros (a cross term of two particles).
      const auto addOuter = [&](const Hat& a, const Hat& b, double value) {
        for (int i = 0; i < 2; ++i)
          for (int j = 0; j < 2; ++j) {
            const double v = value * a.weight[i] * b.weight[j];
            hessian[(a.below + i) * modes + b.below + j] += v;
            hessian[(b.below + j) * modes + a.below + i] += v;
          }
      };
      const std::int32_t slot = slot_of_[pk];
      const double* xp = position.data() + 3 * static_cast<std::ptrdiff_t>(p);
      Block total;      // the forces of the terms other than springs
      double f_along = 0;  // the springs' force along p's fibre
      double own = 0;      // the p-p blocks of p's energy terms, seen along p's fibre
      const auto addOwn = [&](const Block& term) {
        total.fx += term.fx;
        total.fy += term.fy;
        total.fz += term.fz;
        own += quadratic(term, t, t);
      };
      for (std::int32_t s = slot_spring_begin_[static_cast<std::size_t>(slot)]; s < slot_spring_begin_[static_cast<std::size_t>(slot) + 1]; ++s) {
        const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
        const double rest_length = neighbour_rest_length_[static_cast<std::size_t>(s)];
        const double* xo = position.data() + 3 * static_cast<std::ptrdiff_t>(spring.other);
        const Eigen::Vector3d d(xp[0] - xo[0], xp[1] - xo[1], xp[2] - xo[2]);
        const double length_squared = d.squaredNorm();
        const std::size_t ok = static_cast<std::size_t>(spring.other);
        // The spring's energy (listed at both ends between two free particles), and its force and projected Hessian
        // (addSpring: k t I + k (1 - t) / l^2 d d^T, t = max(0, 1 - l0 / l)) seen along the fibres only.
        double isotropic = spring.stiffness, outer = 0;
        if (length_squared > 0.0) {
          const double inverse_length = 1.0 / std::sqrt(length_squared);
          const double stretch = 1.0 - rest_length * inverse_length;
          const double transverse = 0.5 * (stretch + std::abs(stretch));
          isotropic = spring.stiffness * transverse;
          outer = spring.stiffness * (1.0 - transverse) * inverse_length * inverse_length;
          const double pull = spring.stiffness * stretch;
          f_along -= pull * t.dot(d);
          const double extension = length_squared * inverse_length - rest_length;
          energy += (system_.is_fixed[ok] ? 0.5 : 0.25) * spring.stiffness * extension * extension;
        }
        const double t_d = t.dot(d);
        own += isotropic + outer * t_d * t_d;
        // The cross term once per free pair (from its lower-numbered end), the other's own term from its own visit.
        if (system_.is_fixed[ok] || spring.other < p || system_.muscle_of[ok] != system_.muscle_of[pk]) continue;
        const Eigen::Vector3d t_other = along.col(spring.other);
        if (t_other.squaredNorm() == 0) continue;
        const Hat phi_other = hat(fibre_parameter_[spring.other]);
        addOuter(phi, phi_other, -(isotropic * t.dot(t_other) + outer * t_d * t_other.dot(d)));
      }
      const Eigen::Vector3d x = position.col(p);
      for (std::int32_t e = contact_begin_[pk]; e < contact_begin_[pk + 1]; ++e) {
        const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
        Block block;
        addContact(x, atPositions(entry, position),
                   contactStiffnessOf(p, entry), 1.0, block);
        addOwn(block);  // the partner held (a stiffer, safe model)
      }
      Block drag;
      addDrag(drag_weight_[p], drag_along_, dragDirection(p), x, drag_anchor_->col(p), drag);
      drag.addIsotropic(regularisation_[p]);
      addOwn(drag);
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) hessian[(phi.below + i) * modes + phi.below + j] += own * phi.weight[i] * phi.weight[j];
      if (with_volume && volume_.stiffness[m] > 0) {
        const double g_along = volume_gradient_.col(p).dot(t);
        for (int i = 0; i < 2; ++i) volume_along[phi.below + i] += g_along * phi.weight[i];
        const double pressure = volume_.stiffness[m] * (volume_now_[m] - volume_.target(m));
        total.fx -= pressure * volume_gradient_(0, p);
        total.fy -= pressure * volume_gradient_(1, p);
        total.fz -= pressure * volume_gradient_(2, p);
      }
      f_along += t.x() * total.fx + t.y() * total.fy + t.z() * total.fz;
      for (int i = 0; i < 2; ++i) force[phi.below + i] += f_along * phi.weight[i];
    }
    fibre_start_energy_[static_cast<std::size_t>(c)] = energy;
  }
  std::vector<Eigen::MatrixXd> hessian(static_cast<std::size_t>(muscles), Eigen::MatrixXd::Zero(modes, modes));
  std::vector<Eigen::VectorXd> force(static_cast<std::size_t>(muscles), Eigen::VectorXd::Zero(modes));
  std::vector<Eigen::VectorXd> volume_along(static_cast<std::size_t>(muscles), Eigen::VectorXd::Zero(modes));
  for (int c = 0; c < kEnergyChunks; ++c)
    for (std::size_t m = 0; m < static_cast<std::size_t>(muscles); ++m) {
      const double* sums = fibre_accumulator_.data() + (static_cast<std::size_t>(c) * static_cast<std::size_t>(muscles) + m) * per_muscle;
      hessian[m] += Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(sums, modes, modes);
      force[m] += Eigen::Map<const Eigen::VectorXd>(sums + modes * modes, modes);
      volume_along[m] += Eigen::Map<const Eigen::VectorXd>(sums + modes * modes + modes, modes);
    }
  Eigen::VectorXd phi(modes);
  const auto hats = [&](double u, Eigen::VectorXd& out) {
    const Hat h = hat(u);
    out.setZero(modes);
    out[h.below] = h.weight[0];
    out[h.below + 1] = h.weight[1];
  };
  std::vector<Eigen::VectorXd> amplitude(static_cast<std::size_t>(muscles));
  bool any = false;
  for (std::size_t m = 0; m < static_cast<std::size_t>(muscles); ++m) {
    Eigen::MatrixXd h = hessian[m];
    if (volume_.active() && m < volume_.stiffness.size()) h += volume_.stiffness[m] * volume_along[m] * volume_along[m].transpose();
    if (h.trace() <= 0) continue;
    h.diagonal().array() += 1e-12 * h.trace();
    Eigen::LDLT<Eigen::MatrixXd> factor(h);
    if (factor.info() != Eigen::Success) continue;
    amplitude[m] = factor.solve(force[m]);
    any = any || amplitude[m].allFinite();
  }
  if (!any) return false;
  fibre_step_.setZero(3, position.cols());
  double longest = 0;
  std::vector<double> volume_change(static_cast<std::size_t>(muscles), 0.0);
  for (const std::int32_t p : free_particles_) {
    const std::size_t m = static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(p)]);
    if (amplitude[m].size() != modes || !amplitude[m].allFinite()) continue;
    const Eigen::Vector3d t = along.col(p);
    if (t.squaredNorm() == 0) continue;
    hats(fibre_parameter_[p], phi);
    fibre_step_.col(p) = phi.dot(amplitude[m]) * t;
    longest = std::max(longest, fibre_step_.col(p).norm());
    if (volume_.active() && volume_gradient_.cols() == position.cols())
      volume_change[m] += volume_gradient_.col(p).dot(fibre_step_.col(p));
  }
  if (!(longest > 0)) return false;
  // No particle further than the contact margin in one step: the contacts listed for the sweep still hold every
  // sphere it can reach.
  double scale = contact_query_ && contact_margin_m_ > 0 ? std::min(1.0, contact_margin_m_ / longest) : 1.0;
  const auto volumeEnergyAfter = [&](double s) {
    std::vector<double> volumes = volume_now_;
    for (std::size_t m = 0; m < volumes.size(); ++m) volumes[m] += s * volume_change[m];
    return volumeEnergyOf(volumes);
  };
  double start_energy = volumeEnergyAfter(0);
  for (const double part : fibre_start_energy_) start_energy += part;
  for (int halving = 0; halving < 4; ++halving, scale *= 0.5) {
    fibre_trial_ = position + scale * fibre_step_;
    if (energyWithoutVolume(fibre_trial_) + volumeEnergyAfter(scale) < start_energy) {
      position.swap(fibre_trial_);
      // The volume term after the step, to first order (V is linear in each particle; the sweep evaluates it again).
      if (volume_.active())
        for (std::size_t m = 0; m < volume_now_.size(); ++m) volume_now_[m] += scale * volume_change[m];
      return true;
    }
  }
  return false;
}

void BlockDescentSolver::frameForces(const Eigen::Matrix3Xd& position, Eigen::Matrix3Xd& force,
                                     std::vector<Eigen::Matrix3d>& inverse_blocks) {
  force.setZero(3, position.cols());
  inverse_blocks.resize(static_cast<std::size_t>(position.cols()));
  evaluateVolume(position);
#pragma omp parallel for num_threads(thread_count_) schedule(static)
  for (std::int32_t slot = 0; slot < static_cast<std::int32_t>(coloured_particles_.size()); ++slot) {
    const std::int32_t p = coloured_particles_[static_cast<std::size_t>(slot)];
    const double* xp = position.data() + 3 * static_cast<std::ptrdiff_t>(p);
    Block block;
    for (std::int32_t s = slot_spring_begin_[static_cast<std::size_t>(slot)]; s < slot_spring_begin_[static_cast<std::size_t>(slot) + 1]; ++s) {
      const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
      addSpring(xp, position.data() + 3 * static_cast<std::ptrdiff_t>(spring.other), spring.stiffness,
                neighbour_rest_length_[static_cast<std::size_t>(s)], block);
    }
    const Eigen::Vector3d x = position.col(p);
    for (std::int32_t e = contact_begin_[static_cast<std::size_t>(p)]; e < contact_begin_[static_cast<std::size_t>(p) + 1]; ++e) {
      const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
      addContact(x, atPositions(entry, position),
                 contactStiffnessOf(p, entry), 1.0, block);
    }
    addDrag(drag_weight_[p], drag_along_, dragDirection(p), x, drag_anchor_->col(p), block);
    block.addIsotropic(regularisation_[p]);
    addVolumeForce(volume_, volume_now_, volume_gradient_, system_.muscle_of[static_cast<std::size_t>(p)], p, block);
    force.col(p) = Eigen::Vector3d(block.fx, block.fy, block.fz);
    Eigen::Matrix3d hessian;
    hessian << block.hxx, block.hxy, block.hxz, block.hxy, block.hyy, block.hyz, block.hxz, block.hyz, block.hzz;
    inverse_blocks[static_cast<std::size_t>(p)] = hessian.inverse();
  }
}

void BlockDescentSolver::frameHessianTimes(const Eigen::Matrix3Xd& position, const Eigen::Matrix3Xd& direction,
                                           Eigen::Matrix3Xd& product) {
  product.setZero(3, position.cols());
  // The volume term couples every particle of a muscle: k (g . v) g from the square of its change, and
  // k (V - V_rest) times V's own curvature along v. Fixed particles do not move: their directions are left out.
  Eigen::Matrix3Xd volume_product;
  if (volume_.active()) {
    evaluateVolume(position);
    Eigen::Matrix3Xd free_direction = direction;
    for (Eigen::Index i = 0; i < free_direction.cols(); ++i)
      if (system_.is_fixed[static_cast<std::size_t>(i)]) free_direction.col(i).setZero();
    std::vector<double> along(volume_now_.size(), 0.0), weight(volume_now_.size(), 0.0);
    for (Eigen::Index i = 0; i < free_direction.cols(); ++i)
      along[static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(i)])] +=
          volume_gradient_.col(i).dot(free_direction.col(i));
    for (std::size_t m = 0; m < weight.size(); ++m)
      weight[m] = volume_.stiffness[m] * (volume_now_[m] - volume_.target(m));
    volume_.curvature_times(position, free_direction, weight, volume_product);
    for (Eigen::Index i = 0; i < free_direction.cols(); ++i) {
      const std::size_t m = static_cast<std::size_t>(system_.muscle_of[static_cast<std::size_t>(i)]);
      volume_product.col(i) += volume_.stiffness[m] * along[m] * volume_gradient_.col(i);
    }
  }
#pragma omp parallel for num_threads(thread_count_) schedule(static)
  for (std::int32_t slot = 0; slot < static_cast<std::int32_t>(coloured_particles_.size()); ++slot) {
    const std::int32_t p = coloured_particles_[static_cast<std::size_t>(slot)];
    const double* xp = position.data() + 3 * static_cast<std::ptrdiff_t>(p);
    const Eigen::Vector3d vp = direction.col(p);
    Eigen::Vector3d sum = (drag_weight_[p] + regularisation_[p]) * vp;
    if (anisotropicDrag()) {
      const Eigen::Vector3d t = drag_direction_.col(p);
      sum -= drag_weight_[p] * (1.0 - drag_along_) * t.dot(vp) * t;
    }
    const auto apply = [&](const Block& b, const Eigen::Vector3d& relative) {
      sum.x() += b.hxx * relative.x() + b.hxy * relative.y() + b.hxz * relative.z();
      sum.y() += b.hxy * relative.x() + b.hyy * relative.y() + b.hyz * relative.z();
      sum.z() += b.hxz * relative.x() + b.hyz * relative.y() + b.hzz * relative.z();
    };
    for (std::int32_t s = slot_spring_begin_[static_cast<std::size_t>(slot)]; s < slot_spring_begin_[static_cast<std::size_t>(slot) + 1]; ++s) {
      const NeighbourSpring& spring = neighbours_[static_cast<std::size_t>(s)];
      Block block;
      addSpring(xp, position.data() + 3 * static_cast<std::ptrdiff_t>(spring.other), spring.stiffness,
                neighbour_rest_length_[static_cast<std::size_t>(s)], block);
      const bool other_free = !system_.is_fixed[static_cast<std::size_t>(spring.other)];
      apply(block, other_free ? Eigen::Vector3d(vp - direction.col(spring.other)) : vp);
    }
    const Eigen::Vector3d x = position.col(p);
    for (std::int32_t e = contact_begin_[static_cast<std::size_t>(p)]; e < contact_begin_[static_cast<std::size_t>(p) + 1]; ++e) {
      const ContactEntry& entry = contact_entries_[static_cast<std::size_t>(e)];
      Block block;
      addContact(x, atPositions(entry, position),
                 contactStiffnessOf(p, entry), 1.0, block);
      const bool partner_free = entry.partner >= 0 && !system_.is_fixed[static_cast<std::size_t>(entry.partner)];
      apply(block, partner_free ? Eigen::Vector3d(vp - direction.col(entry.partner)) : vp);
    }
    if (volume_product.cols() > 0) sum += volume_product.col(p);
    product.col(p) = sum;
  }
}

SolveStats BlockDescentSolver::solve(ParticleState& state, const StoppingSettings& stopping,
                                     const AfterUpdateHook& after_update) {
  const auto solve_start = Clock::now();
  if (const std::string problem = validate(stopping); !problem.empty())
    throw std::invalid_argument("stopping settings: " + problem);
  SolveStats stats;
  const Eigen::Index n = system_.particleCount();
  if (state.position.cols() != n)
    throw std::invalid_argument("BlockDescentSolver: state has " + std::to_string(state.position.cols()) +
                                " particles, the system " + std::to_string(n));
  entry_position_ = state.position;
  drag_anchor_ = &frameDragAnchor(state, state.carried_position.cols() == n ? state.carried_position : entry_position_,
                                  tied_anchor_);
  const double free_count = std::max<double>(1.0, static_cast<double>(free_particles_.size()));
  const bool chebyshev = settings_.chebyshev_rho > 0;
  const double rho_squared = settings_.chebyshev_rho * settings_.chebyshev_rho;
  double omega = 1.0;
  StoppingMonitor monitor(stopping.rule, stopping.displacement_tolerance_m, stopping.time_budget_ms);
  last_residual_ = 0;

  double previous_elapsed_ms = 0;
  for (int iteration = 0; iteration < stopping.max_iterations; ++iteration) {
    auto phase_start = Clock::now();
    if (iteration > 0) previous_elapsed_ms = millisecondsSince(solve_start);
    gatherContacts(state);
    stats.contacts = static_cast<int>(contacts_.size());
    stats.collision_ms += millisecondsSince(phase_start);
    evaluateVolume(state.position);  // counted with the sweep: it is part of the energy the sweep descends
    if (settings_.fibre_modes > 0 && drag_anchor_ != nullptr && fibreModeStep(state.position)) ++stats.fibre_steps;

    phase_start = Clock::now();
    if (chebyshev && iteration == 0) {
      chebyshev_previous_ = state.position;
      chebyshev_older_ = state.position;
    }
    double residual_squared_sum = 0, displacement_sum = 0;
    const int threads = sweepThreads(stopping.limits);
    const auto sweep_start = Clock::now();
    sweep(state.position, residual_squared_sum, displacement_sum, threads);
    recordSweepTime(threads, millisecondsSince(sweep_start));
    if (chebyshev) {
      // Wang 2015: x_{k+1} = omega (x_sweep - x_{k-1}) + x_{k-1}, omega growing towards 2 / (1 + sqrt(1 - rho^2)).
      if (iteration < settings_.chebyshev_delay) omega = 1.0;
      else if (iteration == settings_.chebyshev_delay) omega = 2.0 / (2.0 - rho_squared);
      else omega = 4.0 / (4.0 - rho_squared * omega);
      if (omega != 1.0)
        for (const std::int32_t p : free_particles_)
          state.position.col(p) = omega * (state.position.col(p) - chebyshev_older_.col(p)) + chebyshev_older_.col(p);
      chebyshev_older_.swap(chebyshev_previous_);
      chebyshev_previous_ = state.position;
    }
    state.previous_position = state.position;  // quasi-static: no velocity
    stats.mss_ms += millisecondsSince(phase_start);
    runAfterUpdateHook(after_update, state, stats);

    stats.iterations = iteration + 1;
    last_residual_ = std::sqrt(residual_squared_sum / free_count) / material_constant_n_;
    stats.mean_displacement_m = displacement_sum / free_count;
    stats.peak_mean_displacement_m = std::max(stats.peak_mean_displacement_m, stats.mean_displacement_m);
    if (!std::isfinite(last_residual_) || !std::isfinite(stats.mean_displacement_m)) {
      stats.diverged = true;
      break;
    }
    const double elapsed_ms = millisecondsSince(solve_start);
    if (stopping.rule == StoppingRule::force_residual) {
      if (last_residual_ < stopping.residual_tolerance) {
        stats.stopping_rule_met = true;
        break;
      }
    } else if (stopping.rule == StoppingRule::time_budget) {
      // A budget is a deadline: stop when another sweep as long as the last would end past it (at least one sweep).
      const double sweep_ms = elapsed_ms - previous_elapsed_ms;
      if (elapsed_ms + sweep_ms > stopping.time_budget_ms) {
        stats.stopping_rule_met = true;
        break;
      }
    } else if (monitor.met(iteration, stats.mean_displacement_m, elapsed_ms)) {
      stats.stopping_rule_met = true;
      break;
    }
    if (solveLimitReached(stopping.limits, elapsed_ms, stats)) break;
  }
  if (!stats.diverged && contact_query_ && stats.iterations > 0 && !stats.cancelled) {
    // Closing contact pass: only the particles touching a listed contact are visited, so that what the last sweep's
    // other moves pushed into a sphere is pushed out (a fraction of a sweep's cost; its residual is not the frame's,
    // which stays the last full sweep's). The sweep's list holds nearly every sphere a particle can touch now: no step
    // was longer than the detection margin beyond the depth it started at. A particle that started deep may move
    // further (on the bundled gait about 14 of 36,443 a frame moved more than the margin since the search, and in 8 of
    // 146 frames one to two muscle pairs overlapped unlisted, up to 0.9 mm): the next frame's search meets those, and
    // CollisionWorld::measureListed counts them in this frame's figures.
    const auto pass_start = Clock::now();
    double ignored_residual = 0, ignored_displacement = 0;
    listContactSlots();
    sweep(state.position, ignored_residual, ignored_displacement, sweepThreads(stopping.limits), true);
    state.previous_position = state.position;
    stats.collision_ms += millisecondsSince(pass_start);
  }
  drag_anchor_ = nullptr;
  if (!stats.diverged && !state.position.allFinite()) stats.diverged = true;
  if (stats.diverged) {
    state.position = entry_position_;
    state.previous_position = entry_position_;
  }
  stats.residual = last_residual_;
  // Converged means the residual criterion, however the solve ended: a fixed number of sweeps or a time budget that
  // left the frame within the tolerance has converged as much as one the residual rule stopped.
  stats.converged = !stats.diverged && stats.iterations > 0 && last_residual_ < stopping.residual_tolerance;
  if (stopping.rule == StoppingRule::iterations && !stats.diverged && !stats.time_limit_reached && !stats.cancelled)
    stats.stopping_rule_met = true;
  stats.total_ms = millisecondsSince(solve_start);
  recordSpringMetrics(system_.springs, state.position, stats, sweepThreads(stopping.limits));
  return stats;
}

}  // namespace muscle_deformation
