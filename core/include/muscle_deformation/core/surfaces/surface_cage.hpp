// The mean_value skinning's cage (a closed triangle mesh whose corners are boundary particles) and mean value
// coordinates (Ju, Schaefer, Warren 2005).
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <Eigen/Core>

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// Invalid input for skinning (open muscle surface, too few particles, degenerate cage); names the muscle.
class SkinningError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// How the mean_value cage is triangulated from the boundary particles.
enum class CageKind {
  fibre_tube,   // the ring of outermost boundary fibres joined sample by sample, ends closed by fans: follows a muscle
                // that is curved along its length (falls back to convex_hull when fibres differ in sample count)
  convex_hull,  // convex hull of the boundary particles (qhull): always closed, but bridges concavities and drops
                // particles that lie on flat parts of the hull
};

std::string toString(CageKind kind);
CageKind cageKindFromString(const std::string& name);  // throws std::invalid_argument

// A closed triangle cage whose corners are particles: mesh vertex k is particle `particle[k]` (muscle-local index).
struct ParticleCage {
  TriangleMesh mesh;
  std::vector<std::int32_t> particle;
  CageKind kind = CageKind::fibre_tube;
};

// Cage of muscle `muscle` of `system` at rest. Throws SkinningError when no closed cage can be built.
ParticleCage buildParticleCage(const MassSpringSystem& system, int muscle, CageKind kind);

// Mean value coordinates of `point` with respect to the closed, consistently wound triangle mesh `cage`: one weight
// per cage vertex, summing to 1, with sum w_k v_k = point. Defined inside and outside the cage; on a cage triangle
// they are that triangle's barycentric coordinates. `on_cage` (optional) reports that case.
Eigen::VectorXd meanValueCoordinates(const TriangleMesh& cage, const Eigen::Vector3d& point, bool* on_cage = nullptr);

}  // namespace muscle_deformation
