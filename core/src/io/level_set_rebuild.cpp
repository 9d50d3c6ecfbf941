#include "muscle_deformation/core/io/level_set_rebuild.hpp"

#include "muscle_deformation/core/base/point_index.hpp"
#include "muscle_deformation/core/base/self_intersection.hpp"

#include "poly_data_conversion.hpp"

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <limits>

#include <vtkNew.h>
#include <vtkPolyData.h>
#include <vtkQuadricDecimation.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <map>
#include <mutex>
#include <numeric>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace muscle_deformation {

namespace {

// Half the narrow band, in voxels, on each side of the surface: enough for the iso-surface and for the flood fill
// that decides the inside to see a closed wall.
constexpr float kHalfBandVoxels = 3.0f;
// The narrow band's voxel budget (about 80 MB of floats).
constexpr double kMaxBandVoxels = 2e7;
// The thinnest side of the bounding box spans at least this many voxels.
constexpr double kMinVoxelsAcross = 40.0;
// The mean thickness (volume over area) spans at least this many voxels: a thin plate of bone in a wide box (OpenSim's
// pelvis: 4.9 mm against a 133 mm box) needs finer voxels than its box says. At 1 mm the pelvis lost 0.11 % of its
// volume, at 3.3 mm (its box's rule) 1.4 %.
constexpr double kVoxelsPerThickness = 5.0;
// The iso-surface is decimated afterwards: it need not have more than this many times the triangles asked for, nor
// fewer than kMinIsoTriangles (quadric decimation of 700,000 triangles took 30 s, of 170,000 4 s).
constexpr double kIsoTrianglesPerTarget = 8.0;
constexpr double kMinIsoTriangles = 2e5;
// The decimation tries the count asked for, then twice it, and so on up to this many times (closedDecimatedSurface).
// A carve follows muscle surfaces into a bone at half a millimetre: a carved pelvis needed about 100,000 triangles to
// stay within a voxel of its iso-surface, where a rebuilt one keeps its own coarse shape.
constexpr long kRebuildMaxFactor = 8;
constexpr long kCarveMaxFactor = 32;
// A volume's level set reaches deeper inside than this (voxels); a sheet's spurious inside does not (see below).
constexpr double kMinDepthVoxels = 1.5;

void initialiseOpenVdbOnce() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

double surfaceArea(const TriangleMesh& mesh) {
  double area = 0;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t));
    area += 0.5 * (mesh.vertices.col(mesh.triangles(1, t)) - a).cross(mesh.vertices.col(mesh.triangles(2, t)) - a).norm();
  }
  return area;
}

// Every undirected edge traversed as often in one direction as in the other: the triangles form a closed, oriented
// chain, and the divergence theorem gives the volume it winds around (a non-manifold edge or a fold does not spoil
// that; a hole or a flipped triangle does).
bool isClosedOrientedChain(const TriangleMesh& mesh) {
  std::unordered_map<std::uint64_t, int> balance;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t a = static_cast<std::uint32_t>(mesh.triangles(k, t));
      const std::uint32_t b = static_cast<std::uint32_t>(mesh.triangles((k + 1) % 3, t));
      if (a == b) continue;
      const std::uint64_t key = (static_cast<std::uint64_t>(std::min(a, b)) << 32) | std::max(a, b);
      balance[key] += a < b ? 1 : -1;
    }
  return std::all_of(balance.begin(), balance.end(), [](const auto& entry) { return entry.second == 0; });
}

// The triangles of one piece each (pieces = triangles connected through shared vertices).
std::vector<std::vector<Eigen::Index>> pieces(const TriangleMesh& mesh) {
  std::vector<int> parent(static_cast<std::size_t>(mesh.vertexCount()));
  std::iota(parent.begin(), parent.end(), 0);
  const auto find = [&](int v) {
    while (parent[static_cast<std::size_t>(v)] != v) {
      parent[static_cast<std::size_t>(v)] = parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(v)])];
      v = parent[static_cast<std::size_t>(v)];
    }
    return v;
  };
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 1; k < 3; ++k) parent[static_cast<std::size_t>(find(mesh.triangles(k, t)))] = find(mesh.triangles(0, t));
  std::map<int, std::vector<Eigen::Index>> by_root;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) by_root[find(mesh.triangles(0, t))].push_back(t);
  std::vector<std::vector<Eigen::Index>> out;
  for (auto& [root, triangles] : by_root) out.push_back(std::move(triangles));
  return out;
}

