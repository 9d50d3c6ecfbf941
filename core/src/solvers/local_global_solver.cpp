#include "muscle_deformation/core/solvers/local_global_solver.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include "muscle_deformation/core/model/spring_layout.hpp"

#include <Eigen/Geometry>
#include <Eigen/LU>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace muscle_deformation {

namespace {
using Clock = std::chrono::steady_clock;

// Edge vectors of a tetrahedron as columns: [x1 - x0, x2 - x0, x3 - x0].
Eigen::Matrix3d edgeMatrix(const Eigen::Matrix3Xd& position, const Eigen::Vector4i& tet) {
  Eigen::Matrix3d edges;
  for (int j = 0; j < 3; ++j) edges.col(j) = position.col(tet[j + 1]) - position.col(tet[0]);
  return edges;
}

// Gradient of the determinant: the cofactor matrix, columns t1 x t2, t2 x t0, t0 x t1.
Eigen::Matrix3d cofactor(const Eigen::Matrix3d& t) {
  Eigen::Matrix3d c;
  c.col(0) = t.col(1).cross(t.col(2));
  c.col(1) = t.col(2).cross(t.col(0));
  c.col(2) = t.col(0).cross(t.col(1));
  return c;
}

// Nearest matrix T to F (Frobenius) with det T = target: Newton steps on the linearised constraint, each the exact
// projection of F onto the tangent plane of det T = target at the current estimate. The iterates keep F's singular
// vectors, so this is the Projective Dynamics volume projection (on the singular values) without an SVD; an inverted
// F (det < 0) is pushed back through zero volume along the same path.
Eigen::Matrix3d projectDeterminant(const Eigen::Matrix3d& f, double target) {
  Eigen::Matrix3d projected = f;
  for (int step = 0; step < 8; ++step) {
    const double c = projected.determinant() - target;
    if (std::abs(c) < 1e-10 * target) break;
    const Eigen::Matrix3d gradient = cofactor(projected);
    const double gradient_squared = gradient.squaredNorm();
    if (gradient_squared < 1e-24) break;  // rank <= 1: no direction to grow the volume along
    const double lambda = (c + (gradient.array() * (f - projected).array()).sum()) / gradient_squared;
    projected = f - lambda * gradient;
  }
  return projected;
}
}  // namespace

std::string validate(const LocalGlobalSettings& s) {
  if (!(s.time_step_s > 0) || !std::isfinite(s.time_step_s)) return "time_step_s must be positive and finite";
  if (s.iterations_per_step < 1) return "iterations_per_step must be >= 1";
  if (!(s.damping >= 0 && s.damping <= 1)) return "damping must be in [0, 1]";
  if (!(s.quasi_static_regularisation > 0) || !std::isfinite(s.quasi_static_regularisation))
    return "quasi_static_regularisation must be positive and finite";
  if (!(s.contact_weight >= 0) || !std::isfinite(s.contact_weight)) return "contact_weight must be >= 0 and finite";
  if (!(s.volume_weight >= 0) || !std::isfinite(s.volume_weight)) return "volume_weight must be >= 0 and finite";
  if (!(s.volume_tolerance >= 0 && s.volume_tolerance < 1)) return "volume_tolerance must be in [0, 1)";
  if (!(s.min_tetrahedron_quality >= 0 && s.min_tetrahedron_quality < 1))
    return "min_tetrahedron_quality must be in [0, 1)";
  if (!(s.max_edge_over_spring > 0)) return "max_edge_over_spring must be positive";
  if (!(s.chebyshev_rho >= 0 && s.chebyshev_rho < 1)) return "chebyshev_rho must be in [0, 1)";
  if (s.chebyshev_delay < 1) return "chebyshev_delay must be >= 1";
  if (s.lbfgs_history < 0) return "lbfgs_history must be >= 0";
  if (s.lbfgs_history > 0 && !s.quasi_static) return "lbfgs_history needs the quasi-static mode";
  if (s.lbfgs_history > 0 && s.chebyshev_rho > 0) return "lbfgs_history and chebyshev_rho exclude each other";
  return {};
}

