// Specifications of the SIMM/OpenSim interpolating spline (knee translations and moving muscle points of gait2392).
#include "muscle_deformation/core/scene/simm_spline.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

namespace md = muscle_deformation;

namespace {

double cubic(double x) { return 0.3 - 1.2 * x + 0.7 * x * x + 0.25 * x * x * x; }
double cubicSlope(double x) { return -1.2 + 1.4 * x + 0.75 * x * x; }

md::SimmSpline splineThrough(const std::vector<double>& x, double (*f)(double)) {
  std::vector<double> y;
  for (double xi : x) y.push_back(f(xi));
  return md::SimmSpline(x, y);
}

}  // namespace

TEST(SimmSpline, PassesThroughEveryKnot) {
  const std::vector<double> x = {-2.0944, -1.22173, -0.523599, -0.349066, -0.174533, 0.159149, 2.0944};
  const std::vector<double> y = {-0.4226, -0.4082, -0.399, -0.3976, -0.3966, -0.395264, -0.396};  // gait2392 knee ty
  const md::SimmSpline spline(x, y);
  for (std::size_t i = 0; i < x.size(); ++i) EXPECT_NEAR(spline.value(x[i]), y[i], 1e-15) << "knot " << i;
}

TEST(SimmSpline, ReproducesACubicExactlyFromUnevenKnots) {
  // The end conditions match the third derivative of the cubic through the four end knots, so a cubic is its own
  // spline: value and slope agree everywhere between the knots.
  const md::SimmSpline spline = splineThrough({-1.0, -0.7, 0.1, 0.25, 0.9, 1.6, 2.0}, cubic);
  for (double x = -1.0; x <= 2.0; x += 0.01) {
    EXPECT_NEAR(spline.value(x), cubic(x), 1e-13) << "x = " << x;
    EXPECT_NEAR(spline.slope(x), cubicSlope(x), 1e-12) << "x = " << x;
  }
}

TEST(SimmSpline, ReproducesACubicFromFourKnots) {
  const md::SimmSpline spline = splineThrough({0.0, 0.5, 1.5, 3.0}, cubic);
  for (double x : {0.1, 0.7, 1.0, 2.2, 2.9}) EXPECT_NEAR(spline.value(x), cubic(x), 1e-13) << "x = " << x;
}

TEST(SimmSpline, ThreeKnotsGiveTheParabolaThroughThem) {
  // y = 2 - x + 3 x^2 through x = 0, 1, 3: with three knots the end conditions leave no third derivative.
  const md::SimmSpline spline({0.0, 1.0, 3.0}, {2.0, 4.0, 26.0});
  for (double x : {0.2, 0.5, 1.7, 2.5}) EXPECT_NEAR(spline.value(x), 2 - x + 3 * x * x, 1e-13) << "x = " << x;
}

TEST(SimmSpline, TwoKnotsGiveTheStraightLine) {
  const md::SimmSpline spline({-2.0944, 0.1745}, {0.0014, 0.0014});  // a constant moving-point component of gait2392
  EXPECT_DOUBLE_EQ(spline.value(-1.0), 0.0014);
  const md::SimmSpline line({1.0, 3.0}, {0.0, 1.0});
  EXPECT_DOUBLE_EQ(line.value(2.0), 0.5);
  EXPECT_DOUBLE_EQ(line.slope(2.0), 0.5);
}

TEST(SimmSpline, ContinuesOutsideTheKnotsAlongTheEndSlope) {
  const md::SimmSpline spline = splineThrough({-1.0, -0.7, 0.1, 0.25, 0.9, 1.6, 2.0}, cubic);
  EXPECT_NEAR(spline.value(-1.5), cubic(-1.0) - 0.5 * cubicSlope(-1.0), 1e-12);
  EXPECT_NEAR(spline.value(3.0), cubic(2.0) + 1.0 * cubicSlope(2.0), 1e-12);
  EXPECT_NEAR(spline.slope(3.0), cubicSlope(2.0), 1e-12);
}

TEST(SimmSpline, RefusesKnotsThatDoNotIncrease) {
  EXPECT_THROW(md::SimmSpline({0.0, 1.0, 1.0}, {0.0, 1.0, 2.0}), std::invalid_argument);
  EXPECT_THROW(md::SimmSpline({0.0, 2.0, 1.0}, {0.0, 1.0, 2.0}), std::invalid_argument);
  EXPECT_THROW(md::SimmSpline({0.0}, {0.0}), std::invalid_argument);
  EXPECT_THROW(md::SimmSpline({0.0, 1.0}, {0.0}), std::invalid_argument);
  EXPECT_THROW(md::SimmSpline({0.0, NAN}, {0.0, 1.0}), std::invalid_argument);
}