// The given triangles of `mesh`, with only the vertices they use.
TriangleMesh subset(const TriangleMesh& mesh, const std::vector<Eigen::Index>& triangles) {
  std::vector<int> new_index(static_cast<std::size_t>(mesh.vertexCount()), -1);
  TriangleMesh out;
  out.triangles.resize(3, static_cast<Eigen::Index>(triangles.size()));
  std::vector<int> kept;
  for (std::size_t i = 0; i < triangles.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      int& index = new_index[static_cast<std::size_t>(mesh.triangles(k, triangles[i]))];
      if (index < 0) {
        index = static_cast<int>(kept.size());
        kept.push_back(mesh.triangles(k, triangles[i]));
      }
      out.triangles(k, static_cast<Eigen::Index>(i)) = index;
    }
  out.vertices.resize(3, static_cast<Eigen::Index>(kept.size()));
  for (std::size_t v = 0; v < kept.size(); ++v) out.vertices.col(static_cast<Eigen::Index>(v)) = mesh.vertices.col(kept[v]);
  return out;
}

// The zero iso-surface of the grid: quads split along their shorter diagonal.
TriangleMesh isoSurface(const openvdb::FloatGrid& grid) {
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(grid, points, triangles, quads, 0.0, 0.0);
  TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(points.size()));
  for (std::size_t v = 0; v < points.size(); ++v)
    mesh.vertices.col(static_cast<Eigen::Index>(v)) << points[v].x(), points[v].y(), points[v].z();
  mesh.triangles.resize(3, static_cast<Eigen::Index>(triangles.size() + 2 * quads.size()));
  Eigen::Index next = 0;
  for (const openvdb::Vec3I& t : triangles) mesh.triangles.col(next++) << int(t[0]), int(t[1]), int(t[2]);
  for (const openvdb::Vec4I& q : quads) {
    const auto at = [&](int k) { return mesh.vertices.col(static_cast<Eigen::Index>(q[k])); };
    if ((at(0) - at(2)).squaredNorm() <= (at(1) - at(3)).squaredNorm()) {
      mesh.triangles.col(next++) << int(q[0]), int(q[1]), int(q[2]);
      mesh.triangles.col(next++) << int(q[0]), int(q[2]), int(q[3]);
    } else {
      mesh.triangles.col(next++) << int(q[0]), int(q[1]), int(q[3]);
      mesh.triangles.col(next++) << int(q[1]), int(q[2]), int(q[3]);
    }
  }
  return mesh;
}

bool isSound(const TriangleMesh& mesh) {
  return mesh.triangleCount() >= 4 && checkSurfaceTopology(mesh).closedManifold() && enclosedVolume(mesh) > 0 &&
         !findSelfIntersections(mesh).crosses();
}

TriangleMesh decimated(const TriangleMesh& mesh, long target_triangles) {
  vtkNew<vtkQuadricDecimation> decimate;
  decimate->SetInputData(toPolyData(mesh));
  decimate->SetTargetReduction(1.0 - static_cast<double>(target_triangles) / static_cast<double>(mesh.triangleCount()));
  decimate->VolumePreservationOn();
  decimate->Update();
  return toTriangleMesh(decimate->GetOutput());
}

std::string fixed(double value, int decimals) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(decimals) << value;
  return out.str();
}

}  // namespace

std::optional<double> LevelSetRebuildReport::volumeChange() const {
  if (!input_volume_m3 || !(*input_volume_m3 > 0)) return std::nullopt;
  return volume_m3 / *input_volume_m3 - 1.0;
}

