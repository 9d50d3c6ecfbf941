// Incompressibility as a term of the frame energy: per muscle m, E_m = k_m / 2 (V_m(x) - V_m,rest)^2, where V_m is the
// muscle's volume as a function of its particles. The solvers that minimise a frame energy (block descent,
// Newton-Krylov) take it beside the springs, contacts and tissue drag; what V is (the volume of the skinned surface,
// surfaces/skinned_volume.hpp) reaches them as callbacks, so the solvers stay free of surfaces.
//
// V_m must be linear in any one particle's position (true of an enclosed volume through a skin: a triangle's triple
// product is antisymmetric), so a particle's own Newton step on the term is exact and the diagonal blocks of V's
// Hessian vanish.
#pragma once

#include <Eigen/Core>

#include <functional>
#include <vector>

namespace muscle_deformation {

struct VolumeTerm {
  std::vector<double> rest_volume_m3;  // per muscle
  std::vector<double> stiffness;       // per muscle, k_m (J/m^6); 0 leaves a muscle out
  // Per muscle, the volume the term pulls towards: the rest volume less the muscle's pressure p_m over k_m, so that
  // E_m = k_m / 2 (V_m - target_m)^2 = p_m (V_m - V_m,rest) + k_m / 2 (V_m - V_m,rest)^2 + const, the augmented
  // Lagrangian of the constraint V_m = V_m,rest. Empty: the rest volumes (no pressure, a plain penalty).
  std::vector<double> target_volume_m3;

  double target(std::size_t muscle) const {
    return target_volume_m3.empty() ? rest_volume_m3[muscle] : target_volume_m3[muscle];
  }
  // Every muscle's volume at `position` and each particle's gradient of its own muscle's volume (m^2, zero where the
  // volume does not depend on the particle).
  std::function<void(const Eigen::Matrix3Xd& position, std::vector<double>& volumes, Eigen::Matrix3Xd& gradients)>
      evaluate;
  // out_p = sum_m weight_m d/dt [dV_m/dx_p](position + t direction): the volume's own curvature along a direction.
  std::function<void(const Eigen::Matrix3Xd& position, const Eigen::Matrix3Xd& direction,
                     const std::vector<double>& weight, Eigen::Matrix3Xd& out)>
      curvature_times;

  bool active() const { return static_cast<bool>(evaluate) && !stiffness.empty(); }
};

}  // namespace muscle_deformation
