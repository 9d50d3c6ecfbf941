#include "muscle_deformation/core/surfaces/surface_bone_contact.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

namespace muscle_deformation {

SurfaceBoneContact::SurfaceBoneContact(std::vector<Eigen::Index> vertex_counts, BoneFields bone_fields)
    : bone_fields_(std::move(bone_fields)) {
  for (const auto& field : bone_fields_)
    if (!field) throw std::invalid_argument("surface bone contact: a bone has no distance field");
  for (const Eigen::Index count : vertex_counts) reads_.emplace_back(bone_fields_.size(), FieldReadCache(count));
}

std::vector<SurfaceBoneCorrection> SurfaceBoneContact::apply(std::vector<Vertices>& surfaces,
                                                             const BoneTransforms& bone_transforms,
                                                             int threads) const {
  if (surfaces.size() != reads_.size())
    throw std::invalid_argument("surface bone contact: " + std::to_string(surfaces.size()) + " surfaces for " +
                                std::to_string(reads_.size()) + " muscles");
  const std::size_t bone_count = bone_fields_.size();
  std::vector<Eigen::Isometry3d> to_pose(bone_count, Eigen::Isometry3d::Identity()), to_rest(bone_count);
  std::vector<AlignedBox> box(bone_count);
  for (std::size_t b = 0; b < bone_count; ++b) {
    if (b < bone_transforms.size()) to_pose[b] = bone_transforms[b];
    to_rest[b] = to_pose[b].inverse();
    box[b] = bone_fields_[b]->reachIn(to_pose[b]);
  }

  std::vector<SurfaceBoneCorrection> corrections(surfaces.size());
  const long muscle_count = static_cast<long>(surfaces.size());
  // Muscles apart on the threads (each its own surface, reads and correction; probes are per thread).
#pragma omp parallel num_threads(std::max(1, threads))
  {
    std::vector<BoneDistanceField::Probe> probes;
    for (std::size_t b = 0; b < bone_count; ++b) probes.push_back(bone_fields_[b]->probe());
#pragma omp for schedule(dynamic, 1)
    for (long muscle = 0; muscle < muscle_count; ++muscle) {
      const std::size_t m = static_cast<std::size_t>(muscle);
      Vertices& surface = surfaces[m];
      std::vector<FieldReadCache>& reads = reads_[m];
      for (FieldReadCache& cache : reads)
        if (cache.size() != surface.cols()) cache = FieldReadCache(surface.cols());  // another surface: nothing known
      SurfaceBoneCorrection& correction = corrections[m];
      for (Eigen::Index v = 0; v < surface.cols(); ++v) {
        for (std::size_t b = 0; b < bone_count; ++b) {
          const Eigen::Vector3d point = surface.col(v);
          if ((point.array() < box[b].min.array()).any() || (point.array() > box[b].max.array()).any()) continue;
          Eigen::Vector3d local = to_rest[b] * point;
          if (reads[b].provenBeyond(v, local, 0.0)) continue;
          double distance = 0;
          Eigen::Vector3d gradient;
          if (!probes[b].closerThan(local, 0.0, distance, gradient)) {
            reads[b].remember(v, local, distance);
            continue;
          }
          // Inside: step out along the gradient to the clearance, reading the field again after each step (the surface
          // curves; one linear step from deep inside can land short).
          const Eigen::Vector3d before = local;
          correction.max_depth_before_m = std::max(correction.max_depth_before_m, -distance);
          for (int step = 0; step < kMaxSteps && distance < 0.5 * kClearanceM; ++step) {
            const double length = gradient.norm();
            if (!(length > 1e-9)) break;  // on the field's medial axis: no way out is defined
            local += (kClearanceM - distance) / length * gradient;
            distance = probes[b].distance(local, gradient);
          }
          reads[b].remember(v, local, distance);
          surface.col(v) = to_pose[b] * local;
          ++correction.vertices_moved;
          correction.max_move_m = std::max(correction.max_move_m, (local - before).norm());
        }
      }
    }
  }
  return corrections;
}

}  // namespace muscle_deformation
