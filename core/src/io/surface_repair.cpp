#include "muscle_deformation/core/io/surface_repair.hpp"

#include "muscle_deformation/core/base/self_intersection.hpp"
#include "muscle_deformation/core/io/mesh_io.hpp"

#include "poly_data_conversion.hpp"

#include <vtkFillHolesFilter.h>
#include <vtkNew.h>
#include <vtkPolyData.h>
#include <vtkPolyDataConnectivityFilter.h>
#include <vtkPolyDataNormals.h>
#include <vtkSmartPointer.h>
#include <vtkTriangleFilter.h>

#include <algorithm>
#include <array>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <vector>

namespace muscle_deformation {
namespace {

using Triangle = std::array<int, 3>;

struct IndexedSurface {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Triangle> triangles;
};

Triangle sortedCopy(Triangle t) {
  std::sort(t.begin(), t.end());
  return t;
}

// Same vertex cycle up to rotation (a flip reverses it).
bool sameWinding(const Triangle& a, const Triangle& b) {
  for (int shift = 0; shift < 3; ++shift)
    if (a[0] == b[shift] && a[1] == b[(shift + 1) % 3] && a[2] == b[(shift + 2) % 3]) return true;
  return false;
}

using Edge = std::pair<int, int>;  // smaller vertex index first

Edge edgeOf(const Triangle& t, int k) {
  const int a = t[static_cast<std::size_t>(k)], b = t[static_cast<std::size_t>((k + 1) % 3)];
  return {std::min(a, b), std::max(a, b)};
}

// How many triangles use each edge.
std::map<Edge, int> edgeUses(const IndexedSurface& surface) {
  std::map<Edge, int> uses;
  for (const Triangle& t : surface.triangles)
    for (int k = 0; k < 3; ++k) ++uses[edgeOf(t, k)];
  return uses;
}

// Every vertex kept (vertex i stays point i), unlike toMesh below which drops unused ones.
TriangleMesh asMesh(const IndexedSurface& surface) {
  TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(surface.vertices.size()));
  for (std::size_t v = 0; v < surface.vertices.size(); ++v)
    mesh.vertices.col(static_cast<Eigen::Index>(v)) = surface.vertices[v];
  mesh.triangles.resize(3, static_cast<Eigen::Index>(surface.triangles.size()));
  for (std::size_t t = 0; t < surface.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k)
      mesh.triangles(k, static_cast<Eigen::Index>(t)) = surface.triangles[t][static_cast<std::size_t>(k)];
  return mesh;
}

vtkSmartPointer<vtkPolyData> toPolyData(const IndexedSurface& surface) {
  return muscle_deformation::toPolyData(asMesh(surface));
}

// Triangles of `data` (filters may leave polygons; they are triangulated first), keeping point indices.
IndexedSurface fromPolyData(vtkPolyData* data) {
  vtkNew<vtkTriangleFilter> triangulate;
  triangulate->SetInputData(data);
  triangulate->PassVertsOff();
  triangulate->PassLinesOff();
  triangulate->Update();
  const TriangleMesh mesh = toTriangleMesh(triangulate->GetOutput());
  IndexedSurface surface;
  surface.vertices.reserve(static_cast<std::size_t>(mesh.vertexCount()));
  for (Eigen::Index v = 0; v < mesh.vertexCount(); ++v) surface.vertices.push_back(mesh.vertices.col(v));
  surface.triangles.reserve(static_cast<std::size_t>(mesh.triangleCount()));
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    surface.triangles.push_back({mesh.triangles(0, t), mesh.triangles(1, t), mesh.triangles(2, t)});
  return surface;
}

// Merges vertices at identical positions; drops vertices no triangle uses. Returns how many were merged away.
long weld(const TriangleMesh& mesh, IndexedSurface& surface) {
  std::map<std::array<double, 3>, int> index_of;
  std::vector<int> new_index(static_cast<std::size_t>(mesh.vertexCount()), -1);
  std::set<int> used;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k) {
      const int v = mesh.triangles(k, t);
      if (v >= 0 && v < mesh.vertexCount()) used.insert(v);
    }
  long welded = 0;
  for (const int v : used) {
    const Eigen::Vector3d p = mesh.vertices.col(v);
    const auto [it, inserted] = index_of.emplace(std::array<double, 3>{p.x(), p.y(), p.z()},
                                                 static_cast<int>(surface.vertices.size()));
    if (inserted)
      surface.vertices.push_back(p);
    else
      ++welded;
    new_index[static_cast<std::size_t>(v)] = it->second;
  }
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    Triangle triangle{};
    bool valid = true;
    for (int k = 0; k < 3; ++k) {
      const int v = mesh.triangles(k, t);
      valid = valid && v >= 0 && v < mesh.vertexCount();
      triangle[static_cast<std::size_t>(k)] = valid ? new_index[static_cast<std::size_t>(v)] : -1;
    }
    surface.triangles.push_back(triangle);  // an out-of-range index makes it degenerate (-1), removed next
  }
  return welded;
}

