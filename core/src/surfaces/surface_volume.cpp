#include "muscle_deformation/core/surfaces/surface_volume.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace muscle_deformation {

std::string validate(const SurfaceVolumeSettings& settings) {
  if (settings.max_rounds < 1) return "max_rounds must be >= 1";
  if (!(settings.tolerance_fraction > 0) || !std::isfinite(settings.tolerance_fraction))
    return "tolerance_fraction must be a positive number";
  return {};
}

namespace {

// Moves shorter than this many voxels of the finest bone field are not checked against the bones (the field is exact
// at voxel centres only, to about half a voxel in between).
constexpr double kUncheckedTravelVoxels = 0.25;

// Six times the signed enclosed volume and its gradient (times six) at every vertex, about `centre` (so that far from
// the origin the triple products do not lose digits).
double sixTimesVolume(const Vertices& vertices, const Triangles& triangles, const Eigen::Vector3d& centre,
                      Eigen::Matrix3Xd& gradient) {
  gradient.setZero(3, vertices.cols());
  double six_volume = 0;
  for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
    const int a = triangles(0, t), b = triangles(1, t), c = triangles(2, t);
    const Eigen::Vector3d pa = vertices.col(a) - centre, pb = vertices.col(b) - centre, pc = vertices.col(c) - centre;
    const Eigen::Vector3d bc = pb.cross(pc);
    six_volume += pa.dot(bc);
    gradient.col(a) += bc;
    gradient.col(b) += pc.cross(pa);
    gradient.col(c) += pa.cross(pb);
  }
  return six_volume;
}

// Six times the signed volume of the surface with every vertex moved by `offset` along its direction, as the cubic
// c[0] + c[1] offset + c[2] offset^2 + c[3] offset^3 (each triangle's triple product is a cubic in the offset).
std::array<double, 4> sixTimesVolumeAlong(const Vertices& vertices, const Eigen::Matrix3Xd& directions,
                                          const Triangles& triangles, const Eigen::Vector3d& centre) {
  std::array<double, 4> c{0, 0, 0, 0};
  for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
    const int a = triangles(0, t), b = triangles(1, t), k = triangles(2, t);
    const Eigen::Vector3d pa = vertices.col(a) - centre, pb = vertices.col(b) - centre, pc = vertices.col(k) - centre;
    const Eigen::Vector3d da = directions.col(a), db = directions.col(b), dc = directions.col(k);
    const Eigen::Vector3d pb_pc = pb.cross(pc), db_pc = db.cross(pc), pb_dc = pb.cross(dc), db_dc = db.cross(dc);
    c[0] += pa.dot(pb_pc);
    c[1] += da.dot(pb_pc) + pa.dot(db_pc + pb_dc);
    c[2] += pa.dot(db_dc) + da.dot(db_pc + pb_dc);
    c[3] += da.dot(db_dc);
  }
  return c;
}

// The root of c[0] - target + c[1] x + c[2] x^2 + c[3] x^3 nearest 0, by Newton from the linear estimate (the
// polynomial is monotone near 0 for any offset smaller than the surface's radius of curvature).
double offsetFor(const std::array<double, 4>& c, double target) {
  double x = c[1] != 0 ? (target - c[0]) / c[1] : 0.0;
  for (int i = 0; i < 20; ++i) {
    const double value = c[0] - target + x * (c[1] + x * (c[2] + x * c[3]));
    const double slope = c[1] + x * (2 * c[2] + 3 * x * c[3]);
    if (!(std::abs(slope) > 0)) break;
    const double step = value / slope;
    x -= step;
    if (std::abs(step) <= 1e-12 * (1 + std::abs(x))) break;
  }
  return x;
}

}  // namespace

SurfaceVolumeConstraint::SurfaceVolumeConstraint(const std::vector<Triangles>& triangles,
                                                 const std::vector<Vertices>& rest_vertices, BoneFields bone_fields,
                                                 SurfaceVolumeSettings settings)
    : triangles_(triangles), bone_fields_(std::move(bone_fields)), settings_(settings) {
  if (const std::string problem = validate(settings_); !problem.empty())
    throw std::invalid_argument("surface volume settings: " + problem);
  if (triangles.size() != rest_vertices.size())
    throw std::invalid_argument("surface volume: " + std::to_string(triangles.size()) + " triangle sets for " +
                                std::to_string(rest_vertices.size()) + " surfaces");
  for (std::size_t b = 0; b < bone_fields_.size(); ++b) {
    if (!bone_fields_[b]) throw std::invalid_argument("surface volume: bone " + std::to_string(b) + " has no field");
    const double resolution = kUncheckedTravelVoxels * bone_fields_[b]->voxel();
    unchecked_travel_m_ = b == 0 ? resolution : std::min(unchecked_travel_m_, resolution);
  }
  for (std::size_t m = 0; m < triangles.size(); ++m) {
    const double volume = enclosedVolume(rest_vertices[m], triangles[m]);
    if (!(std::abs(volume) > 0) || !std::isfinite(volume))
      throw std::invalid_argument("surface volume: muscle " + std::to_string(m) + " encloses no volume at rest");
    rest_volume_.push_back(std::abs(volume));
    winding_.push_back(volume > 0 ? 1.0 : -1.0);
  }
}