std::string LevelSetRebuildReport::describe() const {
  std::ostringstream out;
  out << "rebuilt from a level set (voxel " << fixed(voxel_m * 1e3, 2) << " mm, " << triangles << " triangles";
  if (!decimation_note.empty()) out << "; " << decimation_note;
  out << "): volume " << fixed(volume_m3 * 1e6, 2) << " ml";
  if (const std::optional<double> change = volumeChange())
    out << " against " << fixed(*input_volume_m3 * 1e6, 2) << " ml (" << (*change >= 0 ? "+" : "")
        << fixed(100 * *change, 2) << " %)";
  else
    out << " (the input's own volume is undefined: it was not closed)";
  if (pieces_dropped_volume_m3 > 0) {
    std::ostringstream dropped;
    dropped << std::setprecision(2) << pieces_dropped_volume_m3 * 1e6;
    out << ", loose pieces enclosing " << dropped.str() << " ml dropped";
  }
  out << ", every vertex within " << fixed(max_distance_to_input_m * 1e3, 2) << " mm of the input, the input within "
      << fixed(max_input_distance_m * 1e3, 2) << " mm of it";
  return out.str();
}

double levelSetVoxelFor(const TriangleMesh& mesh, long target_triangles) {
  std::vector<double> edges;
  edges.reserve(static_cast<std::size_t>(3 * mesh.triangleCount()));
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k) {
      const double length = (mesh.vertices.col(mesh.triangles(k, t)) - mesh.vertices.col(mesh.triangles((k + 1) % 3, t))).norm();
      if (length > 0) edges.push_back(length);
    }
  if (edges.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(edges.begin(), edges.begin() + static_cast<std::ptrdiff_t>(edges.size() / 2), edges.end());
  double voxel = 0.5 * edges[edges.size() / 2];
  const AlignedBox box = boundsOf(mesh.vertices);
  const double thinnest = (box.max - box.min).minCoeff();
  if (thinnest > 0) voxel = std::min(voxel, thinnest / kMinVoxelsAcross);
  const double area = surfaceArea(mesh);
  if (isClosedOrientedChain(mesh) && area > 0) {
    const double thickness = std::abs(enclosedVolume(mesh)) / area;  // a plate's half thickness, a third of a ball's radius
    if (thickness > 0) voxel = std::min(voxel, thickness / kVoxelsPerThickness);
  }
  // An iso-surface has about two triangles per voxel face of surface.
  const double max_iso_triangles = std::max(kMinIsoTriangles, kIsoTrianglesPerTarget * static_cast<double>(target_triangles));
  return std::max({voxel, std::sqrt(2.0 * area / max_iso_triangles),
                   std::sqrt(2.0 * kHalfBandVoxels * area / kMaxBandVoxels)});
}