long removeDegenerate(IndexedSurface& surface) {
  const std::size_t before = surface.triangles.size();
  surface.triangles.erase(
      std::remove_if(surface.triangles.begin(), surface.triangles.end(),
                     [&](const Triangle& t) {
                       if (t[0] < 0 || t[1] < 0 || t[2] < 0 || t[0] == t[1] || t[1] == t[2] || t[0] == t[2])
                         return true;
                       const Eigen::Vector3d& a = surface.vertices[static_cast<std::size_t>(t[0])];
                       const Eigen::Vector3d& b = surface.vertices[static_cast<std::size_t>(t[1])];
                       const Eigen::Vector3d& c = surface.vertices[static_cast<std::size_t>(t[2])];
                       return (b - a).cross(c - a).squaredNorm() == 0.0;
                     }),
      surface.triangles.end());
  return static_cast<long>(before - surface.triangles.size());
}

long removeDuplicates(IndexedSurface& surface) {
  std::set<Triangle> seen;
  const std::size_t before = surface.triangles.size();
  surface.triangles.erase(std::remove_if(surface.triangles.begin(), surface.triangles.end(),
                                         [&](const Triangle& t) { return !seen.insert(sortedCopy(t)).second; }),
                          surface.triangles.end());
  return static_cast<long>(before - surface.triangles.size());
}

// Every triangle on an edge shared by three or more triangles goes; hole filling closes what is left.
long removeNonManifold(IndexedSurface& surface) {
  std::map<Edge, int> uses = edgeUses(surface);
  const std::size_t before = surface.triangles.size();
  surface.triangles.erase(std::remove_if(surface.triangles.begin(), surface.triangles.end(),
                                         [&](const Triangle& t) {
                                           for (int k = 0; k < 3; ++k)
                                             if (uses[edgeOf(t, k)] > 2) return true;
                                           return false;
                                         }),
                          surface.triangles.end());
  return static_cast<long>(before - surface.triangles.size());
}

long keepLargestShell(IndexedSurface& surface) {
  if (surface.triangles.empty()) return 0;
  vtkNew<vtkPolyDataConnectivityFilter> connectivity;
  connectivity->SetInputData(toPolyData(surface));
  connectivity->SetExtractionModeToLargestRegion();
  connectivity->Update();
  const std::size_t before = surface.triangles.size();
  surface = fromPolyData(connectivity->GetOutput());
  return static_cast<long>(before) - static_cast<long>(surface.triangles.size());
}

bool hasBoundary(const IndexedSurface& surface) {
  for (const auto& [edge, count] : edgeUses(surface))
    if (count == 1) return true;
  return false;
}

long fillHoles(IndexedSurface& surface) {
  if (surface.triangles.empty() || !hasBoundary(surface)) return 0;
  vtkNew<vtkFillHolesFilter> fill;
  fill->SetInputData(toPolyData(surface));
  fill->SetHoleSize(std::numeric_limits<double>::max());  // every hole: the caller decided to repair
  fill->Update();
  const std::size_t before = surface.triangles.size();
  surface = fromPolyData(fill->GetOutput());
  return static_cast<long>(surface.triangles.size()) - static_cast<long>(before);
}

