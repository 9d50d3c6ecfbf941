#include "muscle_deformation/core/base/self_intersection.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace muscle_deformation {

namespace {

using Vec = Eigen::Vector3d;

// Sign of the volume of the tetrahedron (a, b, c, d): which side of plane abc the point d lies on.
int orient(const Vec& a, const Vec& b, const Vec& c, const Vec& d) {
  const double v = (b - a).cross(c - a).dot(d - a);
  return (v > 0) - (v < 0);
}

// The open segment p-q crosses the interior of triangle abc (strictly: touching is not crossing).
bool segmentCrossesTriangle(const Vec& p, const Vec& q, const Vec& a, const Vec& b, const Vec& c) {
  const int sp = orient(a, b, c, p), sq = orient(a, b, c, q);
  if (sp == 0 || sq == 0 || sp == sq) return false;
  const int s1 = orient(p, q, a, b), s2 = orient(p, q, b, c), s3 = orient(p, q, c, a);
  return s1 != 0 && s1 == s2 && s2 == s3;
}

// Two triangles with no vertex in common cross when an edge of one crosses the other: the segment two crossing
// triangles share ends on their edges.
bool trianglesCross(const std::array<Vec, 3>& t, const std::array<Vec, 3>& u) {
  for (int k = 0; k < 3; ++k) {
    if (segmentCrossesTriangle(t[k], t[(k + 1) % 3], u[0], u[1], u[2])) return true;
    if (segmentCrossesTriangle(u[k], u[(k + 1) % 3], t[0], t[1], t[2])) return true;
  }
  return false;
}

struct Box {
  Vec min, max;
  bool overlaps(const Box& o) const { return (min.array() <= o.max.array()).all() && (o.min.array() <= max.array()).all(); }
};

}  // namespace

std::string SelfIntersectionReport::describe() const {
  if (!crosses()) return "";
  std::ostringstream out;
  out << crossing_pairs << (crossing_pairs == 1 ? " pair" : " pairs") << " of triangles cross each other (one near ("
      << std::setprecision(4) << example.x() << ", " << example.y() << ", " << example.z() << "))";
  return out.str();
}

SelfIntersectionReport findSelfIntersections(const TriangleMesh& mesh) {
  SelfIntersectionReport report;
  const Eigen::Index n = mesh.vertexCount();
  std::vector<int> usable;  // triangles with three distinct vertices in range
  std::vector<Box> boxes(static_cast<std::size_t>(mesh.triangleCount()));
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3i v = mesh.triangles.col(t);
    if ((v.array() < 0).any() || (v.array() >= n).any() || v[0] == v[1] || v[1] == v[2] || v[0] == v[2]) continue;
    Box& box = boxes[static_cast<std::size_t>(t)];
    box.min = mesh.vertices.col(v[0]).cwiseMin(mesh.vertices.col(v[1])).cwiseMin(mesh.vertices.col(v[2]));
    box.max = mesh.vertices.col(v[0]).cwiseMax(mesh.vertices.col(v[1])).cwiseMax(mesh.vertices.col(v[2]));
    if (!box.min.allFinite() || !box.max.allFinite()) continue;
    usable.push_back(static_cast<int>(t));
  }
  if (usable.size() < 2) return report;

  // Grid cells about twice the median triangle's largest extent: each triangle overlaps a few cells.
  std::vector<double> extents;
  extents.reserve(usable.size());
  for (const int t : usable) extents.push_back((boxes[static_cast<std::size_t>(t)].max - boxes[static_cast<std::size_t>(t)].min).maxCoeff());
  std::nth_element(extents.begin(), extents.begin() + static_cast<std::ptrdiff_t>(extents.size() / 2), extents.end());
  AlignedBox all;
  for (const int t : usable) {
    all.extend(boxes[static_cast<std::size_t>(t)].min);
    all.extend(boxes[static_cast<std::size_t>(t)].max);
  }
  // At least the median extent, and no more than about 200 cells along the longest side, so that a few huge triangles
  // among small ones cannot make the grid the size of memory.
  const double cell = std::max({2.0 * extents[extents.size() / 2], (all.max - all.min).maxCoeff() / 200.0, 1e-12});
  const auto cellOf = [&](const Vec& p) {
    return Eigen::Vector3i(((p - all.min) / cell).array().floor().cast<int>());
  };
  const auto key = [](const Eigen::Vector3i& c) {
    return (static_cast<std::uint64_t>(c.x()) << 42) ^ (static_cast<std::uint64_t>(c.y()) << 21) ^
           static_cast<std::uint64_t>(c.z());
  };
  std::unordered_map<std::uint64_t, std::vector<int>> cells;
  for (const int t : usable) {
    const Box& box = boxes[static_cast<std::size_t>(t)];
    const Eigen::Vector3i lo = cellOf(box.min), hi = cellOf(box.max);
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) cells[key({x, y, z})].push_back(t);
  }

  const auto corners = [&](int t) {
    return std::array<Vec, 3>{mesh.vertices.col(mesh.triangles(0, t)), mesh.vertices.col(mesh.triangles(1, t)),
                              mesh.vertices.col(mesh.triangles(2, t))};
  };
  for (const auto& [cell_key, members] : cells) {
    for (std::size_t i = 0; i < members.size(); ++i) {
      for (std::size_t j = i + 1; j < members.size(); ++j) {
        const int a = members[i], b = members[j];
        const Box& box_a = boxes[static_cast<std::size_t>(a)];
        const Box& box_b = boxes[static_cast<std::size_t>(b)];
        if (!box_a.overlaps(box_b)) continue;
        // Each pair once: in the cell holding the lower corner of the boxes' overlap.
        if (key(cellOf(box_a.min.cwiseMax(box_b.min))) != cell_key) continue;
        std::array<int, 3> va{mesh.triangles(0, a), mesh.triangles(1, a), mesh.triangles(2, a)};
        std::array<int, 3> vb{mesh.triangles(0, b), mesh.triangles(1, b), mesh.triangles(2, b)};
        int shared = 0, shared_a = -1, shared_b = -1;
        for (int p = 0; p < 3; ++p)
          for (int q = 0; q < 3; ++q)
            if (va[static_cast<std::size_t>(p)] == vb[static_cast<std::size_t>(q)]) {
              ++shared;
              shared_a = p;
              shared_b = q;
            }
        const std::array<Vec, 3> ta = corners(a), tb = corners(b);
        bool cross = false;
        if (shared == 0) {
          cross = trianglesCross(ta, tb);
        } else if (shared == 1) {
          // They meet at the shared vertex; beyond it, the edge of one opposite that vertex crosses the other.
          const std::size_t pa = static_cast<std::size_t>(shared_a), pb = static_cast<std::size_t>(shared_b);
          cross = segmentCrossesTriangle(ta[(pa + 1) % 3], ta[(pa + 2) % 3], tb[0], tb[1], tb[2]) ||
                  segmentCrossesTriangle(tb[(pb + 1) % 3], tb[(pb + 2) % 3], ta[0], ta[1], ta[2]);
        }
        if (!cross) continue;
        if (report.crossing_pairs == 0) report.example = (ta[0] + ta[1] + ta[2] + tb[0] + tb[1] + tb[2]) / 6.0;
        ++report.crossing_pairs;
      }
    }
  }
  return report;
}

}  // namespace muscle_deformation