namespace {

// The largest distances between two surfaces: from a vertex of `from` to `to`'s triangles.
double largestDistance(const TriangleMesh& from, const SurfaceDistance& to) {
  std::vector<bool> used(static_cast<std::size_t>(from.vertexCount()), false);
  for (Eigen::Index t = 0; t < from.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k) used[static_cast<std::size_t>(from.triangles(k, t))] = true;
  double largest = 0;
  for (Eigen::Index v = 0; v < from.vertexCount(); ++v)
    if (used[static_cast<std::size_t>(v)]) largest = std::max(largest, to.distance(from.vertices.col(v)));
  return largest;
}

// A mesh's vertices in voxel units and its triangles, as OpenVDB takes them.
struct VoxelMesh {
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  VoxelMesh(const TriangleMesh& mesh, double voxel) {
    points.reserve(static_cast<std::size_t>(mesh.vertexCount()));
    for (Eigen::Index v = 0; v < mesh.vertexCount(); ++v)
      points.emplace_back(static_cast<float>(mesh.vertices(0, v) / voxel), static_cast<float>(mesh.vertices(1, v) / voxel),
                          static_cast<float>(mesh.vertices(2, v) / voxel));
    triangles.reserve(static_cast<std::size_t>(mesh.triangleCount()));
    for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
      triangles.emplace_back(static_cast<unsigned>(mesh.triangles(0, t)), static_cast<unsigned>(mesh.triangles(1, t)),
                             static_cast<unsigned>(mesh.triangles(2, t)));
  }
};

// What a decimated surface must stay close to: the input (a rebuild keeps the input's shape) or the iso-surface as
// extracted (a carve changes the input's shape on purpose; decimating must not undo it).
enum class DecimationReference { input, iso_surface };

// The zero iso-surface of `grid` (metres = voxel units x report.voxel_m) as one closed, outward-wound piece (the
// largest; what the others enclosed is reported), decimated to about `target_triangles` while it stays within a voxel
// of the reference and leaves out no more of it than the iso-surface did plus a voxel. The report's distances are to
// `mesh`, the input.
TriangleMesh closedDecimatedSurface(const openvdb::FloatGrid& grid, const TriangleMesh& mesh, long target_triangles,
                                    long max_factor, DecimationReference kept_close_to,
                                    LevelSetRebuildReport& report) {
  TriangleMesh surface = isoSurface(grid);
  surface.vertices *= report.voxel_m;  // back from voxel units to metres
  if (surface.triangleCount() == 0)
    throw NoEnclosedVolumeError("its " + std::to_string(mesh.triangleCount()) + " triangles enclose no volume at a " +
                                fixed(report.voxel_m * 1e3, 3) + " mm voxel: the level set of their distance field "
                                "has no surface");
  report.iso_surface_triangles = static_cast<long>(surface.triangleCount());

  // One closed piece: the one enclosing most; what the others enclosed is reported.
  const std::vector<std::vector<Eigen::Index>> parts = pieces(surface);
  std::size_t largest = 0;
  std::vector<double> volumes;
  for (std::size_t p = 0; p < parts.size(); ++p) {
    volumes.push_back(std::abs(enclosedVolume(subset(surface, parts[p]))));
    if (volumes[p] > volumes[largest]) largest = p;
  }
  for (std::size_t p = 0; p < parts.size(); ++p)
    if (p != largest) report.pieces_dropped_volume_m3 += volumes[p];
  if (parts.size() > 1) surface = subset(surface, parts[largest]);
  if (enclosedVolume(surface) < 0)
    for (Eigen::Index t = 0; t < surface.triangleCount(); ++t) std::swap(surface.triangles(1, t), surface.triangles(2, t));
  if (!(enclosedVolume(surface) > 0))
    throw NoEnclosedVolumeError("its " + std::to_string(mesh.triangleCount()) + " triangles enclose no volume at a " +
                                fixed(report.voxel_m * 1e3, 3) + " mm voxel");

  const TriangleMesh reference = kept_close_to == DecimationReference::input ? mesh : surface;
  const SurfaceDistance to_input(reference.vertices, reference.triangles);
  double iso_to_reference = largestDistance(surface, to_input);
  double reference_to_iso = largestDistance(reference, SurfaceDistance(surface.vertices, surface.triangles));

  // Decimated to about the count asked for. Quadric decimation checks no topology and minds no distance to the input,
  // so a result is taken only when it is a closed 2-manifold that does not cross itself, within a voxel of the input
  // and leaves out no more of it than the iso-surface did plus a voxel; otherwise twice the count is taken, and so on
  // up to `max_factor` times, before the iso-surface is kept as it is. (A 242-triangle OpenSim pelvis: at its own count the
  // decimation moved the surface 1.3 mm at a 1 mm voxel.) The iso-surface is decimated once, to the largest count, and
  // each smaller one from the one before: decimating 170,000 triangles takes seconds, 2,000 milliseconds.
  if (target_triangles > 0 && surface.triangleCount() > target_triangles + target_triangles / 10) {
    std::vector<std::pair<long, TriangleMesh>> candidates;  // largest count first
    for (long factor = max_factor; factor >= 1; factor /= 2) {
      const long target = factor * target_triangles;
      if (target >= surface.triangleCount()) continue;
      candidates.emplace_back(target, decimated(candidates.empty() ? surface : candidates.back().second, target));
    }
    std::string why;
    bool done = false;
    for (auto candidate = candidates.rbegin(); candidate != candidates.rend() && !done; ++candidate) {
      const TriangleMesh& decimated_surface = candidate->second;
      const bool first = candidate == candidates.rbegin();
      if (!isSound(decimated_surface)) {
        if (first) why = "broke the surface";
        continue;
      }
      const double to = largestDistance(decimated_surface, to_input);
      const double from =
          largestDistance(reference, SurfaceDistance(decimated_surface.vertices, decimated_surface.triangles));
      if (to > std::max(report.voxel_m, iso_to_reference) || from > reference_to_iso + report.voxel_m) {
        if (first) why = "moved the surface " + fixed(1e3 * std::max(to, from), 2) + " mm";
        continue;
      }
      if (!first)
        report.decimation_note = "decimation to " + std::to_string(target_triangles) + " triangles " + why +
                                 ", so to " + std::to_string(candidate->first);
      iso_to_reference = to;
      reference_to_iso = from;
      surface = decimated_surface;
      done = true;
    }
    if (!done)
      report.decimation_note = "decimation towards " + std::to_string(target_triangles) + " triangles " +
                               (why.empty() ? "left too few" : why) + ", so the iso-surface is kept as extracted";
  }
  if (kept_close_to == DecimationReference::input) {
    report.max_distance_to_input_m = iso_to_reference;
    report.max_input_distance_m = reference_to_iso;
  } else {
    report.max_distance_to_input_m = largestDistance(surface, SurfaceDistance(mesh.vertices, mesh.triangles));
    report.max_input_distance_m = largestDistance(mesh, SurfaceDistance(surface.vertices, surface.triangles));
  }
  report.triangles = static_cast<long>(surface.triangleCount());
  report.volume_m3 = enclosedVolume(surface);
  return surface;
}

}  // namespace

