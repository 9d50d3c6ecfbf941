#include "muscle_deformation/core/base/inside_test.hpp"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

namespace muscle_deformation {

namespace {

// a * b = product + error, exactly (fma rounds once).
void twoProduct(double a, double b, double& product, double& error) {
  product = a * b;
  error = std::fma(a, b, -product);
}

// a + b = sum + error, exactly.
void twoSum(double a, double b, double& sum, double& error) {
  sum = a + b;
  const double b_part = sum - a;
  const double a_part = sum - b_part;
  error = (a - a_part) + (b - b_part);
}

// Exact sign of a sum of doubles: the terms are gathered into a non-overlapping expansion (Shewchuk's
// grow-expansion with zero elimination) whose largest component carries the sign.
int exactSignOfSum(const double* terms, int count) {
  double expansion[16];
  int length = 0;
  for (int t = 0; t < count; ++t) {
    double running = terms[t];
    int kept = 0;
    for (int i = 0; i < length; ++i) {
      double sum, error;
      twoSum(running, expansion[i], sum, error);
      if (error != 0) expansion[kept++] = error;
      running = sum;
    }
    if (running != 0) expansion[kept++] = running;
    length = kept;
  }
  if (length == 0) return 0;
  return expansion[length - 1] > 0 ? 1 : -1;
}

// Orientation of (a, b, c) in the xy plane: (b - a) x (c - a), positive when counter-clockwise. Returns its exact
// sign; `value` gets the floating-point value. Rounding must not decide the sign: a ray grazing the shared edge of
// two triangles would otherwise be found in both or neither (parity breaks on near-vertical triangles).
int orientation(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double cx, double cy, double* value) {
  const double left = (a.x() - cx) * (b.y() - cy), right = (a.y() - cy) * (b.x() - cx);
  *value = left - right;
  const double bound = (3.0 + 16.0 * 0x1p-53) * 0x1p-53 * (std::abs(left) + std::abs(right));  // Shewchuk's A bound
  if (*value > bound) return 1;
  if (*value < -bound) return -1;
  // Expanded into products of input coordinates, each split exactly into two doubles.
  const double factors[6][2] = {{b.x(), cy}, {-b.x(), a.y()}, {-a.x(), cy}, {-b.y(), cx}, {b.y(), a.x()}, {a.y(), cx}};
  double terms[12];
  for (int k = 0; k < 6; ++k) twoProduct(factors[k][0], factors[k][1], terms[2 * k], terms[2 * k + 1]);
  return exactSignOfSum(terms, 12);
}

// Which side of the projected edge lo -> hi the ray's (x, y) lies on. An exact zero (the ray meets the edge's line)
// is decided by shifting the ray by (e, e^2) with e -> 0+, first in x, then in y: a fixed rule, so the triangles
// around an edge or a vertex agree on which of them the ray passes through.
int edgeSide(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double x, double y, double* value) {
  const int sign = orientation(lo, hi, x, y, value);
  if (sign != 0) return sign;
  if (hi.y() != lo.y()) return hi.y() < lo.y() ? 1 : -1;  // d(orientation)/dx = -(hi.y - lo.y)
  if (hi.x() != lo.x()) return hi.x() > lo.x() ? 1 : -1;  // d(orientation)/dy = hi.x - lo.x
  return 0;                                               // the edge projects to a point
}

}  // namespace

ClosedSurfaceInsideTest::ClosedSurfaceInsideTest(const TriangleMesh& surface, const std::string& name)
    : surface_(surface) {
  const SurfaceTopologyReport topology = checkSurfaceTopology(surface);
  if (topology.boundary_edges > 0 || topology.non_manifold_edges > 0 || topology.degenerate_triangles > 0 ||
      surface.triangleCount() == 0)
    throw OpenSurfaceError(name + ": surface is not closed (" +
                       (surface.triangleCount() == 0 ? std::string("no triangles") : topology.describe()) +
                       "); an inside test needs a closed surface");
  bounds_ = boundsOf(surface.vertices);
  const double width = std::max(bounds_.max.x() - bounds_.min.x(), 1e-12);
  const double height = std::max(bounds_.max.y() - bounds_.min.y(), 1e-12);
  // About two triangles' worth of cells per triangle column, square-ish cells.
  const double cells = std::max(1.0, static_cast<double>(surface.triangleCount()) / 2);
  const double side = std::sqrt(width * height / cells);
  cells_x_ = std::clamp(static_cast<int>(std::ceil(width / side)), 1, 1024);
  cells_y_ = std::clamp(static_cast<int>(std::ceil(height / side)), 1, 1024);
  cell_size_x_ = width / cells_x_;
  cell_size_y_ = height / cells_y_;
  auto cellX = [&](double x) { return std::clamp(static_cast<int>((x - bounds_.min.x()) / cell_size_x_), 0, cells_x_ - 1); };
  auto cellY = [&](double y) { return std::clamp(static_cast<int>((y - bounds_.min.y()) / cell_size_y_), 0, cells_y_ - 1); };
  std::vector<std::vector<std::int32_t>> lists(static_cast<std::size_t>(cells_x_) * cells_y_);
  for (Eigen::Index t = 0; t < surface.triangleCount(); ++t) {
    AlignedBox box;
    for (int k = 0; k < 3; ++k) box.extend(surface.vertices.col(surface.triangles(k, t)));
    for (int cy = cellY(box.min.y()); cy <= cellY(box.max.y()); ++cy)
      for (int cx = cellX(box.min.x()); cx <= cellX(box.max.x()); ++cx)
        lists[static_cast<std::size_t>(cy) * cells_x_ + cx].push_back(static_cast<std::int32_t>(t));
  }
  cell_begin_.assign(1, 0);
  for (const auto& list : lists) {
    cell_triangles_.insert(cell_triangles_.end(), list.begin(), list.end());
    cell_begin_.push_back(static_cast<std::int32_t>(cell_triangles_.size()));
  }
  distance_ = std::make_unique<SurfaceDistance>(surface.vertices, surface.triangles);
}

ClosedSurfaceInsideTest::~ClosedSurfaceInsideTest() = default;
ClosedSurfaceInsideTest::ClosedSurfaceInsideTest(ClosedSurfaceInsideTest&&) noexcept = default;
ClosedSurfaceInsideTest& ClosedSurfaceInsideTest::operator=(ClosedSurfaceInsideTest&&) noexcept = default;

int ClosedSurfaceInsideTest::crossings(const Eigen::Vector3d& point) const {
  const int cx = std::clamp(static_cast<int>((point.x() - bounds_.min.x()) / cell_size_x_), 0, cells_x_ - 1);
  const int cy = std::clamp(static_cast<int>((point.y() - bounds_.min.y()) / cell_size_y_), 0, cells_y_ - 1);
  const std::size_t cell = static_cast<std::size_t>(cy) * cells_x_ + cx;
  int count = 0;
  for (std::int32_t k = cell_begin_[cell]; k < cell_begin_[cell + 1]; ++k) {
    const std::int32_t t = cell_triangles_[k];
    int sides[3];
    double values[3];
    for (int e = 0; e < 3; ++e) {
      const int from = surface_.triangles(e, t), to = surface_.triangles((e + 1) % 3, t);
      const bool forward = from < to;
      sides[e] = edgeSide(surface_.vertices.col(forward ? from : to), surface_.vertices.col(forward ? to : from),
                          point.x(), point.y(), &values[e]);
      if (!forward) sides[e] = -sides[e], values[e] = -values[e];
    }
    if (sides[0] == 0 || sides[0] != sides[1] || sides[1] != sides[2]) continue;  // ray misses this triangle
    // Height of the triangle above the ray's (x, y): value of edge e weights the vertex opposite it.
    const double sum = values[0] + values[1] + values[2];
    double z;
    if (sum != 0) {
      z = (values[1] * surface_.vertices(2, surface_.triangles(0, t)) + values[2] * surface_.vertices(2, surface_.triangles(1, t)) +
           values[0] * surface_.vertices(2, surface_.triangles(2, t))) / sum;
    } else {  // the ray passes through a vertex or edge of a sliver; any of its heights will do
      z = surface_.vertices(2, surface_.triangles(0, t));
    }
    if (z > point.z()) ++count;
  }
  return count;
}

bool ClosedSurfaceInsideTest::contains(const Eigen::Vector3d& point) const {
  if ((point.array() < bounds_.min.array()).any() || (point.array() > bounds_.max.array()).any()) return false;
  return crossings(point) % 2 == 1;
}

double ClosedSurfaceInsideTest::distanceToSurface(const Eigen::Vector3d& point) const {
  const double distance = distance_->distance(point);
  if (std::isfinite(distance)) return distance;
  // SurfaceDistance::distance can miss by rounding when the closest point is a triangle's centroid (it compares the
  // exact distance with the centroid distance); search again with room to spare.
  return distance_->distanceWithin(point, (bounds_.max - bounds_.min).norm() + (point - bounds_.min).norm());
}

}  // namespace muscle_deformation
