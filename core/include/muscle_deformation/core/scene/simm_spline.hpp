// The interpolating cubic spline OpenSim models use for joint translations and moving muscle points (<SimmSpline> in an
// .osim file), inherited from SIMM. Reproducing its end conditions matters: gait2392's knee translation and its
// quadriceps insertions are such splines, and another cubic through the same knots differs between them.
#pragma once

#include <cstddef>
#include <vector>

namespace muscle_deformation {

// A C2 piecewise cubic through the knots (x_i, y_i). Its end conditions are those of Forsythe, Malcolm and Moler's
// SPLINE routine, which SIMM and OpenSim use: on the first and on the last interval the spline's third derivative
// equals that of the cubic through the four end knots (with three knots: zero, so the spline is the parabola through
// them; with two: the straight line). Hence any cubic is reproduced exactly from four or more of its points.
// Outside [x_0, x_last] the spline continues as the straight line with its slope at that end, as OpenSim does.
class SimmSpline {
 public:
  // Throws std::invalid_argument if there are fewer than two knots, x and y differ in size, a value is not finite, or
  // x does not strictly increase.
  SimmSpline(std::vector<double> x, std::vector<double> y);

  double value(double x) const;
  double slope(double x) const;  // first derivative

  const std::vector<double>& knotsX() const { return x_; }
  const std::vector<double>& knotsY() const { return y_; }

 private:
  // Index k of the interval [x_k, x_k+1] that holds x (x inside the knots).
  std::size_t intervalOf(double x) const;

  std::vector<double> x_, y_;
  std::vector<double> second_derivatives_;  // of the spline at each knot
};

}  // namespace muscle_deformation
