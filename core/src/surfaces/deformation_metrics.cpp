#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

namespace muscle_deformation {

DeformationMetrics::DeformationMetrics(const std::vector<Bone>& bones, const std::vector<Muscle>& muscles,
                                       const MassSpringSystem& system,
                                       std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields)
    : bone_fields_(std::move(bone_fields)) {
  if (!bone_fields_.empty() && bone_fields_.size() != bones.size())
    throw MetricsError("metrics: " + std::to_string(bone_fields_.size()) + " bone distance fields for " +
                       std::to_string(bones.size()) + " bones");
  if (static_cast<int>(muscles.size()) != system.muscleCount())
    throw MetricsError("metrics: " + std::to_string(muscles.size()) + " muscle surfaces for a system of " +
                       std::to_string(system.muscleCount()) + " muscles");
  for (std::size_t b = 0; b < bones.size(); ++b) {
    if (bones[b].id != static_cast<int>(b))
      throw MetricsError("metrics: bone '" + bones[b].name + "' has id " + std::to_string(bones[b].id) +
                         " but is at position " + std::to_string(b));
    bone_names_.push_back(bones[b].name);
    if (bone_fields_.size() < bones.size()) {
      try {
        bone_fields_.push_back(std::make_shared<const BoneDistanceField>(bones[b].surface, BoneFieldSettings{},
                                                                         "bone '" + bones[b].name + "'"));
      } catch (const BoneFieldError& error) {
        throw MetricsError(error.what());
      }
    }
  }
  for (const Muscle& muscle : muscles) {
    vertex_reads_.emplace_back(bone_fields_.size(), FieldReadCache(muscle.surface.vertexCount()));
    const SurfaceTopologyReport topology = checkSurfaceTopology(muscle.surface);
    if (!topology.closedManifold())
      throw MetricsError("muscle '" + muscle.name + "': surface is not a closed 2-manifold (" + topology.describe() +
                         "); its enclosed volume is undefined");
    const double volume = enclosedVolume(muscle.surface);
    if (!(std::abs(volume) > 0)) throw MetricsError("muscle '" + muscle.name + "': surface encloses no volume");
    muscle_names_.push_back(muscle.name);
    muscle_triangles_.push_back(muscle.surface.triangles);
    rest_volume_.push_back(std::abs(volume));
    volume_sign_.push_back(volume < 0 ? -1.0 : 1.0);
  }
  // Fibres: consecutive particles of one fibre of one muscle (as fibrePolylines).
  const Eigen::Index n = system.particleCount();
  particle_count_ = n;
  particle_reads_.assign(bone_fields_.size(), FieldReadCache(n));
  particle_own_bone_.assign(static_cast<std::size_t>(n), -1);
  for (Eigen::Index i = 0; i < n; ++i)
    if (system.is_fixed[static_cast<std::size_t>(i)]) particle_own_bone_[static_cast<std::size_t>(i)] = system.fixed_bone[i];
  muscle_particle_runs_.resize(muscle_names_.size());
  const auto muscleOf = [&system](Eigen::Index i) {
    return system.fibre_of[i] == kTendonAnchor ? -1 : system.muscle_of[i];
  };
  for (Eigen::Index begin = 0; begin < n;) {
    const int muscle = muscleOf(begin);
    Eigen::Index end = begin;
    while (end < n && muscleOf(end) == muscle) ++end;
    if (muscle >= 0) muscle_particle_runs_[static_cast<std::size_t>(muscle)].emplace_back(begin, end);
    begin = end;
  }
  Eigen::Index first = 0;
  for (Eigen::Index i = 1; i <= n; ++i)
    if (i == n || system.fibre_of[i] != system.fibre_of[i - 1] || system.muscle_of[i] != system.muscle_of[i - 1]) {
      if (system.fibre_of[first] != kTendonAnchor) {
        fibre_muscle_.push_back(system.muscle_of[i - 1]);
        fibre_range_.emplace_back(first, i);
      }
      first = i;
    }
  // With unit rest lengths the ratios are the rest lengths themselves.
  fibre_rest_length_ = Eigen::VectorXd::Ones(static_cast<Eigen::Index>(fibre_muscle_.size()));
  fibre_rest_length_ = fibreLengthRatios(system.rest_position);
  for (Eigen::Index f = 0; f < fibre_rest_length_.size(); ++f)
    if (!(fibre_rest_length_[f] > 0)) fibre_rest_length_[f] = std::numeric_limits<double>::quiet_NaN();
}

Eigen::VectorXd DeformationMetrics::fibreLengthRatios(const Eigen::Matrix3Xd& particle_positions) const {
  Eigen::VectorXd ratios(static_cast<Eigen::Index>(fibre_muscle_.size()));
  for (std::size_t f = 0; f < fibre_muscle_.size(); ++f) {
    double length = 0;
    for (Eigen::Index i = fibre_range_[f].first + 1; i < fibre_range_[f].second; ++i)
      length += (particle_positions.col(i) - particle_positions.col(i - 1)).norm();
    ratios[static_cast<Eigen::Index>(f)] = length / fibre_rest_length_[static_cast<Eigen::Index>(f)];
  }
  return ratios;
}

namespace {

// The bones placed by one pose, for testing many points: each bone's world-to-rest transform, its box in the world and
// a probe of its field. A point is taken back into a bone's rest frame and read only where its last read (`reads`)
// does not already prove it out of that bone.
class PosedBones {
 public:
  PosedBones(const std::vector<std::shared_ptr<const BoneDistanceField>>& fields, const BoneTransforms& transforms) {
    for (std::size_t b = 0; b < fields.size(); ++b) {
      const Eigen::Isometry3d to_pose = b < transforms.size() ? transforms[b] : Eigen::Isometry3d::Identity();
      to_rest_.push_back(to_pose.inverse());
      box_.push_back(fields[b]->reachIn(to_pose));
      probes_.push_back(fields[b]->probe());
    }
  }

