#include "muscle_deformation/core/scene/simm_spline.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace muscle_deformation {
namespace {

// The third divided difference f[x_i, ..., x_i+3]: the leading coefficient of the cubic through those four knots,
// i.e. a sixth of its third derivative.
double thirdDividedDifference(const std::vector<double>& x, const std::vector<double>& y, std::size_t i) {
  double first[3], second[2];
  for (std::size_t j = 0; j < 3; ++j) first[j] = (y[i + j + 1] - y[i + j]) / (x[i + j + 1] - x[i + j]);
  for (std::size_t j = 0; j < 2; ++j) second[j] = (first[j + 1] - first[j]) / (x[i + j + 2] - x[i + j]);
  return (second[1] - second[0]) / (x[i + 3] - x[i]);
}

}  // namespace

SimmSpline::SimmSpline(std::vector<double> x, std::vector<double> y) : x_(std::move(x)), y_(std::move(y)) {
  const std::size_t n = x_.size();
  if (n != y_.size()) {
    throw std::invalid_argument("spline: " + std::to_string(n) + " x values but " + std::to_string(y_.size()) +
                                " y values");
  }
  if (n < 2) throw std::invalid_argument("spline: needs at least 2 knots, has " + std::to_string(n));
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(x_[i]) || !std::isfinite(y_[i])) {
      throw std::invalid_argument("spline: knot " + std::to_string(i + 1) + " is not a finite number");
    }
    if (i > 0 && x_[i] <= x_[i - 1]) {
      throw std::invalid_argument("spline: x does not increase at knot " + std::to_string(i + 1));
    }
  }
  second_derivatives_.assign(n, 0.0);
  if (n == 2) return;  // the straight line

  // Unknowns: the second derivatives M_i at the knots. Interior rows make the first derivative continuous; the two
  // end rows fix the (constant) third derivative (M_1 - M_0) / h_0 on each end interval.
  Eigen::MatrixXd system = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
  const auto h = [&](std::size_t i) { return x_[i + 1] - x_[i]; };
  const auto chord_slope = [&](std::size_t i) { return (y_[i + 1] - y_[i]) / h(i); };
  for (std::size_t i = 1; i + 1 < n; ++i) {
    system(i, i - 1) = h(i - 1);
    system(i, i) = 2 * (h(i - 1) + h(i));
    system(i, i + 1) = h(i);
    rhs(i) = 6 * (chord_slope(i) - chord_slope(i - 1));
  }
  system(0, 0) = -1;
  system(0, 1) = 1;
  system(n - 1, n - 2) = -1;
  system(n - 1, n - 1) = 1;
  if (n >= 4) {
    rhs(0) = 6 * h(0) * thirdDividedDifference(x_, y_, 0);
    rhs(n - 1) = 6 * h(n - 2) * thirdDividedDifference(x_, y_, n - 4);
  }
  const Eigen::VectorXd solution = system.partialPivLu().solve(rhs);
  for (std::size_t i = 0; i < n; ++i) second_derivatives_[i] = solution(i);
}

std::size_t SimmSpline::intervalOf(double x) const {
  const auto above = std::upper_bound(x_.begin(), x_.end(), x);
  const std::size_t k = above == x_.begin() ? 0 : static_cast<std::size_t>(above - x_.begin()) - 1;
  return std::min(k, x_.size() - 2);
}

double SimmSpline::value(double x) const {
  if (x < x_.front()) return y_.front() + (x - x_.front()) * slope(x_.front());
  if (x > x_.back()) return y_.back() + (x - x_.back()) * slope(x_.back());
  const std::size_t k = intervalOf(x);
  const double h = x_[k + 1] - x_[k];
  const double from_left = x - x_[k], from_right = x_[k + 1] - x;
  const double m0 = second_derivatives_[k], m1 = second_derivatives_[k + 1];
  return (m0 * from_right * from_right * from_right + m1 * from_left * from_left * from_left) / (6 * h) +
         (y_[k] / h - m0 * h / 6) * from_right + (y_[k + 1] / h - m1 * h / 6) * from_left;
}

double SimmSpline::slope(double x) const {
  x = std::clamp(x, x_.front(), x_.back());  // the extrapolating lines keep the end slopes
  const std::size_t k = intervalOf(x);
  const double h = x_[k + 1] - x_[k];
  const double from_left = x - x_[k], from_right = x_[k + 1] - x;
  const double m0 = second_derivatives_[k], m1 = second_derivatives_[k + 1];
  return (m1 * from_left * from_left - m0 * from_right * from_right) / (2 * h) + (y_[k + 1] - y_[k]) / h -
         (m1 - m0) * h / 6;
}

}  // namespace muscle_deformation