TriangleMesh rebuildFromLevelSet(const TriangleMesh& mesh, long target_triangles, LevelSetRebuildReport& report,
                                 double voxel_m) {
  report = LevelSetRebuildReport{};
  if (!mesh.vertices.allFinite()) throw std::invalid_argument("the surface has a vertex that is not a finite number");
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k)
      if (mesh.triangles(k, t) < 0 || mesh.triangles(k, t) >= mesh.vertexCount())
        throw std::invalid_argument("triangle " + std::to_string(t) + " refers to vertex " +
                                    std::to_string(mesh.triangles(k, t)) + ", which does not exist");
  report.input_triangles = static_cast<long>(mesh.triangleCount());
  if (isClosedOrientedChain(mesh)) report.input_volume_m3 = enclosedVolume(mesh);
  report.voxel_m = voxel_m > 0 ? voxel_m : levelSetVoxelFor(mesh, target_triangles);
  if (!(report.voxel_m > 0))
    throw NoEnclosedVolumeError("its " + std::to_string(mesh.triangleCount()) +
                                " triangles have no extent (every edge has zero length)");

  initialiseOpenVdbOnce();
  // The grid is built in voxel units (a unit transform, the vertices divided by the voxel): OpenVDB refuses a transform
  // whose scale it takes for zero ("Non-zero scale values required"), which a millimetre-sized part in metres reaches
  // (VoxelMesh).
  //
  // The inside must reach deeper than the voxels the triangles cut: OpenVDB signs those from the nearest triangle, so a
  // sheet or a fin gets a skin of "inside" voxels a voxel thick on one side (a flat sheet of three triangles gave a
  // shell of 10,000 triangles). A real volume thinner than that at the first voxel is tried again at half of it, twice.
  openvdb::FloatGrid::Ptr grid;
  double deepest_voxels = 0;
  for (int attempt = 0; attempt < 3; ++attempt) {
    if (attempt > 0) report.voxel_m *= 0.5;
    const VoxelMesh voxels(mesh, report.voxel_m);
    const auto transform = openvdb::math::Transform::createLinearTransform(1.0);
    grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*transform, voxels.points, voxels.triangles,
                                                              kHalfBandVoxels);
    float deepest = 0;
    for (auto value = grid->tree().cbeginValueAll(); value; ++value) deepest = std::min(deepest, *value);
    deepest_voxels = -deepest;  // in voxels: the grid's unit
    if (deepest_voxels > kMinDepthVoxels) break;
  }
  if (!(deepest_voxels > kMinDepthVoxels))
    throw NoEnclosedVolumeError("its " + std::to_string(mesh.triangleCount()) + " triangles enclose no volume: the " +
                                "level set of their distance field has no inside deeper than " +
                                fixed(deepest_voxels, 1) + " voxels of " + fixed(report.voxel_m * 1e3, 3) +
                                " mm (a sheet, a fin, or an open surface whose outside reaches in)");

  return closedDecimatedSurface(*grid, mesh, target_triangles, kRebuildMaxFactor, DecimationReference::input, report);
}

