// Triangle meshes and polylines: the geometric primitives every other stage works on.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace muscle_deformation {

using Vertices = Eigen::Matrix3Xd;      // one column per vertex, metres
using Triangles = Eigen::Matrix3Xi;     // one column per triangle, vertex indices

struct TriangleMesh {
  Vertices vertices = Vertices(3, 0);
  Triangles triangles = Triangles(3, 0);

  Eigen::Index vertexCount() const { return vertices.cols(); }
  Eigen::Index triangleCount() const { return triangles.cols(); }
};

// An ordered list of points, e.g. one muscle fibre from origin to insertion.
using Polyline = Eigen::Matrix3Xd;

struct AlignedBox {
  Eigen::Vector3d min = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d max = Eigen::Vector3d::Constant(-std::numeric_limits<double>::infinity());
  bool empty() const { return (min.array() > max.array()).any(); }
  void extend(const Eigen::Vector3d& p) {
    min = min.cwiseMin(p);
    max = max.cwiseMax(p);
  }
};

AlignedBox boundsOf(const Vertices& points);

// What is wrong with a surface that should bound a volume. Empty issues() means closed and 2-manifold.
struct SurfaceTopologyReport {
  long boundary_edges = 0;       // edges used by one triangle: the surface has holes
  long non_manifold_edges = 0;   // edges used by three or more triangles
  long inconsistent_edges = 0;   // edges traversed in the same direction by both triangles (flipped winding)
  long degenerate_triangles = 0; // repeated vertex index or out-of-range index
  long unused_vertices = 0;      // vertices no triangle refers to (harmless, reported for information)

  bool closedManifold() const {
    return boundary_edges == 0 && non_manifold_edges == 0 && inconsistent_edges == 0 && degenerate_triangles == 0;
  }
  // Human-readable summary, e.g. "12 boundary edges (open surface), 2 non-manifold edges".
  std::string describe() const;
};

SurfaceTopologyReport checkSurfaceTopology(const TriangleMesh& mesh);

// Signed volume enclosed by a closed, consistently oriented surface (divergence theorem).
// Positive when triangles wind counter-clockwise seen from outside.
double enclosedVolume(const TriangleMesh& mesh);

// Same, for the mesh's connectivity with other vertex positions (e.g. a deformed surface).
double enclosedVolume(const Vertices& vertices, const Triangles& triangles);

// Per-vertex unit normals, area-weighted average of incident face normals.
Vertices vertexNormals(const TriangleMesh& mesh);

// Closest point on triangle (a, b, c) to p.
Eigen::Vector3d closestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                       const Eigen::Vector3d& c);

// Total length of a polyline.
double polylineLength(const Polyline& line);

}  // namespace muscle_deformation