MuscleTetrahedra buildMuscleTetrahedra(const MassSpringSystem& system, double min_quality,
                                       double max_edge_over_spring) {
  MuscleTetrahedra result;
  result.muscle_count = system.muscleCount();
  std::vector<double> rest_volumes;
  // Median spring rest length per muscle: the scale of a tetrahedron that lies inside the muscle's particle cloud.
  std::vector<std::vector<double>> rest_lengths(static_cast<std::size_t>(system.muscleCount()));
  for (std::size_t s = 0; s < system.springs.size(); ++s)
    rest_lengths[static_cast<std::size_t>(system.muscle_of[system.springs.first[s]])].push_back(
        system.springs.rest_length[static_cast<Eigen::Index>(s)]);

  for (int m = 0; m < system.muscleCount(); ++m) {
    const std::int32_t begin = system.muscle_begin[m], end = system.muscle_begin[m + 1];
    if (end - begin < 5) continue;
    std::vector<double>& lengths = rest_lengths[static_cast<std::size_t>(m)];
    double max_edge = std::numeric_limits<double>::infinity();
    if (!lengths.empty()) {
      std::nth_element(lengths.begin(), lengths.begin() + lengths.size() / 2, lengths.end());
      max_edge = max_edge_over_spring * lengths[lengths.size() / 2];
    }
    const Eigen::Matrix3Xd points = system.rest_position.middleCols(begin, end - begin);
    std::vector<Eigen::Vector4i> local;
    try {
      local = delaunayTetrahedra(points);
    } catch (const std::runtime_error&) {
      continue;  // flat or degenerate point set: no volume to keep
    }
    for (Eigen::Vector4i tet : local) {
      tet.array() += begin;
      Eigen::Matrix3d edges = edgeMatrix(system.rest_position, tet);
      double volume = edges.determinant() / 6.0;
      if (volume < 0) {  // orient positively so that det F = 1 at rest
        std::swap(tet[1], tet[2]);
        volume = -volume;
      }
      double edge_squared_sum = 0, longest = 0;
      for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j) {
          const double length = (system.rest_position.col(tet[i]) - system.rest_position.col(tet[j])).norm();
          edge_squared_sum += length * length;
          longest = std::max(longest, length);
        }
      const double rms_edge = std::sqrt(edge_squared_sum / 6.0);
      const double quality = rms_edge > 0 ? 6.0 * std::sqrt(2.0) * volume / (rms_edge * rms_edge * rms_edge) : 0.0;
      if (quality < min_quality || longest > max_edge || !(volume > 0)) continue;
      result.tetrahedra.push_back(tet);
      result.muscle_of.push_back(m);
      rest_volumes.push_back(volume);
    }
  }
  result.rest_volume = Eigen::Map<const Eigen::VectorXd>(rest_volumes.data(), static_cast<Eigen::Index>(rest_volumes.size()));
  return result;
}

Eigen::VectorXd muscleVolumeChange(const MuscleTetrahedra& tetrahedra, const Eigen::Matrix3Xd& position) {
  Eigen::VectorXd rest = Eigen::VectorXd::Zero(tetrahedra.muscle_count);
  Eigen::VectorXd now = Eigen::VectorXd::Zero(tetrahedra.muscle_count);
  for (std::size_t t = 0; t < tetrahedra.tetrahedra.size(); ++t) {
    const int m = tetrahedra.muscle_of[t];
    rest[m] += tetrahedra.rest_volume[static_cast<Eigen::Index>(t)];
    now[m] += edgeMatrix(position, tetrahedra.tetrahedra[t]).determinant() / 6.0;
  }
  Eigen::VectorXd change = Eigen::VectorXd::Zero(tetrahedra.muscle_count);
  for (int m = 0; m < tetrahedra.muscle_count; ++m)
    if (rest[m] > 0) change[m] = (now[m] - rest[m]) / rest[m];
  return change;
}

LocalGlobalSolver::LocalGlobalSolver(const MassSpringSystem& system, LocalGlobalSettings settings)
    : system_(system), settings_(settings) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("local/global solver settings: " + problem);
  buildTerms();
  buildAndFactorise();
  const Eigen::Index n = system_.particleCount();
  fixed_position_.setZero(n, 3);
  entry_position_.setZero(3, n);
  entry_previous_position_.setZero(3, n);
  fixed_rhs_.setZero(free_count_, 3);
  rhs_.setZero(free_count_, 3);
  free_current_.setZero(free_count_, 3);
  free_previous_.setZero(free_count_, 3);
  free_next_.setZero(free_count_, 3);
  chebyshev_older_.setZero(free_count_, 3);
  inertial_target_.setZero(free_count_, 3);
  inertial_prediction_.setZero(free_count_, 3);
  if (settings_.lbfgs_history > 0) {
    for (Eigen::MatrixXd* buffer : {&gradient_, &previous_gradient_, &trial_gradient_, &direction_, &trial_})
      buffer->setZero(free_count_, 3);
    const auto history = static_cast<std::size_t>(settings_.lbfgs_history);
    history_step_.assign(history, Eigen::MatrixXd::Zero(free_count_, 3));
    history_gradient_change_.assign(history, Eigen::MatrixXd::Zero(free_count_, 3));
    history_inverse_curvature_.assign(history, 0.0);
    history_alpha_.assign(history, 0.0);
  }
}