TriangleMesh carvedFromLevelSet(const TriangleMesh& mesh, const std::vector<TriangleMesh>& cutters, double clearance_m,
                                double voxel_m, long target_triangles, LevelSetRebuildReport& report) {
  report = LevelSetRebuildReport{};
  if (!(voxel_m > 0) || !std::isfinite(voxel_m)) throw std::invalid_argument("the carve's voxel must be positive");
  if (!(clearance_m >= 0) || !std::isfinite(clearance_m))
    throw std::invalid_argument("the carve's clearance must be zero or positive");
  if (!checkSurfaceTopology(mesh).closedManifold())
    throw std::invalid_argument("the surface to carve is not a closed 2-manifold");
  for (const TriangleMesh& cutter : cutters)
    if (!checkSurfaceTopology(cutter).closedManifold())
      throw std::invalid_argument("a surface to carve with is not a closed 2-manifold");
  report.input_triangles = static_cast<long>(mesh.triangleCount());
  report.input_volume_m3 = std::abs(enclosedVolume(mesh));
  report.voxel_m = voxel_m;
  initialiseOpenVdbOnce();
  const auto transform = openvdb::math::Transform::createLinearTransform(1.0);  // voxel units (VoxelMesh)
  // The carved surface's distance field everywhere inside: a cutter reaching deep into it must reach its inactive
  // interior too, which a narrow band leaves at one value.
  const VoxelMesh carved(mesh, voxel_m);
  openvdb::FloatGrid::Ptr grid = openvdb::tools::meshToSignedDistanceField<openvdb::FloatGrid>(
      *transform, carved.points, carved.triangles, std::vector<openvdb::Vec4I>(), kHalfBandVoxels,
      std::numeric_limits<float>::max());
  const float clearance = static_cast<float>(clearance_m / voxel_m);
  for (const TriangleMesh& cutter : cutters) {
    // Its narrow band reaches beyond the clearance; deeper inside, the band's inactive value (negative) still says
    // "inside", which is all the difference needs there.
    const VoxelMesh voxels(cutter, voxel_m);
    const openvdb::FloatGrid::Ptr cut = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(
        *transform, voxels.points, voxels.triangles, kHalfBandVoxels + clearance + 1.0f);
    const auto cut_values = cut->getConstAccessor();
    // bone minus (cutter grown by the clearance): max(bone, clearance - cutter), voxel by voxel.
    for (auto voxel = grid->beginValueOn(); voxel; ++voxel) {
      const float grown = clearance - cut_values.getValue(voxel.getCoord());
      if (grown > *voxel) voxel.setValue(grown);
    }
  }
  return closedDecimatedSurface(*grid, mesh, target_triangles, kCarveMaxFactor, DecimationReference::iso_surface,
                                report);
}

}  // namespace muscle_deformation
