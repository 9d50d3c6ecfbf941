// Each muscle's enclosed volume as a function of the particles, through its skin: the surface the node shows is
// skinned on the particles (surface_skinning.hpp), so its volume V_m(x) = 1/6 sum_triangles v_a . (v_b x v_c), with
// every vertex v = sum_j w_j x_j (+ bone-rotated offsets for nearest_average, constant within a frame), is a function of
// the particle positions. Its gradient and curvature make the incompressibility term of the frame energy,
// E = sum_m k_m / 2 (V_m(x) - V_m,rest)^2, which the solvers minimise with the springs (block_descent_solver.hpp).
//
// V is linear in any one particle's position: moving particle p alone changes every vertex by w_vp d, and a triangle's
// triple product is antisymmetric, so the terms quadratic and cubic in d vanish. A sweep's per-particle Newton step on
// the volume term is therefore exact, and the diagonal 3 x 3 block of V's Hessian is zero.
#pragma once

#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <vector>

namespace muscle_deformation {

class SkinnedVolume {
 public:
  // `skinning` must outlive this object (its weights are read in place). The rest volumes are those of the skinned
  // rest particles (the volume term is zero at rest).
  SkinnedVolume(const SurfaceSkinning& skinning, const MassSpringSystem& system);

  int muscleCount() const { return static_cast<int>(rest_volume_m3_.size()); }
  const std::vector<double>& restVolumes() const { return rest_volume_m3_; }  // m^3, per muscle
  // Skin area at rest (m^2) and how many particles the skin follows, per muscle: the scale of the volume gradient.
  const std::vector<double>& restAreas() const { return rest_area_m2_; }
  const std::vector<int>& skinParticleCounts() const { return skin_particles_; }

  // Every muscle's volume at `position` (m^3), and each particle's gradient dV_m/dx_p of its own muscle's volume (m^2;
  // zero for particles no vertex follows). `transforms`: the bones of the frame (nearest_average reads their rotations).
  void evaluate(const Eigen::Matrix3Xd& position, const BoneTransforms& transforms, std::vector<double>& volumes,
                Eigen::Matrix3Xd& gradients) const;
  // Every muscle's volume only.
  void volumes(const Eigen::Matrix3Xd& position, const BoneTransforms& transforms, std::vector<double>& volumes) const;
  // The second derivative of each muscle's volume along `direction` (m per metre of direction), weighted per muscle:
  // out_p = sum_m weight_m d/dt [dV_m/dx_p](x + t direction).
  void curvatureTimes(const Eigen::Matrix3Xd& position, const BoneTransforms& transforms,
                      const Eigen::Matrix3Xd& direction, const std::vector<double>& weight,
                      Eigen::Matrix3Xd& out) const;
  // Threads the muscles are shared out on (the results do not depend on it); 1 until set.
  void setThreads(int threads) { threads_ = std::max(1, threads); }

 private:
  int threads_ = 1;
  const SurfaceSkinning& skinning_;
  std::vector<double> rest_volume_m3_, rest_area_m2_;
  std::vector<int> skin_particles_;
  Eigen::Index particle_count_ = 0;
  mutable std::vector<Vertices> vertices_, vertex_gradients_;  // per muscle, scratch
};

}  // namespace muscle_deformation