Eigen::Index LocalGlobalSolver::factorNonZeros() const { return factor_.matrixL().nestedExpression().nonZeros(); }

void LocalGlobalSolver::buildTerms() {
  const Eigen::Index n = system_.particleCount();
  free_index_.assign(static_cast<std::size_t>(n), -1);
  free_particle_.clear();
  for (Eigen::Index i = 0; i < n; ++i)
    if (!system_.is_fixed[static_cast<std::size_t>(i)]) {
      free_index_[static_cast<std::size_t>(i)] = static_cast<std::int32_t>(free_particle_.size());
      free_particle_.push_back(static_cast<std::int32_t>(i));
    }
  free_count_ = static_cast<Eigen::Index>(free_particle_.size());

  // Springs between two fixed particles move rigidly with the pose or not at all: they have no free unknown.
  springs_.clear();
  spring_entry_.assign(system_.springs.size(), -1);
  for (std::size_t s = 0; s < system_.springs.size(); ++s) {
    const std::int32_t a = system_.springs.first[s], b = system_.springs.second[s];
    const std::int32_t fa = free_index_[static_cast<std::size_t>(a)], fb = free_index_[static_cast<std::size_t>(b)];
    if (fa < 0 && fb < 0) continue;
    const auto e = static_cast<Eigen::Index>(s);
    spring_entry_[s] = static_cast<std::int32_t>(springs_.size());
    springs_.push_back({a, b, fa, fb, system_.springs.stiffness[e], system_.springs.rest_length[e]});
  }

  volume_terms_.clear();
  volume_stiffness_ = Eigen::VectorXd::Zero(system_.muscleCount());
  if (settings_.volume_weight <= 0) return;
  tetrahedra_ = buildMuscleTetrahedra(system_, settings_.min_tetrahedron_quality, settings_.max_edge_over_spring);
  // The springs' effective modulus per muscle, sum k l0^2 / V: the energy density (times 2) of a uniform unit
  // strain. Scaling the volume weight by it makes volume_weight a dimensionless ratio valid for any resolution.
  Eigen::VectorXd spring_energy = Eigen::VectorXd::Zero(system_.muscleCount());
  Eigen::VectorXd muscle_volume = Eigen::VectorXd::Zero(system_.muscleCount());
  for (std::size_t s = 0; s < system_.springs.size(); ++s) {
    const auto e = static_cast<Eigen::Index>(s);
    const double rest = system_.springs.rest_length[e];
    spring_energy[system_.muscle_of[system_.springs.first[s]]] += system_.springs.stiffness[e] * rest * rest;
  }
  for (std::size_t t = 0; t < tetrahedra_.tetrahedra.size(); ++t)
    muscle_volume[tetrahedra_.muscle_of[t]] += tetrahedra_.rest_volume[static_cast<Eigen::Index>(t)];
  for (int m = 0; m < system_.muscleCount(); ++m)
    if (muscle_volume[m] > 0) volume_stiffness_[m] = settings_.volume_weight * spring_energy[m] / muscle_volume[m];

  for (std::size_t t = 0; t < tetrahedra_.tetrahedra.size(); ++t) {
    const Eigen::Vector4i& tet = tetrahedra_.tetrahedra[t];
    VolumeTerm term{};
    bool any_free = false;
    for (int j = 0; j < 4; ++j) {
      term.vertex[j] = tet[j];
      term.free[j] = free_index_[static_cast<std::size_t>(tet[j])];
      any_free = any_free || term.free[j] >= 0;
    }
    if (!any_free) continue;
    term.rest_inverse = edgeMatrix(system_.rest_position, tet).inverse();
    term.weight = volume_stiffness_[tetrahedra_.muscle_of[t]] * tetrahedra_.rest_volume[static_cast<Eigen::Index>(t)];
    volume_terms_.push_back(term);
  }
}

namespace {
// Gradient operator of a tetrahedron: F = sum_j x_j g_j^T with g_j the columns of the result (g_0 = -g_1 - g_2 - g_3,
// g_1..3 the rows of Dm^-1).
Eigen::Matrix<double, 3, 4> gradientOperator(const Eigen::Matrix3d& rest_inverse) {
  Eigen::Matrix<double, 3, 4> g;
  g.rightCols<3>() = rest_inverse.transpose();
  g.col(0) = -g.rightCols<3>().rowwise().sum();
  return g;
}
}  // namespace

