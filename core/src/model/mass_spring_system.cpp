#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <algorithm>
#include <vector>

namespace muscle_deformation {

std::size_t MassSpringSystem::modelBytes() const {
  const auto particles = static_cast<std::size_t>(particleCount());
  const std::size_t per_particle = sizeof(double) * (3 /*rest*/ + 1 /*mass*/ + 1 /*radius*/) + 2 /*flags*/ +
                                   4 * sizeof(std::int32_t) + kBlendBones * (sizeof(std::int32_t) + sizeof(double));
  const std::size_t per_spring = 2 * sizeof(std::int32_t) + 2 * sizeof(double);
  return per_particle * particles + per_spring * springs.size();
}

double MassSpringSystem::medianCollisionRadius() const {
  std::vector<double> radii;
  for (Eigen::Index i = 0; i < radius.size(); ++i)
    if (radius[i] > 0) radii.push_back(radius[i]);
  if (radii.empty()) return 0;
  const auto middle = radii.begin() + static_cast<std::ptrdiff_t>(radii.size() / 2);
  std::nth_element(radii.begin(), middle, radii.end());
  return *middle;
}

std::vector<Eigen::Matrix3Xd> fibrePolylines(const MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
  // Particles of one fibre are stored consecutively, in order from the fibre start.
  std::vector<Eigen::Matrix3Xd> fibres;
  Eigen::Index begin = 0;
  for (Eigen::Index i = 1; i <= system.particleCount(); ++i) {
    const bool fibre_ends = i == system.particleCount() || system.fibre_of[i] != system.fibre_of[i - 1] ||
                            system.muscle_of[i] != system.muscle_of[i - 1];
    if (!fibre_ends) continue;
    if (system.fibre_of[begin] != kTendonAnchor) fibres.push_back(position.middleCols(begin, i - begin));
    begin = i;
  }
  return fibres;
}

}  // namespace muscle_deformation