  // Only bones whose box meets the box of `points` are tested by the calls to inside() that follow.
  template <class Points>
  void lookNear(const Points& points) {
    near_.clear();
    if (points.cols() == 0) return;
    const Eigen::Vector3d low = points.rowwise().minCoeff(), high = points.rowwise().maxCoeff();
    for (std::size_t b = 0; b < box_.size(); ++b)
      if ((high.array() >= box_[b].min.array()).all() && (low.array() <= box_[b].max.array()).all()) near_.push_back(b);
  }

  // Whether point k (of `reads`, one cache per bone) is inside any bone near but `ignored_bone`; raises `deepest` and
  // sets `deepest_bone` where it lies deeper.
  bool inside(std::vector<FieldReadCache>& reads, Eigen::Index k, const Eigen::Vector3d& point, double& deepest,
              int& deepest_bone, int ignored_bone = -1) {
    bool inside = false;
    for (const std::size_t b : near_) {
      if (static_cast<int>(b) == ignored_bone) continue;
      if ((point.array() < box_[b].min.array()).any() || (point.array() > box_[b].max.array()).any()) continue;
      const Eigen::Vector3d local = to_rest_[b] * point;
      if (reads[b].provenBeyond(k, local, 0.0)) continue;
      double distance = 0;
      Eigen::Vector3d unused;
      const bool closer = probes_[b].closerThan(local, 0.0, distance, unused);
      reads[b].remember(k, local, distance);
      if (!closer) continue;
      inside = true;
      if (-distance > deepest) {
        deepest = -distance;
        deepest_bone = static_cast<int>(b);
      }
    }
    return inside;
  }

