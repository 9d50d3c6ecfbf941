#include "muscle_deformation/support/synthetic_scene.hpp"

#include <cmath>
#include <map>
#include <stdexcept>
#include <tuple>

namespace muscle_deformation {

namespace {
constexpr double kPi = 3.14159265358979323846;

// Scene geometry (metres): hip centre at the origin, femur hanging along -z, knee 0.42 m below.
const Eigen::Vector3d kHipCentre(0, 0, 0);
const Eigen::Vector3d kKneeCentre(0, 0, -0.42);

// Orthonormal frame with w along `axis`.
void frameAlong(const Eigen::Vector3d& axis, Eigen::Vector3d& u, Eigen::Vector3d& v, Eigen::Vector3d& w) {
  w = axis.normalized();
  const Eigen::Vector3d helper = std::abs(w.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  u = w.cross(helper).normalized();
  v = w.cross(u);
}

// A closed tube: `rings` + 1 circles of `segments` vertices, radius given per ring, capped by one centre vertex at
// each end. Outward winding.
TriangleMesh makeTube(const Eigen::Vector3d& bottom, const Eigen::Vector3d& top, int segments, int rings,
                      const std::function<Eigen::Vector2d(double)>& radii) {
  Eigen::Vector3d u, v, w;
  frameAlong(top - bottom, u, v, w);
  TriangleMesh mesh;
  const int ring_vertices = segments;
  mesh.vertices.resize(3, (rings + 1) * ring_vertices + 2);
  for (int r = 0; r <= rings; ++r) {
    const double t = static_cast<double>(r) / rings;
    const Eigen::Vector2d radius = radii(t);
    const Eigen::Vector3d centre = bottom + t * (top - bottom);
    for (int s = 0; s < segments; ++s) {
      const double angle = 2 * kPi * s / segments;
      mesh.vertices.col(r * ring_vertices + s) = centre + radius.x() * std::cos(angle) * u + radius.y() * std::sin(angle) * v;
    }
  }
  const int bottom_cap = (rings + 1) * ring_vertices;
  const int top_cap = bottom_cap + 1;
  mesh.vertices.col(bottom_cap) = bottom;
  mesh.vertices.col(top_cap) = top;
  std::vector<Eigen::Vector3i> triangles;
  for (int r = 0; r < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      const int a = r * ring_vertices + s, b = r * ring_vertices + (s + 1) % segments;
      const int c = a + ring_vertices, d = b + ring_vertices;
      triangles.emplace_back(a, b, d);
      triangles.emplace_back(a, d, c);
    }
  for (int s = 0; s < segments; ++s) {
    triangles.emplace_back(bottom_cap, (s + 1) % segments, s);
    triangles.emplace_back(top_cap, rings * ring_vertices + s, rings * ring_vertices + (s + 1) % segments);
  }
  mesh.triangles.resize(3, static_cast<Eigen::Index>(triangles.size()));
  for (std::size_t t = 0; t < triangles.size(); ++t) mesh.triangles.col(static_cast<Eigen::Index>(t)) = triangles[t];
  return mesh;
}
}  // namespace

TriangleMesh makeCylinderMesh(const Eigen::Vector3d& bottom_centre, const Eigen::Vector3d& top_centre, double radius,
                              int segments, int rings) {
  return makeTube(bottom_centre, top_centre, segments, rings, [radius](double) { return Eigen::Vector2d(radius, radius); });
}

TriangleMesh makeSphereMesh(const Eigen::Vector3d& centre, double radius, int subdivisions) {
  // Icosahedron, then each subdivision splits every triangle in four and projects the new vertices to the sphere.
  const double g = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> vertices = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                                           {0, -1, -g}, {0, 1, -g}, {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
  for (auto& vertex : vertices) vertex.normalize();
  std::vector<Eigen::Vector3i> faces = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                        {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                        {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                        {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (int level = 0; level < subdivisions; ++level) {
    std::map<std::pair<int, int>, int> midpoint;
    auto middle = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      const auto it = midpoint.find(key);
      if (it != midpoint.end()) return it->second;
      vertices.push_back((vertices[a] + vertices[b]).normalized());
      return midpoint[key] = static_cast<int>(vertices.size()) - 1;
    };
    std::vector<Eigen::Vector3i> finer;
    for (const auto& f : faces) {
      const int ab = middle(f[0], f[1]), bc = middle(f[1], f[2]), ca = middle(f[2], f[0]);
      finer.insert(finer.end(), {{f[0], ab, ca}, {f[1], bc, ab}, {f[2], ca, bc}, {ab, bc, ca}});
    }
    faces.swap(finer);
  }
  TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(vertices.size()));
  for (std::size_t i = 0; i < vertices.size(); ++i) mesh.vertices.col(static_cast<Eigen::Index>(i)) = centre + radius * vertices[i];
  mesh.triangles.resize(3, static_cast<Eigen::Index>(faces.size()));
  for (std::size_t i = 0; i < faces.size(); ++i) mesh.triangles.col(static_cast<Eigen::Index>(i)) = faces[i];
  return mesh;
}

TriangleMesh makeBoxMesh(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double max_edge_m) {
  // Each face is a grid of quads split in two; vertices on shared box edges are welded by their grid coordinates.
  Eigen::Vector3i cells;
  for (int axis = 0; axis < 3; ++axis)
    cells[axis] = max_edge_m > 0 ? std::max(1, static_cast<int>(std::ceil((hi[axis] - lo[axis]) / max_edge_m))) : 1;
  std::map<std::tuple<int, int, int>, int> vertex_of;
  std::vector<Eigen::Vector3d> vertices;
  auto vertex = [&](const Eigen::Vector3i& grid) {
    const auto key = std::make_tuple(grid.x(), grid.y(), grid.z());
    const auto it = vertex_of.find(key);
    if (it != vertex_of.end()) return it->second;
    vertices.push_back(lo + (hi - lo).cwiseProduct(grid.cast<double>().cwiseQuotient(cells.cast<double>())));
    return vertex_of[key] = static_cast<int>(vertices.size()) - 1;
  };
  std::vector<Eigen::Vector3i> triangles;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;  // (u, v, axis) is right-handed
      for (int i = 0; i < cells[u]; ++i)
        for (int j = 0; j < cells[v]; ++j) {
          Eigen::Vector3i corner[4];
          for (int c = 0; c < 4; ++c) {
            corner[c][axis] = side * cells[axis];
            corner[c][u] = i + (c == 1 || c == 2);
            corner[c][v] = j + (c >= 2);
          }
          const int a = vertex(corner[0]), b = vertex(corner[1]), c = vertex(corner[2]), d = vertex(corner[3]);
          // u x v points along +axis: counter-clockwise (a, b, c, d) faces +axis, so flip on the low side.
          if (side == 1) {
            triangles.emplace_back(a, b, c);
            triangles.emplace_back(a, c, d);
          } else {
            triangles.emplace_back(a, c, b);
            triangles.emplace_back(a, d, c);
          }
        }
    }
  TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(vertices.size()));
  for (std::size_t i = 0; i < vertices.size(); ++i) mesh.vertices.col(static_cast<Eigen::Index>(i)) = vertices[i];
  mesh.triangles.resize(3, static_cast<Eigen::Index>(triangles.size()));
  for (std::size_t t = 0; t < triangles.size(); ++t) mesh.triangles.col(static_cast<Eigen::Index>(t)) = triangles[t];
  return mesh;
}

Muscle makeSpindleMuscle(const std::string& name, const Eigen::Vector3d& bottom, const Eigen::Vector3d& top,
                         double peak_radius, double aspect, int fibres_per_side, int fibre_points, int segments,
                         int rings) {
  if (fibres_per_side < 1 || fibre_points < 2) throw std::invalid_argument("spindle muscle: need fibres and points");
  auto profile = [peak_radius](double t) { return peak_radius * (0.35 + 0.65 * std::sin(kPi * t)); };
  Muscle muscle;
  muscle.name = name;
  muscle.surface = makeTube(bottom, top, segments, rings, [&](double t) {
    return Eigen::Vector2d(profile(t), aspect * profile(t));
  });
  Eigen::Vector3d u, v, w;
  frameAlong(top - bottom, u, v, w);
  // Grid across the cross-section, inside the ellipse: square of half-width 0.6 of the radius.
  for (int row = 0; row < fibres_per_side; ++row)
    for (int column = 0; column < fibres_per_side; ++column) {
      const double a = fibres_per_side == 1 ? 0.0 : -0.6 + 1.2 * row / (fibres_per_side - 1);
      const double b = fibres_per_side == 1 ? 0.0 : -0.6 + 1.2 * column / (fibres_per_side - 1);
      Polyline fibre(3, fibre_points);
      for (int k = 0; k < fibre_points; ++k) {
        const double t = static_cast<double>(k) / (fibre_points - 1);
        fibre.col(k) = bottom + t * (top - bottom) + profile(t) * (a * u + aspect * b * v);
      }
      muscle.fibres.push_back(fibre);
    }
  return muscle;
}

SyntheticScene makeSyntheticThigh(int muscle_count, int fibres_per_side) {
  SyntheticScene scene;
  const double femur_radius = 0.014;
  scene.bones.push_back({0, "pelvis", makeBoxMesh({-0.08, -0.12, 0.02}, {0.08, 0.12, 0.08}, 0.006)});
  // Rings as far apart as the segments around, so triangles are near equilateral: the one-ring bone-sphere heuristic
  // sizes spheres by the longest edge and would otherwise make spheres far larger than the bone.
  const int segments = 24;
  const double edge = 2 * kPi * femur_radius / segments;
  const auto rings = [edge](double length) { return static_cast<int>(std::ceil(length / edge)); };
  scene.bones.push_back({1, "femur", makeCylinderMesh(kKneeCentre, kHipCentre, femur_radius, segments, rings(0.42))});
  scene.bones.push_back({2, "tibia", makeCylinderMesh(kKneeCentre + Eigen::Vector3d(0, 0, -0.40),
                                                      kKneeCentre + Eigen::Vector3d(0, 0, -0.02), femur_radius, segments,
                                                      rings(0.38))});
  // Muscles on two rings around the femur, running from just below the pelvis to just above the tibia's top, so
  // that their fibre ends attach to pelvis and tibia and the femur pushes against them.
  const double peak_radius = 0.011;
  for (int m = 0; m < muscle_count; ++m) {
    const bool inner = m % 2 == 0;
    const double ring = inner ? femur_radius + peak_radius + 0.002 : femur_radius + 3 * peak_radius + 0.006;
    const double angle = 2 * kPi * m / muscle_count + (inner ? 0.0 : kPi / muscle_count);
    const Eigen::Vector3d offset(ring * std::cos(angle), ring * std::sin(angle), 0);
    scene.muscles.push_back(makeSpindleMuscle("muscle_" + std::to_string(m), kKneeCentre + Eigen::Vector3d(0, 0, -0.05) + offset,
                                              Eigen::Vector3d(0, 0, 0.019) + offset, peak_radius, 0.8, fibres_per_side));
  }
  return scene;
}

Pose syntheticThighPose(double hip_flexion_rad, double knee_flexion_rad) {
  // Rotation about +y by a positive angle swings -z (the thigh) towards -x; hip flexion moves the knee forward (+x).
  const Eigen::Isometry3d hip = Eigen::Translation3d(kHipCentre) * Eigen::AngleAxisd(-hip_flexion_rad, Eigen::Vector3d::UnitY()) *
                                Eigen::Translation3d(-kHipCentre);
  const Eigen::Isometry3d knee = Eigen::Translation3d(kKneeCentre) *
                                 Eigen::AngleAxisd(knee_flexion_rad, Eigen::Vector3d::UnitY()) *
                                 Eigen::Translation3d(-kKneeCentre);
  Pose pose;
  pose.bone_transforms["pelvis"] = Eigen::Isometry3d::Identity();
  pose.bone_transforms["femur"] = hip;
  pose.bone_transforms["tibia"] = hip * knee;
  return pose;
}

}  // namespace muscle_deformation