TriangleMesh toMesh(const IndexedSurface& surface) {
  // Drop vertices no triangle uses, keeping the order of the rest.
  std::vector<int> new_index(surface.vertices.size(), -1);
  for (const Triangle& t : surface.triangles)
    for (const int v : t) new_index[static_cast<std::size_t>(v)] = 0;
  int next = 0;
  for (int& index : new_index)
    if (index == 0) index = next++;
  TriangleMesh mesh;
  mesh.vertices.resize(3, next);
  for (std::size_t v = 0; v < surface.vertices.size(); ++v)
    if (new_index[v] >= 0) mesh.vertices.col(new_index[v]) = surface.vertices[v];
  mesh.triangles.resize(3, static_cast<Eigen::Index>(surface.triangles.size()));
  for (std::size_t t = 0; t < surface.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k)
      mesh.triangles(k, static_cast<Eigen::Index>(t)) =
          new_index[static_cast<std::size_t>(surface.triangles[t][static_cast<std::size_t>(k)])];
  return mesh;
}

// Closes the holes vtkFillHolesFilter leaves (measured on OpenSim's pelvis.vtp: loops through a vertex where two
// holes touch) with a fan from each loop's centroid. Winding is left to orient().
long fanFillRemainingHoles(IndexedSurface& surface) {
  std::multimap<int, int> boundary;  // vertex -> neighbour along a boundary edge (both directions)
  for (const auto& [edge, count] : edgeUses(surface))
    if (count == 1) {
      boundary.emplace(edge.first, edge.second);
      boundary.emplace(edge.second, edge.first);
    }
  long added = 0;
  auto takeEdge = [&](int from, int to) {
    for (auto [it, end] = boundary.equal_range(from); it != end; ++it)
      if (it->second == to) {
        boundary.erase(it);
        break;
      }
  };
  while (!boundary.empty()) {
    // Walk one loop: every vertex has an even number of boundary edges, so a walk returns to its start.
    const int start = boundary.begin()->first;
    std::vector<int> loop{start};
    int at = start;
    while (true) {
      const auto next = boundary.find(at);
      if (next == boundary.end()) break;
      const int to = next->second;
      takeEdge(at, to);
      takeEdge(to, at);
      if (to == start) break;
      loop.push_back(to);
      at = to;
    }
    if (loop.size() < 3) continue;  // a dangling edge cannot bound a hole
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const int v : loop) centroid += surface.vertices[static_cast<std::size_t>(v)];
    centroid /= static_cast<double>(loop.size());
    const int centre = static_cast<int>(surface.vertices.size());
    surface.vertices.push_back(centroid);
    for (std::size_t i = 0; i < loop.size(); ++i) surface.triangles.push_back({loop[i], loop[(i + 1) % loop.size()], centre});
    added += static_cast<long>(loop.size());
  }
  return added;
}

// Winds every triangle like its neighbours, counter-clockwise seen from outside (positive enclosed volume).
long orient(IndexedSurface& surface) {
  if (surface.triangles.empty()) return 0;
  const std::vector<Triangle> before = surface.triangles;
  vtkNew<vtkPolyDataNormals> normals;
  normals->SetInputData(toPolyData(surface));
  normals->ConsistencyOn();
  normals->AutoOrientNormalsOn();
  normals->SplittingOff();
  normals->NonManifoldTraversalOff();
  normals->ComputePointNormalsOff();
  normals->ComputeCellNormalsOn();
  normals->Update();
  IndexedSurface oriented = fromPolyData(normals->GetOutput());
  if (oriented.triangles.size() != before.size()) return 0;  // unexpected: keep the input's winding
  if (enclosedVolume(toMesh(oriented)) < 0)
    for (Triangle& t : oriented.triangles) std::swap(t[1], t[2]);
  long flipped = 0;
  for (std::size_t t = 0; t < before.size(); ++t)
    if (!sameWinding(before[t], oriented.triangles[t])) ++flipped;
  surface = std::move(oriented);
  return flipped;
}

}  // namespace

bool SurfaceRepairReport::changed() const {
  return welded_vertices || degenerate_triangles_removed || duplicate_triangles_removed ||
         non_manifold_triangles_removed || hole_triangles_added || shell_triangles_dropped || triangles_flipped ||
         level_set.has_value();
}

