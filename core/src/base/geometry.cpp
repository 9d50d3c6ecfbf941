// Basic geometry on triangle meshes and polylines (Eigen only).
#include "muscle_deformation/core/base/geometry.hpp"

#include <algorithm>
#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

namespace muscle_deformation {

namespace {

// Throws instead of reading out of bounds: callers may pass a deformed vertex set that does not match.
void requireIndicesInRange(const Vertices& vertices, const Triangles& triangles, const char* what) {
  const Eigen::Index n = vertices.cols();
  for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
    for (int k = 0; k < 3; ++k) {
      const int i = triangles(k, t);
      if (i < 0 || i >= n) {
        std::ostringstream msg;
        msg << what << ": triangle " << t << " refers to vertex " << i << " but there are only " << n << " vertices";
        throw std::out_of_range(msg.str());
      }
    }
  }
}

std::string plural(long n, const char* singular, const char* plural_form) {
  return std::to_string(n) + " " + (n == 1 ? singular : plural_form);
}

Eigen::Vector3d closestPointOnSegment(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  if (!(len2 > 0.0)) return a;  // zero-length segment
  const double t = std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
  return a + t * ab;
}

}  // namespace

AlignedBox boundsOf(const Vertices& points) {
  AlignedBox box;
  for (Eigen::Index i = 0; i < points.cols(); ++i) box.extend(points.col(i));
  return box;
}

SurfaceTopologyReport checkSurfaceTopology(const TriangleMesh& mesh) {
  SurfaceTopologyReport report;
  const Eigen::Index n = mesh.vertexCount();

  // Per undirected edge: how often it is traversed from its lower to its higher index, and back.
  struct EdgeUse {
    int forward = 0;
    int backward = 0;
  };
  std::unordered_map<std::uint64_t, EdgeUse> edges;
  edges.reserve(static_cast<std::size_t>(mesh.triangleCount()) * 2);
  std::vector<char> used(static_cast<std::size_t>(n), 0);

  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3i tri = mesh.triangles.col(t);
    bool valid = true;
    for (int k = 0; k < 3; ++k) valid = valid && tri[k] >= 0 && tri[k] < n;
    if (!valid || tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) {
      // Counting its edges would only add noise (e.g. a spurious boundary) on top of the real problem.
      ++report.degenerate_triangles;
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      const int a = tri[k];
      const int b = tri[(k + 1) % 3];
      used[static_cast<std::size_t>(a)] = 1;
      const std::uint64_t key =
          (static_cast<std::uint64_t>(std::min(a, b)) << 32) | static_cast<std::uint32_t>(std::max(a, b));
      EdgeUse& use = edges[key];
      if (a < b) {
        ++use.forward;
      } else {
        ++use.backward;
      }
    }
  }

  for (const auto& entry : edges) {
    const int uses = entry.second.forward + entry.second.backward;
    if (uses == 1) {
      ++report.boundary_edges;
    } else if (uses > 2) {
      ++report.non_manifold_edges;
    } else if (entry.second.forward != 1) {
      // Two triangles sharing an edge must traverse it in opposite directions if they wind the same way.
      ++report.inconsistent_edges;
    }
  }
  report.unused_vertices = static_cast<long>(std::count(used.begin(), used.end(), 0));
  return report;
}

std::string SurfaceTopologyReport::describe() const {
  std::vector<std::string> parts;
  if (boundary_edges > 0) {
    parts.push_back(plural(boundary_edges, "boundary edge", "boundary edges") + " (open surface: holes)");
  }
  if (non_manifold_edges > 0) {
    parts.push_back(plural(non_manifold_edges, "non-manifold edge", "non-manifold edges") +
                    " (shared by three or more triangles)");
  }
  if (inconsistent_edges > 0) {
    parts.push_back(plural(inconsistent_edges, "inconsistently oriented edge", "inconsistently oriented edges") +
                    " (some triangles wound the wrong way)");
  }
  if (degenerate_triangles > 0) {
    parts.push_back(plural(degenerate_triangles, "degenerate triangle", "degenerate triangles") +
                    " (repeated or out-of-range vertex index)");
  }
  std::string text;
  if (parts.empty()) {
    text = "closed, consistently oriented 2-manifold";
  } else {
    for (std::size_t i = 0; i < parts.size(); ++i) text += (i == 0 ? "" : ", ") + parts[i];
  }
  if (unused_vertices > 0) {
    text += "; " + plural(unused_vertices, "unused vertex", "unused vertices") + " (harmless)";
  }
  return text;
}

