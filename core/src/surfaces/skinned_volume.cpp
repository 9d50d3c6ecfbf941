#include "muscle_deformation/core/surfaces/skinned_volume.hpp"

#include <stdexcept>

namespace muscle_deformation {
namespace {

// W^T g: the particles' share of a per-vertex quantity, added into `out` (the muscle's particles start at `begin`).
void scatterToParticles(const MuscleSkin::Weights& weights, const Vertices& per_vertex, Eigen::Index begin,
                        Eigen::Matrix3Xd& out) {
  const std::int32_t* row_begin = weights.outerIndexPtr();
  const std::int32_t* column = weights.innerIndexPtr();
  const double* weight = weights.valuePtr();
  for (Eigen::Index v = 0; v < weights.rows(); ++v)
    for (std::int32_t k = row_begin[v]; k < row_begin[v + 1]; ++k)
      out.col(begin + column[k]) += weight[k] * per_vertex.col(v);
}

}  // namespace

SkinnedVolume::SkinnedVolume(const SurfaceSkinning& skinning, const MassSpringSystem& system)
    : skinning_(skinning), particle_count_(system.particleCount()) {
  const std::vector<MuscleSkin>& skins = skinning_.muscles();
  if (static_cast<int>(skins.size()) != system.muscleCount())
    throw std::invalid_argument("skinned volume: " + std::to_string(skins.size()) + " skins for " +
                                std::to_string(system.muscleCount()) + " muscles");
  vertices_.resize(skins.size());
  vertex_gradients_.resize(skins.size());
  for (std::size_t m = 0; m < skins.size(); ++m) {
    const MuscleSkin& skin = skins[m];
    skin.update(system.rest_position, BoneTransforms(), vertices_[m]);
    rest_volume_m3_.push_back(enclosedVolume(vertices_[m], skin.triangles()));
    double area = 0;
    for (Eigen::Index t = 0; t < skin.triangles().cols(); ++t) {
      const Eigen::Vector3d a = vertices_[m].col(skin.triangles()(0, t)), b = vertices_[m].col(skin.triangles()(1, t)),
                            c = vertices_[m].col(skin.triangles()(2, t));
      area += 0.5 * (b - a).cross(c - a).norm();
    }
    rest_area_m2_.push_back(area);
    std::vector<char> followed(static_cast<std::size_t>(skin.weights().cols()), 0);
    for (int k = 0; k < skin.weights().nonZeros(); ++k) followed[static_cast<std::size_t>(skin.weights().innerIndexPtr()[k])] = 1;
    int count = 0;
    for (char f : followed) count += f;
    skin_particles_.push_back(count);
  }
}

void SkinnedVolume::volumes(const Eigen::Matrix3Xd& position, const BoneTransforms& transforms,
                            std::vector<double>& volumes) const {
  const std::vector<MuscleSkin>& skins = skinning_.muscles();
  volumes.assign(skins.size(), 0.0);
  const int muscles = static_cast<int>(skins.size());
#pragma omp parallel for num_threads(threads_) schedule(dynamic)
  for (int mi = 0; mi < muscles; ++mi) {
    const std::size_t m = static_cast<std::size_t>(mi);
    skins[m].update(position, transforms, vertices_[m]);
    volumes[m] = enclosedVolume(vertices_[m], skins[m].triangles());
  }
}

void SkinnedVolume::evaluate(const Eigen::Matrix3Xd& position, const BoneTransforms& transforms,
                             std::vector<double>& volumes, Eigen::Matrix3Xd& gradients) const {
  const std::vector<MuscleSkin>& skins = skinning_.muscles();
  volumes.assign(skins.size(), 0.0);
  gradients.setZero(3, particle_count_);
  // One muscle per thread: each writes its own vertices and its own particles' columns, and sums its volume alone, so
  // the result does not depend on the thread count.
  const int muscles = static_cast<int>(skins.size());
#pragma omp parallel for num_threads(threads_) schedule(dynamic)
  for (int mi = 0; mi < muscles; ++mi) {
    const std::size_t m = static_cast<std::size_t>(mi);
    const MuscleSkin& skin = skins[m];
    Vertices& v = vertices_[m];
    skin.update(position, transforms, v);
    const Triangles& triangles = skin.triangles();
    Vertices& dv = vertex_gradients_[m];
    dv.setZero(3, v.cols());
    double six_volume = 0;
    // dV/dv_a = (v_b x v_c) / 6 for every triangle (a, b, c) and its rotations.
    for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
      const int a = triangles(0, t), b = triangles(1, t), c = triangles(2, t);
      const Eigen::Vector3d va = v.col(a), vb = v.col(b), vc = v.col(c);
      const Eigen::Vector3d bc = vb.cross(vc);
      six_volume += va.dot(bc);
      dv.col(a) += bc;
      dv.col(b) += vc.cross(va);
      dv.col(c) += va.cross(vb);
    }
    volumes[m] = six_volume / 6.0;
    dv /= 6.0;
    scatterToParticles(skin.weights(), dv, skin.particleBegin(), gradients);
  }
}

void SkinnedVolume::curvatureTimes(const Eigen::Matrix3Xd& position, const BoneTransforms& transforms,
                                   const Eigen::Matrix3Xd& direction, const std::vector<double>& weight,
                                   Eigen::Matrix3Xd& out) const {
  const std::vector<MuscleSkin>& skins = skinning_.muscles();
  out.setZero(3, particle_count_);
  const int muscles = static_cast<int>(skins.size());
#pragma omp parallel for num_threads(threads_) schedule(dynamic)
  for (int mi = 0; mi < muscles; ++mi) {
    const std::size_t m = static_cast<std::size_t>(mi);
    if (m >= weight.size() || weight[m] == 0.0) continue;
    Vertices u;
    const MuscleSkin& skin = skins[m];
    Vertices& v = vertices_[m];
    skin.update(position, transforms, v);
    // The vertices' displacement along the direction: the weights only (the bone offsets do not move with particles).
    skin.linearPart(direction, u);
    const Triangles& triangles = skin.triangles();
    Vertices& dv = vertex_gradients_[m];
    dv.setZero(3, v.cols());
    // d/dt (v_b x v_c) = u_b x v_c + v_b x u_c, and the same for the rotations of the triangle.
    for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
      const int a = triangles(0, t), b = triangles(1, t), c = triangles(2, t);
      const Eigen::Vector3d va = v.col(a), vb = v.col(b), vc = v.col(c);
      const Eigen::Vector3d ua = u.col(a), ub = u.col(b), uc = u.col(c);
      dv.col(a) += ub.cross(vc) + vb.cross(uc);
      dv.col(b) += uc.cross(va) + vc.cross(ua);
      dv.col(c) += ua.cross(vb) + va.cross(ub);
    }
    dv *= weight[m] / 6.0;
    scatterToParticles(skin.weights(), dv, skin.particleBegin(), out);
  }
}

}  // namespace muscle_deformation
