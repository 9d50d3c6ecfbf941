// The mean_value skinning's cage (a closed triangle mesh on the boundary particles) and mean value coordinates.
#include "muscle_deformation/core/surfaces/surface_cage.hpp"

extern "C" {
#include <libqhull_r/qhull_ra.h>
}

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numeric>

namespace muscle_deformation {

std::string toString(CageKind kind) {
  switch (kind) {
    case CageKind::fibre_tube: return "fibre_tube";
    case CageKind::convex_hull: return "convex_hull";
  }
  return "unknown";
}

CageKind cageKindFromString(const std::string& name) {
  for (CageKind kind : {CageKind::fibre_tube, CageKind::convex_hull})
    if (toString(kind) == name) return kind;
  throw std::invalid_argument("unknown cage kind '" + name + "' (expected fibre_tube or convex_hull)");
}

namespace {


std::string muscleLabel(const MassSpringSystem& system, int muscle) {
  return "muscle '" + (muscle < system.muscleCount() ? system.muscle_name[muscle] : std::to_string(muscle)) + "'";
}

// Makes the triangles wind outwards (positive enclosed volume).
void windOutwards(TriangleMesh& mesh) {
  if (enclosedVolume(mesh) < 0) mesh.triangles.row(1).swap(mesh.triangles.row(2));
}

// Convex hull of the given muscle-local particles; triangles from qhull's triangulated output ("Qt").
ParticleCage convexHullCage(const Eigen::Matrix3Xd& rest, const std::vector<std::int32_t>& candidates,
                            const std::string& label) {
  const int count = static_cast<int>(candidates.size());
  if (count < 4) throw SkinningError(label + ": a cage needs at least 4 particles, got " + std::to_string(count));
  std::vector<coordT> coordinates(3 * static_cast<std::size_t>(count));
  for (int i = 0; i < count; ++i)
    for (int d = 0; d < 3; ++d) coordinates[3 * i + d] = rest(d, candidates[i]);

  qhT qh_storage;
  qhT* qh = &qh_storage;
  QHULL_LIB_CHECK
  qh_zero(qh, stderr);
  char options[] = "qhull Qt";
  FILE* quiet = std::fopen("/dev/null", "w");  // qhull's own messages; failures become an exception below
  const int status = qh_new_qhull(qh, 3, count, coordinates.data(), False, options, nullptr, quiet ? quiet : stderr);
  std::vector<Eigen::Vector3i> triangles;
  std::map<int, int> vertex_of_point;  // qhull point id -> cage vertex
  if (status == 0) {
    facetT* facet;
    vertexT* vertex;
    vertexT** vertexp;
    FORALLfacets {
      int corner[3], point_id[3];
      int corners = 0;
      FOREACHvertex_(facet->vertices) {
        const int id = qh_pointid(qh, vertex->point);
        if (corners < 3) {
          point_id[corners] = id;
          corner[corners++] = vertex_of_point.try_emplace(id, static_cast<int>(vertex_of_point.size())).first->second;
        }
      }
      if (corners != 3) continue;
      // qhull stores the outward normal; wind each triangle to agree with it (works for flat triangles too).
      Eigen::Vector3d p[3];
      for (int k = 0; k < 3; ++k) p[k] = rest.col(candidates[point_id[k]]);
      const Eigen::Vector3d normal(facet->normal[0], facet->normal[1], facet->normal[2]);
      if ((p[1] - p[0]).cross(p[2] - p[0]).dot(normal) < 0) std::swap(corner[1], corner[2]);
      triangles.emplace_back(corner[0], corner[1], corner[2]);
    }
  }
  qh_freeqhull(qh, !qh_ALL);
  int current_long = 0, total_long = 0;
  qh_memfreeshort(qh, &current_long, &total_long);
  if (quiet) std::fclose(quiet);
  if (status != 0 || triangles.empty())
    throw SkinningError(label + ": convex hull of the boundary particles failed (qhull exit code " +
                        std::to_string(status) + "): the particles may be coplanar");

  ParticleCage cage;
  cage.kind = CageKind::convex_hull;
  cage.particle.resize(vertex_of_point.size());
  cage.mesh.vertices.resize(3, static_cast<Eigen::Index>(vertex_of_point.size()));
  for (const auto& [point, v] : vertex_of_point) {
    cage.particle[v] = candidates[point];
    cage.mesh.vertices.col(v) = rest.col(candidates[point]);
  }
  cage.mesh.triangles.resize(3, static_cast<Eigen::Index>(triangles.size()));
  for (std::size_t t = 0; t < triangles.size(); ++t) cage.mesh.triangles.col(static_cast<Eigen::Index>(t)) = triangles[t];
  windOutwards(cage.mesh);
  return cage;
}

// 2-D convex hull, counter-clockwise (monotone chain).
std::vector<int> convexHull2d(const std::vector<Eigen::Vector2d>& points) {
  std::vector<int> order(points.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return points[a].x() < points[b].x() || (points[a].x() == points[b].x() && points[a].y() < points[b].y());
  });
  auto cross = [&](int o, int a, int b) {
    const Eigen::Vector2d u = points[a] - points[o], v = points[b] - points[o];
    return u.x() * v.y() - u.y() * v.x();
  };
  std::vector<int> hull;
  for (int pass = 0; pass < 2; ++pass) {  // lower chain, then upper chain
    const std::size_t start = hull.size();
    for (int i : order) {
      while (hull.size() >= start + 2 && cross(hull[hull.size() - 2], hull.back(), i) <= 0) hull.pop_back();
      hull.push_back(i);
    }
    hull.pop_back();  // the chain's last point starts the other chain
    std::reverse(order.begin(), order.end());
  }
  return hull;
}

// The fibres on the outline of the cross-section, in order around it: every fibre within `band` of the convex
// hull's boundary, sorted by where it projects onto that boundary. The band keeps the whole outer row of a fibre
// grid whose fibres were jittered by sampling, not only the few that happen to be extreme.
std::vector<int> outlineRing(const std::vector<Eigen::Vector2d>& points, double band) {
  const std::vector<int> hull = convexHull2d(points);
  if (hull.size() < 3) return {};
  std::vector<double> arc_start(hull.size() + 1, 0.0);
  for (std::size_t e = 0; e < hull.size(); ++e)
    arc_start[e + 1] = arc_start[e] + (points[hull[(e + 1) % hull.size()]] - points[hull[e]]).norm();
  std::vector<std::pair<double, int>> kept;  // (position along the outline, point)
  for (int i = 0; i < static_cast<int>(points.size()); ++i) {
    double best_distance = std::numeric_limits<double>::infinity(), best_position = 0;
    for (std::size_t e = 0; e < hull.size(); ++e) {
      const Eigen::Vector2d a = points[hull[e]], b = points[hull[(e + 1) % hull.size()]];
      const double length2 = (b - a).squaredNorm();
      const double t = length2 > 0 ? std::clamp((points[i] - a).dot(b - a) / length2, 0.0, 1.0) : 0.0;
      const double distance = (a + t * (b - a) - points[i]).norm();
      if (distance < best_distance) best_distance = distance, best_position = arc_start[e] + t * std::sqrt(length2);
    }
    if (best_distance <= band) kept.emplace_back(best_position, i);
  }
  std::sort(kept.begin(), kept.end());
  std::vector<int> ring;
  for (const auto& [position, i] : kept) ring.push_back(i);
  return ring;
}

// The outermost boundary fibres, ordered around the muscle, joined sample by sample into a tube; each end closed by
// a fan from the end particle nearest the middle of the ring's end. Returns false when the fibres do not allow it.
bool fibreTubeCage(const MassSpringSystem& system, int muscle, ParticleCage& cage) {
  const Eigen::Index begin = system.muscle_begin[muscle], end = system.muscle_begin[muscle + 1];
  struct Fibre {
    Eigen::Index first = 0, count = 0;
    bool boundary = false;
  };
  std::vector<Fibre> fibres;
  for (Eigen::Index i = begin; i < end; ++i) {
    if (system.fibre_of[i] == kTendonAnchor) continue;  // a tendon's bone end: no sample of any fibre
    if (i == begin || system.fibre_of[i] != system.fibre_of[i - 1]) fibres.push_back({i - begin, 0, false});
    fibres.back().count += 1;
    fibres.back().boundary = fibres.back().boundary || system.is_boundary[i];
  }
  std::vector<int> candidates;
  for (int f = 0; f < static_cast<int>(fibres.size()); ++f)
    if (fibres[f].boundary) candidates.push_back(f);
  if (candidates.size() < 3) {  // no boundary marking (e.g. a bare system): every fibre may be on the ring
    candidates.resize(fibres.size());
    std::iota(candidates.begin(), candidates.end(), 0);
  }
  if (candidates.size() < 3) return false;
  const Eigen::Index samples = fibres[candidates[0]].count;
  if (samples < 2) return false;
  for (const Fibre& fibre : fibres)
    if (fibre.count != samples) return false;

  // Cross-section plane: perpendicular to the mean fibre direction; fibres placed there by their mean position.
  const auto rest = system.rest_position.middleCols(begin, end - begin);
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();
  for (int f : candidates) {
    const Eigen::Vector3d direction = rest.col(fibres[f].first + samples - 1) - rest.col(fibres[f].first);
    if (direction.norm() > 0) axis += direction.normalized();
  }
  if (axis.norm() < 1e-9) return false;
  axis.normalize();
  const Eigen::Vector3d helper = std::abs(axis.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d e1 = axis.cross(helper).normalized(), e2 = axis.cross(e1);
  std::vector<Eigen::Vector2d> placed;
  for (int f : candidates) {
    const Eigen::Vector3d mean = rest.middleCols(fibres[f].first, samples).rowwise().mean();
    placed.emplace_back(mean.dot(e1), mean.dot(e2));
  }
  // Band: half the typical spacing between neighbouring fibres (the next row inwards is a whole spacing away).
  std::vector<double> spacing;
  for (std::size_t i = 0; i < placed.size(); ++i) {
    double nearest = std::numeric_limits<double>::infinity();
    for (std::size_t j = 0; j < placed.size(); ++j)
      if (j != i) nearest = std::min(nearest, (placed[i] - placed[j]).norm());
    spacing.push_back(nearest);
  }
  std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
  const std::vector<int> ring_index = outlineRing(placed, spacing[spacing.size() / 2] / 2);
  if (ring_index.size() < 3) return false;
  std::vector<int> ring;
  for (int k : ring_index) ring.push_back(candidates[k]);
  const int ring_size = static_cast<int>(ring.size());

  // Cage vertices: ring fibre r, sample s -> r * samples + s; then the two fan centres (if not on the ring).
  std::vector<std::int32_t> particle;
  for (int f : ring)
    for (Eigen::Index s = 0; s < samples; ++s) particle.push_back(static_cast<std::int32_t>(fibres[f].first + s));
  std::vector<Eigen::Vector3i> triangles;
  for (int r = 0; r < ring_size; ++r) {
    const int a0 = r * static_cast<int>(samples), b0 = ((r + 1) % ring_size) * static_cast<int>(samples);
    for (int s = 0; s + 1 < samples; ++s) {
      triangles.emplace_back(a0 + s, b0 + s, b0 + s + 1);
      triangles.emplace_back(a0 + s, b0 + s + 1, a0 + s + 1);
    }
  }
  for (int cap = 0; cap < 2; ++cap) {
    const Eigen::Index sample = cap == 0 ? 0 : samples - 1;
    Eigen::Vector3d middle = Eigen::Vector3d::Zero();
    for (int f : ring) middle += rest.col(fibres[f].first + sample);
    middle /= ring_size;
    // Fan centre: the end particle of a fibre off the ring nearest the middle, so the fan spreads from inside.
    int centre_fibre = -1;
    double best = std::numeric_limits<double>::infinity();
    for (int f = 0; f < static_cast<int>(fibres.size()); ++f) {
      if (std::find(ring.begin(), ring.end(), f) != ring.end()) continue;
      const double distance = (rest.col(fibres[f].first + sample) - middle).norm();
      if (distance < best) best = distance, centre_fibre = f;
    }
    auto corner = [&](int r) { return r * static_cast<int>(samples) + static_cast<int>(sample); };
    // The tube walks the start ring r -> r+1 and the end ring r+1 -> r; each cap goes the other way round.
    auto fan = [&](int centre, int a, int b) {
      if (cap == 0) triangles.emplace_back(centre, b, a);
      else triangles.emplace_back(centre, a, b);
    };
    if (centre_fibre >= 0) {
      const int centre = static_cast<int>(particle.size());
      particle.push_back(static_cast<std::int32_t>(fibres[centre_fibre].first + sample));
      for (int r = 0; r < ring_size; ++r) fan(centre, corner(r), corner((r + 1) % ring_size));
    } else {  // every fibre is on the ring: fan from the first ring fibre
      for (int r = 1; r + 1 < ring_size; ++r) fan(corner(0), corner(r), corner(r + 1));
    }
  }
  cage.kind = CageKind::fibre_tube;
  cage.particle = particle;
  cage.mesh.vertices.resize(3, static_cast<Eigen::Index>(particle.size()));
  for (std::size_t k = 0; k < particle.size(); ++k) cage.mesh.vertices.col(static_cast<Eigen::Index>(k)) = rest.col(particle[k]);
  cage.mesh.triangles.resize(3, static_cast<Eigen::Index>(triangles.size()));
  for (std::size_t t = 0; t < triangles.size(); ++t) cage.mesh.triangles.col(static_cast<Eigen::Index>(t)) = triangles[t];
  windOutwards(cage.mesh);
  return std::abs(enclosedVolume(cage.mesh)) > 0;
}

}  // namespace

ParticleCage buildParticleCage(const MassSpringSystem& system, int muscle, CageKind kind) {
  if (muscle < 0 || muscle + 1 >= static_cast<int>(system.muscle_begin.size()))
    throw SkinningError("cage: no muscle " + std::to_string(muscle) + " in the system");
  const std::string label = muscleLabel(system, muscle);
  ParticleCage cage;
  if (kind == CageKind::fibre_tube && fibreTubeCage(system, muscle, cage)) {
    // checked below like the hull
  } else {
    const Eigen::Index begin = system.muscle_begin[muscle], end = system.muscle_begin[muscle + 1];
    std::vector<std::int32_t> candidates;
    for (Eigen::Index i = begin; i < end; ++i)
      if (system.is_boundary[i]) candidates.push_back(static_cast<std::int32_t>(i - begin));
    if (candidates.size() < 4) {  // no boundary marking: the hull of all particles is the same hull
      candidates.resize(static_cast<std::size_t>(end - begin));
      std::iota(candidates.begin(), candidates.end(), 0);
    }
    cage = convexHullCage(system.rest_position.middleCols(begin, end - begin), candidates, label);
  }
  const SurfaceTopologyReport topology = checkSurfaceTopology(cage.mesh);
  if (!topology.closedManifold())
    throw SkinningError(label + ": the " + toString(cage.kind) + " cage is not a closed 2-manifold: " +
                        topology.describe());
  return cage;
}

Eigen::VectorXd meanValueCoordinates(const TriangleMesh& cage, const Eigen::Vector3d& point, bool* on_cage) {
  const Eigen::Index n = cage.vertexCount();
  Eigen::VectorXd weights = Eigen::VectorXd::Zero(n);
  if (on_cage) *on_cage = false;
  if (n == 0) return weights;
  // Relative tolerances: scale-free, so millimetre and metre models behave alike.
  const AlignedBox box = boundsOf(cage.vertices);
  const double size = (box.max - box.min).norm();
  const double epsilon = 1e-12;

  // Unit directions from the point to every cage corner, and the distances.
  Eigen::Matrix3Xd direction(3, n);
  Eigen::VectorXd distance(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Vector3d offset = cage.vertices.col(k) - point;
    distance[k] = offset.norm();
    if (distance[k] <= epsilon * size) {  // on a corner: that corner's value
      weights[k] = 1;
      if (on_cage) *on_cage = true;
      return weights;
    }
    direction.col(k) = offset / distance[k];
  }

  const double plane_tolerance = 1e-10 * size;
  for (Eigen::Index t = 0; t < cage.triangleCount(); ++t) {
    const int corner[3] = {cage.triangles(0, t), cage.triangles(1, t), cage.triangles(2, t)};
    const Eigen::Vector3d a = cage.vertices.col(corner[0]), b = cage.vertices.col(corner[1]),
                          c = cage.vertices.col(corner[2]);
    const Eigen::Vector3d normal = (b - a).cross(c - a);
    const double area2 = normal.norm();
    if (area2 <= 1e-14 * size * size) continue;  // a flat sliver subtends no solid angle
    if (std::abs(normal.dot(point - a)) <= plane_tolerance * area2) {
      // In the triangle's plane: on the triangle, the interpolant is linear there (barycentric coordinates); beside
      // it, the triangle is seen edge-on and contributes nothing.
      const double squared = area2 * area2;
      const double wa = (b - point).cross(c - point).dot(normal) / squared;
      const double wb = (c - point).cross(a - point).dot(normal) / squared;
      const double wc = 1 - wa - wb;
      if (std::min({wa, wb, wc}) >= -1e-12) {
        weights.setZero();
        weights[corner[0]] = wa;
        weights[corner[1]] = wb;
        weights[corner[2]] = wc;
        if (on_cage) *on_cage = true;
        return weights;
      }
      continue;
    }
    // The triangle projected on the unit sphere around the point. theta[i]: its side opposite corner i.
    double theta[3], side_sine[3];
    for (int i = 0; i < 3; ++i) {
      const double chord = (direction.col(corner[(i + 1) % 3]) - direction.col(corner[(i + 2) % 3])).norm();
      theta[i] = 2 * std::asin(std::min(1.0, chord / 2));
      side_sine[i] = std::sin(theta[i]);
    }
    if (std::min({side_sine[0], side_sine[1], side_sine[2]}) < 1e-12) continue;  // seen edge-on
    const double half_sum = (theta[0] + theta[1] + theta[2]) / 2;
    // Triple product of the unit directions = sin(side) sin(side) sin(angle) at any corner: gives the sine of each
    // corner angle accurately, with the orientation's sign, even for thin spherical triangles.
    const double triple =
        direction.col(corner[0]).dot(direction.col(corner[1]).cross(direction.col(corner[2])));
    double cosine[3], sine[3];
    for (int i = 0; i < 3; ++i) {
      const double adjacent = side_sine[(i + 1) % 3] * side_sine[(i + 2) % 3];
      cosine[i] = std::clamp(2 * std::sin(half_sum) * std::sin(half_sum - theta[i]) / adjacent - 1, -1.0, 1.0);
      sine[i] = triple / adjacent;
    }
    for (int i = 0; i < 3; ++i) {
      const int next = (i + 1) % 3, previous = (i + 2) % 3;
      weights[corner[i]] += (theta[i] - cosine[next] * theta[previous] - cosine[previous] * theta[next]) /
                            (distance[corner[i]] * side_sine[next] * sine[previous]);
    }
  }
  const double sum = weights.sum();
  if (sum != 0 && std::isfinite(sum)) weights /= sum;
  return weights;
}

}  // namespace muscle_deformation