double enclosedVolume(const TriangleMesh& mesh) { return enclosedVolume(mesh.vertices, mesh.triangles); }

double enclosedVolume(const Vertices& vertices, const Triangles& triangles) {
  requireIndicesInRange(vertices, triangles, "enclosedVolume");
  if (triangles.cols() == 0) return 0.0;
  // Tetrahedra from a point near the surface rather than the origin: same result for a closed surface,
  // but far less cancellation when the mesh sits far from the origin (e.g. millimetre scan coordinates).
  const Eigen::Vector3d origin = vertices.col(triangles(0, 0));
  double six_volume = 0.0;
  for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
    const Eigen::Vector3d a = vertices.col(triangles(0, t)) - origin;
    const Eigen::Vector3d b = vertices.col(triangles(1, t)) - origin;
    const Eigen::Vector3d c = vertices.col(triangles(2, t)) - origin;
    six_volume += a.dot(b.cross(c));
  }
  return six_volume / 6.0;
}

Vertices vertexNormals(const TriangleMesh& mesh) {
  requireIndicesInRange(mesh.vertices, mesh.triangles, "vertexNormals");
  Vertices normals = Vertices::Zero(3, mesh.vertexCount());
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t));
    const Eigen::Vector3d b = mesh.vertices.col(mesh.triangles(1, t));
    const Eigen::Vector3d c = mesh.vertices.col(mesh.triangles(2, t));
    // The cross product's length is twice the area: summing it unnormalised gives the area weighting.
    const Eigen::Vector3d weighted = (b - a).cross(c - a);
    for (int k = 0; k < 3; ++k) normals.col(mesh.triangles(k, t)) += weighted;
  }
  for (Eigen::Index i = 0; i < normals.cols(); ++i) {
    const double len = normals.col(i).norm();
    // Unused vertices (and vertices whose faces cancel) keep a zero normal rather than NaN.
    if (len > 0.0) normals.col(i) /= len;
  }
  return normals;
}

Eigen::Vector3d closestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                       const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a;
  const Eigen::Vector3d ac = c - a;
  const Eigen::Vector3d n = ab.cross(ac);
  const double n2 = n.squaredNorm();
  const double longest2 = std::max({ab.squaredNorm(), ac.squaredNorm(), (c - b).squaredNorm()});

  // Only trust the plane projection if the triangle has a well-defined normal; slivers and collapsed triangles
  // fall through to the edges, which always gives a sensible answer.
  if (n2 > 1e-24 * longest2 * longest2) {
    const Eigen::Vector3d q = p - n * (n.dot(p - a) / n2);
    const bool inside = n.dot(ab.cross(q - a)) >= 0.0 && n.dot((c - b).cross(q - b)) >= 0.0 &&
                        n.dot((a - c).cross(q - c)) >= 0.0;
    if (inside) return q;
  }

  // Outside (or degenerate): the closest point lies on one of the edges.
  const Eigen::Vector3d candidates[3] = {closestPointOnSegment(p, a, b), closestPointOnSegment(p, b, c),
                                         closestPointOnSegment(p, c, a)};
  Eigen::Vector3d best = candidates[0];
  double best2 = (p - best).squaredNorm();
  for (int k = 1; k < 3; ++k) {
    const double d2 = (p - candidates[k]).squaredNorm();
    if (d2 < best2) {
      best2 = d2;
      best = candidates[k];
    }
  }
  return best;
}

double polylineLength(const Polyline& line) {
  double length = 0.0;
  for (Eigen::Index i = 1; i < line.cols(); ++i) length += (line.col(i) - line.col(i - 1)).norm();
  return length;
}

}  // namespace muscle_deformation