void LocalGlobalSolver::buildAndFactorise() {
  const auto start = Clock::now();
  const Eigen::Index n = system_.particleCount();
  // W + L over all particles, one scalar per particle pair: the three coordinates share it (the energy is isotropic),
  // so three right-hand sides share one factorisation of an n x n matrix instead of a 3n x 3n one.
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(4 * springs_.size() + 16 * volume_terms_.size() + static_cast<std::size_t>(n));
  Eigen::VectorXd diagonal = Eigen::VectorXd::Zero(n);
  for (const Spring& s : springs_) {
    triplets.emplace_back(s.a, s.a, s.stiffness);
    triplets.emplace_back(s.b, s.b, s.stiffness);
    triplets.emplace_back(s.a, s.b, -s.stiffness);
    triplets.emplace_back(s.b, s.a, -s.stiffness);
    diagonal[s.a] += s.stiffness;
    diagonal[s.b] += s.stiffness;
  }
  for (const VolumeTerm& term : volume_terms_) {
    const Eigen::Matrix<double, 3, 4> g = gradientOperator(term.rest_inverse);
    const Eigen::Matrix4d block = term.weight * g.transpose() * g;
    for (int i = 0; i < 4; ++i) {
      diagonal[term.vertex[i]] += block(i, i);
      for (int j = 0; j < 4; ++j) triplets.emplace_back(term.vertex[i], term.vertex[j], block(i, j));
    }
  }
  inertia_weight_.resize(free_count_);
  contact_weight_.resize(free_count_);
  double mean_diagonal = 0;
  for (Eigen::Index f = 0; f < free_count_; ++f) mean_diagonal += diagonal[free_particle_[static_cast<std::size_t>(f)]];
  mean_diagonal = free_count_ > 0 ? mean_diagonal / static_cast<double>(free_count_) : 1.0;
  if (!(mean_diagonal > 0)) mean_diagonal = 1.0;
  const double h = settings_.time_step_s;
  for (Eigen::Index f = 0; f < free_count_; ++f) {
    const std::int32_t i = free_particle_[static_cast<std::size_t>(f)];
    inertia_weight_[f] = settings_.quasi_static ? settings_.quasi_static_regularisation * mean_diagonal
                                                : system_.mass[i] / (h * h);
    contact_weight_[f] = system_.radius[i] > 0 ? settings_.contact_weight * mean_diagonal : 0.0;
    triplets.emplace_back(i, i, inertia_weight_[f] + contact_weight_[f]);
    if (settings_.quasi_static) {  // both pull towards the current iterate: one weight
      inertia_weight_[f] += contact_weight_[f];
      contact_weight_[f] = 0;
    }
  }

  // Split into the free-free block (factorised) and the free-fixed coupling (moves to the right-hand side).
  std::vector<Eigen::Triplet<double>> free_free, free_fixed;
  free_free.reserve(triplets.size());
  for (const Eigen::Triplet<double>& t : triplets) {
    const std::int32_t row = free_index_[static_cast<std::size_t>(t.row())];
    if (row < 0) continue;
    const std::int32_t column = free_index_[static_cast<std::size_t>(t.col())];
    if (column >= 0)
      free_free.emplace_back(row, column, t.value());
    else
      free_fixed.emplace_back(row, t.col(), t.value());
  }
  Eigen::SparseMatrix<double> matrix(free_count_, free_count_);
  matrix.setFromTriplets(free_free.begin(), free_free.end());
  if (settings_.lbfgs_history > 0) {
    // The proximal weights only shape the preconditioner; the energy's Hessian part is L alone.
    Eigen::VectorXd proximal(free_count_);
    for (Eigen::Index f = 0; f < free_count_; ++f) proximal[f] = inertia_weight_[f] + contact_weight_[f];
    Eigen::SparseMatrix<double> proximal_matrix(free_count_, free_count_);
    proximal_matrix = Eigen::SparseMatrix<double>(proximal.asDiagonal());
    stiffness_free_ = matrix - proximal_matrix;
  }
  free_fixed_.resize(free_count_, n);
  free_fixed_.setFromTriplets(free_fixed.begin(), free_fixed.end());
  factor_.compute(matrix);
  if (factor_.info() != Eigen::Success)
    throw std::runtime_error("local/global solver: factorisation of the system matrix failed");
  ++factorisations_;
  factorisation_ms_ = millisecondsSince(start);
}