std::vector<SurfaceVolumeCorrection> SurfaceVolumeConstraint::apply(std::vector<Vertices>& surfaces,
                                                                    const BoneTransforms& bone_transforms,
                                                                    int threads) const {
  if (surfaces.size() != triangles_.size())
    throw std::invalid_argument("surface volume: " + std::to_string(surfaces.size()) + " surfaces for " +
                                std::to_string(triangles_.size()) + " muscles");
  // Each bone's world-to-rest transform and its reach in the world, once per frame.
  std::vector<Eigen::Isometry3d> to_bone_rest(bone_fields_.size(), Eigen::Isometry3d::Identity());
  std::vector<AlignedBox> bone_reach(bone_fields_.size());
  for (std::size_t b = 0; b < bone_fields_.size(); ++b) {
    const Eigen::Isometry3d pose = b < bone_transforms.size() ? bone_transforms[b] : Eigen::Isometry3d::Identity();
    to_bone_rest[b] = pose.inverse();
    bone_reach[b] = bone_fields_[b]->reachIn(pose);
  }
  std::vector<SurfaceVolumeCorrection> corrections(surfaces.size());
  // Muscles apart on the threads, largest share first by dynamic scheduling (each projects its own surface).
  const long muscle_count = static_cast<long>(surfaces.size());
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(dynamic, 1)
  for (long m = 0; m < muscle_count; ++m)
    corrections[static_cast<std::size_t>(m)] =
        project(static_cast<int>(m), surfaces[static_cast<std::size_t>(m)], to_bone_rest, bone_reach);
  return corrections;
}

SurfaceVolumeCorrection SurfaceVolumeConstraint::project(int muscle, Vertices& surface,
                                                         const std::vector<Eigen::Isometry3d>& to_bone_rest,
                                                         const std::vector<AlignedBox>& bone_reach) const {
  const std::size_t m = static_cast<std::size_t>(muscle);
  const Triangles& triangles = triangles_[m];
  const double rest = rest_volume_[m], winding = winding_[m];
  SurfaceVolumeCorrection correction;
  const Eigen::Index n = surface.cols();
  if (n == 0) return correction;
  const Eigen::Vector3d centre = surface.rowwise().mean();
  Eigen::Matrix3Xd directions;
  const double volume = winding * sixTimesVolume(surface, triangles, centre, directions) / 6.0;
  correction.volume_error_before_pct = correction.volume_error_after_pct = 100.0 * (volume - rest) / rest;
  if (std::abs(volume - rest) <= settings_.tolerance_fraction * rest) return correction;

  // Every vertex moves the same distance along its normal (the volume gradient's direction): with w_i = 1 / |grad_i V|
  // that is the PBD projection, and along fixed normals the volume is a cubic in the distance, solved exactly.
  for (Eigen::Index i = 0; i < n; ++i) {
    const double length = directions.col(i).norm();
    directions.col(i) = length > 0 ? Eigen::Vector3d(winding * directions.col(i) / length) : Eigen::Vector3d::Zero();
  }
  std::vector<BoneDistanceField::Probe> probes;
  probes.reserve(bone_fields_.size());
  for (const auto& field : bone_fields_) probes.push_back(field->probe());
  // Signed distance to the nearest bone the point is inside of (+infinity when it is inside none); one voxel read
  // proves most points outside.
  const auto insideDepth = [&](const Eigen::Vector3d& point) {
    double deepest = std::numeric_limits<double>::infinity();
    for (std::size_t b = 0; b < bone_fields_.size(); ++b) {
      const AlignedBox& box = bone_reach[b];
      if ((point.array() < box.min.array()).any() || (point.array() > box.max.array()).any()) continue;
      double distance = 0;
      Eigen::Vector3d unused;
      if (probes[b].closerThan(to_bone_rest[b] * point, 0.0, distance, unused)) deepest = std::min(deepest, distance);
    }
    return deepest;
  };

  double offset = 0;
  for (int round = 0; round < settings_.max_rounds; ++round) {
    const std::array<double, 4> cubic = sixTimesVolumeAlong(surface, directions, triangles, centre);
    offset = offsetFor(cubic, 6.0 * winding * rest);
    // A vertex the offset would put into a bone, or deeper into one it already is in (the bundled data put some there
    // at rest), keeps its place, and the others make up the volume in the next round. An offset below the fields'
    // resolution is not checked.
    int newly_held = 0;
    if (!bone_fields_.empty() && std::abs(offset) > unchecked_travel_m_) {
      for (Eigen::Index i = 0; i < n; ++i) {
        if (directions.col(i).isZero()) continue;
        const double after = insideDepth(surface.col(i) + offset * directions.col(i));
        if (after < 0 && after < insideDepth(surface.col(i))) {
          directions.col(i).setZero();
          ++newly_held;
        }
      }
    }
    correction.vertices_held_by_bone += newly_held;
    if (newly_held == 0) break;
  }
  int moved = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (directions.col(i).isZero()) continue;
    surface.col(i) += offset * directions.col(i);
    ++moved;
  }
  const double after = winding * enclosedVolume(surface, triangles);
  correction.volume_error_after_pct = 100.0 * (after - rest) / rest;
  correction.max_offset_m = moved > 0 ? std::abs(offset) : 0.0;
  correction.mean_offset_m = std::abs(offset) * moved / static_cast<double>(n);
  return correction;
}

}  // namespace muscle_deformation