std::string SurfaceRepairReport::describe() const {
  std::vector<std::string> parts;
  auto add = [&](long count, const std::string& what) {
    if (count > 0) parts.push_back(what + " " + std::to_string(count));
  };
  add(welded_vertices, "vertices welded:");
  add(degenerate_triangles_removed, "degenerate triangles removed:");
  add(duplicate_triangles_removed, "duplicate triangles removed:");
  add(non_manifold_triangles_removed, "triangles on non-manifold edges removed:");
  add(shell_triangles_dropped, "triangles of loose pieces dropped:");
  add(hole_triangles_added, "triangles added to close holes:");
  add(triangles_flipped, "triangles flipped to a consistent outward winding:");
  std::string text;
  for (const std::string& part : parts) text += (text.empty() ? "" : ", ") + part;
  if (level_set)
    text = (text.empty() ? "the local repairs changed nothing" : "the local repairs (" + text + ")") + " left " +
           left_by_local_repair + ", so the surface was " + level_set->describe();
  return text.empty() ? "nothing changed" : text;
}

TriangleMesh repairSurface(const TriangleMesh& mesh, SurfaceRepairReport& report) {
  report = SurfaceRepairReport{};
  IndexedSurface surface;
  report.welded_vertices = weld(mesh, surface);
  report.degenerate_triangles_removed = removeDegenerate(surface);
  report.duplicate_triangles_removed = removeDuplicates(surface);
  report.non_manifold_triangles_removed = removeNonManifold(surface);
  report.shell_triangles_dropped = keepLargestShell(surface);
  report.hole_triangles_added = fillHoles(surface);
  report.hole_triangles_added += fanFillRemainingHoles(surface);
  report.triangles_flipped = orient(surface);
  return toMesh(surface);
}

TriangleMesh closedOrRepaired(const TriangleMesh& mesh, const std::string& source, SurfaceRepairReport& report,
                              std::string* defects) {
  report = SurfaceRepairReport{};
  const SurfaceTopologyReport found = checkSurfaceTopology(mesh);
  std::string found_text = found.closedManifold() ? "" : found.describe();
  if (const SelfIntersectionReport crossings = findSelfIntersections(mesh); crossings.crosses())
    found_text += (found_text.empty() ? "" : ", ") + crossings.describe();
  if (defects) *defects = found_text;
  if (found_text.empty()) return mesh;  // a good surface is used exactly as stored

  TriangleMesh repaired = repairSurface(mesh, report);
  std::string left;
  if (repaired.triangleCount() < 4)
    left = "fewer than 4 triangles";
  else if (const SurfaceTopologyReport topology = checkSurfaceTopology(repaired); !topology.closedManifold())
    left = topology.describe();
  else if (const SelfIntersectionReport crossings = findSelfIntersections(repaired); crossings.crosses())
    left = crossings.describe();
  if (left.empty()) return repaired;

  // What the local repair could not undo: the volume the triangles enclose decides. The local repair's result is
  // closer to closed (holes filled, fins gone), so it is rebuilt unless nothing of it is left.
  report.left_by_local_repair = left;
  TriangleMesh from = repaired;
  if (from.triangleCount() == 0) {  // the surface as given, without the triangles that name no vertex
    IndexedSurface welded;
    weld(mesh, welded);
    removeDegenerate(welded);
    from = toMesh(welded);
  }
  LevelSetRebuildReport rebuild;
  TriangleMesh rebuilt;
  try {
    rebuilt = rebuildFromLevelSet(from, static_cast<long>(mesh.triangleCount()), rebuild);
  } catch (const NoEnclosedVolumeError& e) {
    const std::string local = report.describe();
    throw LoadError(source + ": is not a closed, consistently oriented 2-manifold surface (" + found_text +
                    ") and cannot be made one: " + e.what() + " (the local repair: " + local + "; it left: " + left +
                    ")");
  }
  const SurfaceTopologyReport result = checkSurfaceTopology(rebuilt);
  if (!result.closedManifold())  // the iso-surface of a level set is closed: this would be a bug, said as such
    throw LoadError(source + ": the level-set rebuild of the surface left " + result.describe());
  report.level_set = rebuild;
  return rebuilt;
}

TriangleMesh loadRepairedClosedSurface(const std::string& path, double scale_to_metres, SurfaceRepairReport& report) {
  return closedOrRepaired(loadTriangleMesh(path, scale_to_metres), path, report);
}

}  // namespace muscle_deformation