 private:
  std::vector<Eigen::Isometry3d> to_rest_;
  std::vector<AlignedBox> box_;
  std::vector<BoneDistanceField::Probe> probes_;
  std::vector<std::size_t> near_;
};

}  // namespace

SceneMetrics DeformationMetrics::measureParticles(const Eigen::Matrix3Xd& particle_positions,
                                                  const BoneTransforms& bone_transforms, int threads) const {
  if (particle_positions.cols() != particle_count_)
    throw MetricsError("metrics: " + std::to_string(particle_positions.cols()) + " particle positions, the system has " +
                       std::to_string(particle_count_));
  SceneMetrics scene;
  scene.muscles.resize(muscle_names_.size());
  for (std::size_t m = 0; m < muscle_names_.size(); ++m) scene.muscles[m].name = muscle_names_[m];
  // Muscles apart on the threads: each writes its own figures and its own particles' entries of the read caches.
  const long muscle_count = static_cast<long>(muscle_particle_runs_.size());
#pragma omp parallel num_threads(std::max(1, threads))
  {
    PosedBones bones(bone_fields_, bone_transforms);
#pragma omp for schedule(dynamic, 1)
    for (long muscle = 0; muscle < muscle_count; ++muscle) {
      MuscleMetrics& out = scene.muscles[static_cast<std::size_t>(muscle)];
      int deepest_bone = -1;
      for (const auto& [begin, end] : muscle_particle_runs_[static_cast<std::size_t>(muscle)]) {
        bones.lookNear(particle_positions.middleCols(begin, end - begin));
        for (Eigen::Index i = begin; i < end; ++i)
          out.particles_inside_bone += bones.inside(particle_reads_, i, particle_positions.col(i),
                                                    out.max_particle_inside_bone_depth_m, deepest_bone,
                                                    particle_own_bone_[static_cast<std::size_t>(i)]);
      }
      if (deepest_bone >= 0) out.deepest_particle_bone = bone_names_[static_cast<std::size_t>(deepest_bone)];
    }
  }
  for (const MuscleMetrics& out : scene.muscles) {
    scene.particles_inside_bone += out.particles_inside_bone;
    scene.max_particle_inside_bone_depth_m =
        std::max(scene.max_particle_inside_bone_depth_m, out.max_particle_inside_bone_depth_m);
  }
  return scene;
}

SceneMetrics DeformationMetrics::measure(const std::vector<Vertices>& surfaces, const Eigen::Matrix3Xd& particle_positions,
                                         const BoneTransforms& bone_transforms, int threads) const {
  const auto start = std::chrono::steady_clock::now();
  if (surfaces.size() != muscle_names_.size())
    throw MetricsError("metrics: " + std::to_string(surfaces.size()) + " deformed surfaces for " +
                       std::to_string(muscle_names_.size()) + " muscles");
  for (std::size_t m = 0; m < muscle_names_.size(); ++m)
    if (surfaces[m].cols() <= muscle_triangles_[m].maxCoeff())
      throw MetricsError("muscle '" + muscle_names_[m] + "': deformed surface has " +
                         std::to_string(surfaces[m].cols()) + " vertices, fewer than its triangles refer to");
  SceneMetrics scene = measureParticles(particle_positions, bone_transforms, threads);
  // Muscles apart on the threads (each its own surface, reads and figures; bone probes are per thread); the scene's
  // figures are summed afterwards in muscle order, so they do not depend on the thread count.
  const long muscle_count = static_cast<long>(muscle_names_.size());
#pragma omp parallel num_threads(std::max(1, threads))
  {
    PosedBones bones(bone_fields_, bone_transforms);
#pragma omp for schedule(dynamic, 1)
    for (long muscle = 0; muscle < muscle_count; ++muscle) {
      const std::size_t m = static_cast<std::size_t>(muscle);
      MuscleMetrics& out = scene.muscles[m];
      const Vertices& surface = surfaces[m];
      out.rest_volume_m3 = rest_volume_[m];
      out.volume_m3 = volume_sign_[m] * enclosedVolume(surface, muscle_triangles_[m]);
      out.volume_error_pct = (out.volume_m3 - out.rest_volume_m3) / out.rest_volume_m3 * 100;
      std::vector<FieldReadCache>& reads = vertex_reads_[m];
      for (FieldReadCache& cache : reads)
        if (cache.size() != surface.cols()) cache = FieldReadCache(surface.cols());  // another surface: nothing known
      bones.lookNear(surface);
      int deepest_bone = -1;
      for (Eigen::Index v = 0; v < surface.cols(); ++v)
        out.vertices_inside_bone += bones.inside(reads, v, surface.col(v), out.max_inside_bone_depth_m, deepest_bone);
      if (deepest_bone >= 0) out.deepest_bone = bone_names_[static_cast<std::size_t>(deepest_bone)];
    }
  }
  for (std::size_t m = 0; m < muscle_names_.size(); ++m) {
    const MuscleMetrics& out = scene.muscles[m];
    scene.vertices_inside_bone += out.vertices_inside_bone;
    scene.max_inside_bone_depth_m = std::max(scene.max_inside_bone_depth_m, out.max_inside_bone_depth_m);
    scene.volume_error_mean_pct += std::abs(out.volume_error_pct);
    scene.volume_error_max_pct = std::max(scene.volume_error_max_pct, std::abs(out.volume_error_pct));
  }
  if (!scene.muscles.empty()) scene.volume_error_mean_pct /= static_cast<double>(scene.muscles.size());

  const Eigen::VectorXd ratios = fibreLengthRatios(particle_positions);
  std::vector<double> sum(muscle_names_.size(), 0.0);
  for (std::size_t f = 0; f < fibre_muscle_.size(); ++f) {
    MuscleMetrics& out = scene.muscles[fibre_muscle_[f]];
    const double change = (ratios[static_cast<Eigen::Index>(f)] - 1) * 100;
    if (out.fibres == 0) out.fibre_length_change_min_pct = out.fibre_length_change_max_pct = change;
    out.fibre_length_change_min_pct = std::min(out.fibre_length_change_min_pct, change);
    out.fibre_length_change_max_pct = std::max(out.fibre_length_change_max_pct, change);
    sum[fibre_muscle_[f]] += change;
    out.fibres += 1;
  }
  for (std::size_t m = 0; m < scene.muscles.size(); ++m)
    if (scene.muscles[m].fibres > 0) scene.muscles[m].fibre_length_change_mean_pct = sum[m] / scene.muscles[m].fibres;
  scene.compute_ms = millisecondsSince(start);
  return scene;
}

}  // namespace muscle_deformation