template <bool kWithEnergy>
double LocalGlobalSolver::addProjections(const Eigen::Matrix3Xd& position, Eigen::MatrixXd& rhs) const {
  // Each spring's optimal auxiliary vector d is its current direction at rest length; it enters as k d for the first
  // particle and -k d for the second.
  double energy = 0;
  const double* x = position.data();
  double* r = rhs.data();
  const Eigen::Index ld = free_count_;  // column stride of rhs
  for (const Spring& s : springs_) {
    const double dx = x[3 * s.a] - x[3 * s.b], dy = x[3 * s.a + 1] - x[3 * s.b + 1], dz = x[3 * s.a + 2] - x[3 * s.b + 2];
    const double length = std::sqrt(dx * dx + dy * dy + dz * dz);
    if constexpr (kWithEnergy) energy += 0.5 * s.stiffness * (length - s.rest_length) * (length - s.rest_length);
    // Coincident particles give no direction; d = 0 pulls them together for one iteration and they separate after.
    const double scale = length > 0 ? s.stiffness * s.rest_length / length : 0.0;
    if (s.fa >= 0) {
      r[s.fa] += scale * dx;
      r[s.fa + ld] += scale * dy;
      r[s.fa + 2 * ld] += scale * dz;
    }
    if (s.fb >= 0) {
      r[s.fb] -= scale * dx;
      r[s.fb + ld] -= scale * dy;
      r[s.fb + 2 * ld] -= scale * dz;
    }
  }
  // Volume terms: the nearest deformation gradient T whose determinant lies in [1 - e, 1 + e]; it enters as
  // w V T g_j for vertex j.
  const double low = 1.0 - settings_.volume_tolerance, high = 1.0 + settings_.volume_tolerance;
  for (const VolumeTerm& term : volume_terms_) {
    Eigen::Matrix3d edges;
    for (int j = 0; j < 3; ++j) edges.col(j) = position.col(term.vertex[j + 1]) - position.col(term.vertex[0]);
    const Eigen::Matrix3d deformation = edges * term.rest_inverse;
    const double determinant = deformation.determinant();
    Eigen::Matrix3d target = deformation;
    if (!(determinant >= low && determinant <= high))
      target = projectDeterminant(deformation, determinant < low ? low : high);
    if constexpr (kWithEnergy) energy += 0.5 * term.weight * (deformation - target).squaredNorm();
    const Eigen::Matrix<double, 3, 4> g = gradientOperator(term.rest_inverse);
    const Eigen::Matrix<double, 3, 4> force = term.weight * target * g;
    for (int j = 0; j < 4; ++j) {
      const std::int32_t f = term.free[j];
      if (f < 0) continue;
      r[f] += force(0, j);
      r[f + ld] += force(1, j);
      r[f + 2 * ld] += force(2, j);
    }
  }
  return energy;
}

void LocalGlobalSolver::localGlobalIteration(const ParticleState& state) {
  rhs_ = inertial_target_ + fixed_rhs_;
  addProjections<false>(state.position, rhs_);
  // Global step: the prefactored matrix, three right-hand sides.
  solvePrefactored(rhs_, free_next_);
}

void LocalGlobalSolver::solvePrefactored(const Eigen::MatrixXd& rhs, Eigen::MatrixXd& result) {
  const Eigen::SparseMatrix<double>& lower = factor_.matrixL().nestedExpression();  // strictly lower, unit diagonal
  const Eigen::VectorXd& diagonal = factor_.vectorD();
  const auto* permutation = factor_.permutationP().indices().data();
  const auto* column_start = lower.outerIndexPtr();
  const auto* row = lower.innerIndexPtr();
  const double* value = lower.valuePtr();
  const Eigen::Index n = free_count_;
  permuted_solution_.resize(3, n);
  for (Eigen::Index i = 0; i < n; ++i) permuted_solution_.col(permutation[i]) = rhs.row(i).transpose();
  double* y = permuted_solution_.data();
  for (Eigen::Index j = 0; j < n; ++j) {  // L z = P b
    const double y0 = y[3 * j], y1 = y[3 * j + 1], y2 = y[3 * j + 2];
    for (auto p = column_start[j]; p < column_start[j + 1]; ++p) {
      double* target = y + 3 * row[p];
      target[0] -= value[p] * y0;
      target[1] -= value[p] * y1;
      target[2] -= value[p] * y2;
    }
  }
  for (Eigen::Index j = 0; j < n; ++j) permuted_solution_.col(j) /= diagonal[j];  // D w = z
  for (Eigen::Index j = n - 1; j >= 0; --j) {  // L^T v = w
    double y0 = y[3 * j], y1 = y[3 * j + 1], y2 = y[3 * j + 2];
    for (auto p = column_start[j]; p < column_start[j + 1]; ++p) {
      const double* source = y + 3 * row[p];
      y0 -= value[p] * source[0];
      y1 -= value[p] * source[1];
      y2 -= value[p] * source[2];
    }
    y[3 * j] = y0;
    y[3 * j + 1] = y1;
    y[3 * j + 2] = y2;
  }
  result.resize(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) result.row(i) = permuted_solution_.col(permutation[i]).transpose();
}

