// Whether a point lies inside a closed triangle surface, exactly, and how far it is from it: shared by scene loading
// (fibres within their muscle), preparation (muscles against bones) and the fidelity metrics.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/base/point_index.hpp"

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// The surface an inside test was asked for is not closed; the message names it and what is open.
class OpenSurfaceError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Exact inside test for a closed triangle surface: parity of the crossings of a ray in +z. The ray is tested against
// each triangle's projection onto the xy plane with edge tests evaluated in one canonical direction per edge and
// ties broken by a fixed infinitesimal shift of the ray, so a ray through an edge or a vertex is counted exactly once
// by exactly one triangle of the fan around it. Needs a closed surface (no holes; OpenSurfaceError otherwise); the winding
// may be inconsistent.
class ClosedSurfaceInsideTest {
 public:
  explicit ClosedSurfaceInsideTest(const TriangleMesh& surface, const std::string& name = "surface");
  ~ClosedSurfaceInsideTest();
  ClosedSurfaceInsideTest(ClosedSurfaceInsideTest&&) noexcept;
  ClosedSurfaceInsideTest& operator=(ClosedSurfaceInsideTest&&) noexcept;

  // Points exactly on the surface may go either way.
  bool contains(const Eigen::Vector3d& point) const;
  // Exact distance from the point to the surface (metres).
  double distanceToSurface(const Eigen::Vector3d& point) const;
  const AlignedBox& bounds() const { return bounds_; }

 private:
  int crossings(const Eigen::Vector3d& point) const;

  TriangleMesh surface_;
  AlignedBox bounds_;
  // Uniform grid over the xy extent: each cell lists the triangles whose xy bounding box overlaps it.
  int cells_x_ = 1, cells_y_ = 1;
  double cell_size_x_ = 1, cell_size_y_ = 1;
  std::vector<std::int32_t> cell_begin_;
  std::vector<std::int32_t> cell_triangles_;
  std::unique_ptr<SurfaceDistance> distance_;
};

}  // namespace muscle_deformation
