#include "muscle_deformation/core/surfaces/surface_volume.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

namespace muscle_deformation {

std::string validate(const SurfaceVolumeSettings& settings) {
  if (settings.max_projections < 1) return "max_projections must be >= 1";
  if (!(settings.tolerance_fraction > 0) || !std::isfinite(settings.tolerance_fraction))
    return "tolerance_fraction must be a positive number";
  return {};
}

namespace {

// Added to twice a vertex's first move when proving it far from the bones, so that the later, smaller projections of
// the same frame rarely need another look.
constexpr double kClearanceMarginM = 0.0005;
// Moves shorter than this many voxels of the finest bone field are not checked against the bones (the field is exact
// at voxel centres only, to about half a voxel in between).
constexpr double kUncheckedTravelVoxels = 0.25;

// Six times the signed enclosed volume and its gradient (times six) at every vertex, about the vertices' centroid (so
// that far from the origin the triple products do not lose digits).
double sixTimesVolume(const Vertices& vertices, const Triangles& triangles, Eigen::Matrix3Xd& gradient) {
  const Eigen::Vector3d centre = vertices.rowwise().mean();
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
  Eigen::Matrix3Xd gradient;
  for (std::size_t m = 0; m < triangles.size(); ++m) {
    const double volume = sixTimesVolume(rest_vertices[m], triangles[m], gradient) / 6.0;
    if (!(std::abs(volume) > 0) || !std::isfinite(volume))
      throw std::invalid_argument("surface volume: muscle " + std::to_string(m) + " encloses no volume at rest");
    rest_volume_.push_back(std::abs(volume));
    winding_.push_back(volume > 0 ? 1.0 : -1.0);
  }
}

std::vector<SurfaceVolumeCorrection> SurfaceVolumeConstraint::apply(std::vector<Vertices>& surfaces,
                                                                    const BoneTransforms& bone_transforms) const {
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
  // One thread: a few milliseconds for the bundled scene, and a parallel loop beside a busy core took three times as long
  // (its threads wait for the descheduled one).
  for (std::size_t m = 0; m < surfaces.size(); ++m)
    corrections[m] = project(static_cast<int>(m), surfaces[m], to_bone_rest, bone_reach);
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
  const Vertices start = surface;
  std::vector<char> held(static_cast<std::size_t>(n), 0);
  std::vector<BoneDistanceField::Probe> probes;
  probes.reserve(bone_fields_.size());
  for (const auto& field : bone_fields_) probes.push_back(field->probe());
  // How far `point` is from every bone at least (a lower bound, exact below `limit`); +infinity away from all bones.
  // Most points are proven farther than `limit` by one voxel read.
  const auto boneClearance = [&](const Eigen::Vector3d& point, double limit) {
    double nearest = std::numeric_limits<double>::infinity();
    for (std::size_t b = 0; b < bone_fields_.size(); ++b) {
      const AlignedBox& box = bone_reach[b];
      if ((point.array() < box.min.array()).any() || (point.array() > box.max.array()).any()) continue;
      double distance = 0;
      Eigen::Vector3d unused;
      probes[b].closerThan(to_bone_rest[b] * point, limit, distance, unused);
      nearest = std::min(nearest, distance);
    }
    return nearest;
  };
  // A vertex that stays within `clearance` of where it started cannot have entered a bone; only one that travels
  // farther is looked at where it lands.
  std::vector<double> clearance(static_cast<std::size_t>(n), -std::numeric_limits<double>::infinity());
  std::vector<char> clearance_known(static_cast<std::size_t>(n), 0);

  Eigen::Matrix3Xd gradient;
  for (int projection = 0; projection <= settings_.max_projections; ++projection) {
    const double volume = winding * sixTimesVolume(surface, triangles, gradient) / 6.0;
    if (projection == 0) correction.volume_error_before_pct = 100.0 * (volume - rest) / rest;
    correction.volume_error_after_pct = 100.0 * (volume - rest) / rest;
    const double excess = volume - rest;
    if (std::abs(excess) <= settings_.tolerance_fraction * rest || projection == settings_.max_projections) break;
    gradient *= winding / 6.0;
    // Each vertex weighs as much as its share of the surface (w_i = 1 / |grad_i V|, grad_i V being a third of the area
    // around it along its normal): every vertex then moves the same distance along its normal, whatever the sizes of
    // its triangles (with equal weights a vertex with large triangles around it, such as the centre of a cap, moves
    // centimetres while its neighbours move micrometres).
    double weight_sum = 0;
    for (Eigen::Index i = 0; i < n; ++i)
      if (!held[static_cast<std::size_t>(i)]) weight_sum += gradient.col(i).norm();
    if (!(weight_sum > 0)) break;
    const double offset = -excess / weight_sum;
    for (Eigen::Index i = 0; i < n; ++i) {
      const std::size_t v = static_cast<std::size_t>(i);
      const double length = gradient.col(i).norm();
      if (held[v] || !(length > 0)) continue;
      const Eigen::Vector3d moved = surface.col(i) + (offset / length) * gradient.col(i);
      if (!bone_fields_.empty()) {
        const double travel = (moved - start.col(i)).norm();
        // A move below the fields' resolution is not looked at: the projection puts no vertex deeper than that into a
        // bone.
        if (travel <= unchecked_travel_m_) {
          surface.col(i) = moved;
          continue;
        }
        if (!clearance_known[v]) {
          clearance[v] = boneClearance(start.col(i), 2 * travel + kClearanceMarginM);
          clearance_known[v] = 1;
        }
        // Never into a bone, nor deeper into one it already is in (the bundled data put some vertices there at rest).
        if (travel >= clearance[v]) {
          const double after = boneClearance(moved, 0.0);
          if (after < 0 && after < boneClearance(start.col(i), 0.0)) {
            held[v] = 1;
            ++correction.vertices_held_by_bone;
            continue;
          }
        }
      }
      surface.col(i) = moved;
    }
  }
  double offset_sum = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const double offset = (surface.col(i) - start.col(i)).norm();
    offset_sum += offset;
    correction.max_offset_m = std::max(correction.max_offset_m, offset);
  }
  correction.mean_offset_m = offset_sum / static_cast<double>(n);
  return correction;
}

}  // namespace muscle_deformation