void LocalGlobalSolver::scatterFree(const Eigen::MatrixXd& free, Eigen::Matrix3Xd& position) const {
  for (Eigen::Index f = 0; f < free_count_; ++f)
    position.col(free_particle_[static_cast<std::size_t>(f)]) = free.row(f).transpose();
}

void LocalGlobalSolver::gatherFree(const Eigen::Matrix3Xd& position, Eigen::MatrixXd& free) const {
  for (Eigen::Index f = 0; f < free_count_; ++f)
    free.row(f) = position.col(free_particle_[static_cast<std::size_t>(f)]).transpose();
}

double LocalGlobalSolver::energyAndGradient(const Eigen::Matrix3Xd& position, const Eigen::MatrixXd& free,
                                            Eigen::MatrixXd& gradient) {
  rhs_ = fixed_rhs_;
  const double energy = addProjections<true>(position, rhs_);
  gradient.noalias() = stiffness_free_ * free;
  gradient -= rhs_;
  return energy;
}

void LocalGlobalSolver::quasiNewtonIterations(ParticleState& state, const StoppingSettings& stopping_settings,
                                              const AfterUpdateHook& after_update, SolveStats& stats,
                                              Clock::time_point solve_start) {
  // L-BFGS two-loop recursion with H0 = (L + W)^-1 (the prefactored matrix), backtracking (Armijo) line search on the
  // energy. The collision hook runs after every accepted step; when it moved particles the energy and gradient are
  // evaluated again at the corrected positions, so every curvature pair is between points where gradients were taken.
  const int history = settings_.lbfgs_history;
  const double free_count = std::max<double>(1.0, static_cast<double>(free_count_));
  constexpr double kArmijo = 1e-4;
  constexpr int kMaxHalvings = 30;
  int stored = 0, newest = -1;
  StoppingMonitor stopping(stopping_settings.rule, stopping_settings.displacement_tolerance_m, stopping_settings.time_budget_ms);

  auto mss_start = Clock::now();
  gatherFree(state.position, free_current_);
  double energy = energyAndGradient(state.position, free_current_, gradient_);
  for (int iteration = 0; iteration < stopping_settings.max_iterations; ++iteration) {
    if (iteration > 0) {
      const int slot = (newest + 1) % history;
      history_step_[slot] = free_current_ - free_previous_;
      history_gradient_change_[slot] = gradient_ - previous_gradient_;
      const double curvature = (history_step_[slot].array() * history_gradient_change_[slot].array()).sum();
      // Only pairs of positive curvature keep the inverse-Hessian estimate positive definite.
      if (curvature > 1e-12 * history_step_[slot].norm() * history_gradient_change_[slot].norm()) {
        history_inverse_curvature_[slot] = 1.0 / curvature;
        newest = slot;
        stored = std::min(stored + 1, history);
      }
    }
    direction_ = gradient_;
    for (int j = 0; j < stored; ++j) {
      const int slot = (newest - j + history) % history;
      history_alpha_[slot] = history_inverse_curvature_[slot] * (history_step_[slot].array() * direction_.array()).sum();
      direction_ -= history_alpha_[slot] * history_gradient_change_[slot];
    }
    solvePrefactored(direction_, trial_);  // trial_ is free until the line search
    direction_.swap(trial_);
    for (int j = stored - 1; j >= 0; --j) {
      const int slot = (newest - j + history) % history;
      const double beta =
          history_inverse_curvature_[slot] * (history_gradient_change_[slot].array() * direction_.array()).sum();
      direction_ += (history_alpha_[slot] - beta) * history_step_[slot];
    }
    direction_ = -direction_;
    double slope = (gradient_.array() * direction_.array()).sum();
    if (!(slope < 0)) {  // the history no longer describes the energy here: fall back to the plain preconditioned step
      stored = 0;
      solvePrefactored(gradient_, direction_);
      direction_ = -direction_;
      slope = (gradient_.array() * direction_.array()).sum();
    }

    double step = 1.0, trial_energy = energy;
    bool decreased = false;
    for (int halving = 0; halving <= kMaxHalvings && slope < 0; ++halving, step *= 0.5) {
      trial_ = free_current_ + step * direction_;
      scatterFree(trial_, state.position);
      trial_energy = energyAndGradient(state.position, trial_, trial_gradient_);
      if (trial_energy <= energy + kArmijo * step * slope) {
        decreased = true;
        break;
      }
    }
    if (!decreased) {  // no descent left at machine precision: this is the minimum the hook allows
      scatterFree(free_current_, state.position);
      stats.iterations = iteration + 1;
      stats.mean_displacement_m = 0;
      stats.mss_ms += millisecondsSince(mss_start);
      stats.stopping_rule_met = stopping_settings.rule != StoppingRule::time_budget;
      stats.converged = stats.no_descent_left = true;  // a minimum (of what the hook allows)
      return;
    }
    free_previous_.swap(free_current_);
    free_current_.swap(trial_);
    previous_gradient_.swap(gradient_);
    gradient_.swap(trial_gradient_);
    energy = trial_energy;
    scatterFree(free_previous_, state.previous_position);
    stats.mss_ms += millisecondsSince(mss_start);

    runAfterUpdateHook(after_update, state, stats);
    mss_start = Clock::now();
    if (stats.contacts > 0) {
      gatherFree(state.position, free_current_);
      energy = energyAndGradient(state.position, free_current_, gradient_);
    }
    // Measured between the states the hook left: a step into a contact that the hook undoes is no motion, so resting
    // contacts do not keep the displacement rule from settling.
    const double displacement = (free_current_ - free_previous_).rowwise().norm().sum();
    stats.iterations = iteration + 1;
    stats.mean_displacement_m = displacement / free_count;
    if (!std::isfinite(stats.mean_displacement_m) || !std::isfinite(energy)) {
      stats.diverged = true;  // finishSolve puts the entry state back
      break;
    }
    stats.peak_mean_displacement_m = std::max(stats.peak_mean_displacement_m, stats.mean_displacement_m);
    const double elapsed_ms = millisecondsSince(solve_start);
    if (stopping.met(iteration, stats.mean_displacement_m, elapsed_ms)) {
      stats.stopping_rule_met = true;
      stats.converged = stopping_settings.rule == StoppingRule::displacement;
      break;
    }
    if (solveLimitReached(stopping_settings.limits, elapsed_ms, stats)) break;
  }
  stats.mss_ms += millisecondsSince(mss_start);
}

