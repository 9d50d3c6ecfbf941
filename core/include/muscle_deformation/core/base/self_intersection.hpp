// Whether a triangle surface crosses itself. A closed 2-manifold whose edges all pair up can still fold through
// itself (a segmentation smoothed into a tuck, a lobe pushed through its neighbour): its enclosed volume and every
// inside test are then wrong, and no edge count shows it.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <limits>
#include <string>

namespace muscle_deformation {

struct SelfIntersectionReport {
  long crossing_pairs = 0;        // pairs of triangles whose interiors cross
  Eigen::Vector3d example = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());  // a crossing, m
  bool crosses() const { return crossing_pairs > 0; }
  // e.g. "12 pairs of triangles cross each other (one near (0.012, -0.030, 0.101) m)"; "" when none do.
  std::string describe() const;
};

// Pairs of triangles whose interiors cross. Triangles that share an edge are never counted (they meet along it);
// triangles that share one vertex are counted when they cross beyond it, as a fold around that vertex does. Touching
// and coplanar overlaps are not counted: in general position the test is exact up to floating-point rounding of the
// orientation determinants. Triangles with an out-of-range vertex index are skipped (checkSurfaceTopology reports
// them). O(n) expected for triangles of similar size (a uniform grid of their bounding boxes).
SelfIntersectionReport findSelfIntersections(const TriangleMesh& mesh);

}  // namespace muscle_deformation