void LocalGlobalSolver::restLengthsChanged() {
  // Rest lengths enter the local projections only, not the prefactored matrix.
  if (!system_.belly_tone.empty()) {
    for (std::size_t spring = 0; spring < spring_entry_.size(); ++spring) {
      const std::int32_t entry = spring_entry_[spring];
      if (entry >= 0) springs_[static_cast<std::size_t>(entry)].rest_length = system_.springs.rest_length[static_cast<Eigen::Index>(spring)];
    }
    return;
  }
  for (const TendonPath& tendon : system_.tendon_paths) {
    const std::int32_t entry = spring_entry_[static_cast<std::size_t>(tendon.spring)];
    if (entry >= 0) springs_[static_cast<std::size_t>(entry)].rest_length = system_.springs.rest_length[tendon.spring];
  }
}

SolveStats LocalGlobalSolver::solve(ParticleState& state, const StoppingSettings& stopping_settings,
                                    const AfterUpdateHook& after_update) {
  if (const std::string problem = validate(stopping_settings); !problem.empty())
    throw std::invalid_argument("stopping settings: " + problem);
  if (stopping_settings.rule == StoppingRule::force_residual)
    throw std::invalid_argument("the local/global solver does not measure a force residual (stopping rule "
                                "force_residual needs solver block_descent or newton_krylov)");
  const Eigen::Index n = system_.particleCount();
  if (state.position.cols() != n || state.previous_position.cols() != n)
    throw std::invalid_argument("particle state does not match the mass-spring system (" +
                                std::to_string(state.position.cols()) + " particles given, " + std::to_string(n) +
                                " expected)");
  SolveStats stats;
  const auto solve_start = Clock::now();
  entry_position_ = state.position;
  entry_previous_position_ = state.previous_position;
  // The pose enters only here: the fixed particles' coupling terms, constant over the solve.
  for (Eigen::Index i = 0; i < n; ++i)
    if (system_.is_fixed[static_cast<std::size_t>(i)]) fixed_position_.row(i) = state.position.col(i).transpose();
  fixed_rhs_.noalias() = -(free_fixed_ * fixed_position_);

  if (settings_.lbfgs_history > 0) {
    quasiNewtonIterations(state, stopping_settings, after_update, stats, solve_start);
    return finishSolve(state, stopping_settings, stats, solve_start);
  }
  const double free_count = std::max<double>(1.0, static_cast<double>(free_count_));
  const int per_step = settings_.quasi_static ? 1 : settings_.iterations_per_step;
  const double keep_velocity = 1.0 - settings_.damping;
  const bool chebyshev = settings_.chebyshev_rho > 0;
  const double rho_squared = settings_.chebyshev_rho * settings_.chebyshev_rho;
  double omega = 1.0;
  int step_iteration = 0;  // iterations since the start of the current time step (Chebyshev restarts with it)
  StoppingMonitor stopping(stopping_settings.rule, stopping_settings.displacement_tolerance_m, stopping_settings.time_budget_ms);

  for (int iteration = 0; iteration < stopping_settings.max_iterations; ++iteration) {
    const auto mss_start = Clock::now();
    for (Eigen::Index f = 0; f < free_count_; ++f)
      free_current_.row(f) = state.position.col(free_particle_[static_cast<std::size_t>(f)]).transpose();
    if (settings_.quasi_static) {
      // Proximal term towards the current iterate: the fixed point is the static equilibrium.
      inertial_target_ = inertia_weight_.asDiagonal() * free_current_;
      step_iteration = iteration;
    } else if (iteration % per_step == 0) {
      // New implicit Euler step: y = x_n + (1 - damping)(x_n - x_{n-1}), from the state (whose previous position the
      // collision hook may have reset to stop a collided particle).
      for (Eigen::Index f = 0; f < free_count_; ++f)
        free_previous_.row(f) = state.previous_position.col(free_particle_[static_cast<std::size_t>(f)]).transpose();
      inertial_prediction_ = free_current_ + keep_velocity * (free_current_ - free_previous_);
      free_previous_ = free_current_;  // x_n: the previous position once this step is done
      step_iteration = 0;
    } else {
      ++step_iteration;
    }
    if (!settings_.quasi_static)
      inertial_target_ = inertia_weight_.asDiagonal() * inertial_prediction_ + contact_weight_.asDiagonal() * free_current_;
    localGlobalIteration(state);

    if (chebyshev) {
      // Wang 2015: x^{k+1} = omega (x_hat^{k+1} - x^{k-1}) + x^{k-1}, omega from the Chebyshev recurrence.
      if (step_iteration < settings_.chebyshev_delay)
        omega = 1.0;
      else if (step_iteration == settings_.chebyshev_delay)
        omega = 2.0 / (2.0 - rho_squared);
      else
        omega = 4.0 / (4.0 - rho_squared * omega);
      if (omega != 1.0) free_next_ = omega * (free_next_ - chebyshev_older_) + chebyshev_older_;
      chebyshev_older_ = free_current_;
    }

    double displacement = 0;
    for (Eigen::Index f = 0; f < free_count_; ++f) {
      const std::int32_t i = free_particle_[static_cast<std::size_t>(f)];
      displacement += (free_next_.row(f) - free_current_.row(f)).norm();
      state.position.col(i) = free_next_.row(f).transpose();
      state.previous_position.col(i) =
          settings_.quasi_static ? free_current_.row(f).transpose() : free_previous_.row(f).transpose();
    }
    stats.mss_ms += millisecondsSince(mss_start);

    runAfterUpdateHook(after_update, state, stats);
    stats.iterations = iteration + 1;
    stats.mean_displacement_m = displacement / free_count;
    if (!std::isfinite(stats.mean_displacement_m)) {
      stats.diverged = true;
      break;
    }
    stats.peak_mean_displacement_m = std::max(stats.peak_mean_displacement_m, stats.mean_displacement_m);
    const double elapsed_ms = millisecondsSince(solve_start);
    if (stopping.met(iteration, stats.mean_displacement_m, elapsed_ms)) {
      stats.stopping_rule_met = true;
      stats.converged = stopping_settings.rule == StoppingRule::displacement;
      break;
    }
    if (solveLimitReached(stopping_settings.limits, elapsed_ms, stats)) break;
  }
  return finishSolve(state, stopping_settings, stats, solve_start);
}

SolveStats LocalGlobalSolver::finishSolve(ParticleState& state, const StoppingSettings& stopping, SolveStats& stats,
                                          Clock::time_point solve_start) const {
  // The last collision hook ran after the last displacement was measured.
  if (!stats.diverged && !state.position.allFinite()) stats.diverged = true;
  if (stats.diverged) {
    state.position = entry_position_;
    state.previous_position = entry_previous_position_;
    stats.mean_displacement_m = 0;
    stats.peak_mean_displacement_m = 0;
  }
  // The quasi-static result is an equilibrium: leave it at rest.
  if (settings_.quasi_static) state.previous_position = state.position;
  if (stats.diverged) stats.converged = stats.no_descent_left = false;
  if (stopping.rule == StoppingRule::iterations && !stats.diverged && !stats.time_limit_reached &&
      !stats.cancelled)
    stats.stopping_rule_met = true;
  stats.last_dt_s = stats.min_dt_s = stats.max_dt_s = settings_.quasi_static ? 0.0 : settings_.time_step_s;
  stats.time_step_s = stats.last_dt_s;
  stats.total_ms = millisecondsSince(solve_start);
  recordSpringMetrics(system_.springs, state.position, stats);
  return stats;
}

}  // namespace muscle_deformation
