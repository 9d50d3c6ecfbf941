// Contacts handed to a solver that treats them as energy inside its solve (block descent), rather than as a
// projection after each update (the AfterUpdateHook the explicit and local/global solvers use).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <vector>

namespace muscle_deformation {

struct ParticleState;

struct ContactSet {
  // A particle against a sphere that does not move during the solve (a bone sphere in the pose): the particle's
  // centre is kept at least `distance` (sum of the two radii) from `centre`.
  struct Obstacle {
    std::int32_t particle;
    Eigen::Vector3d centre;
    double distance;
  };
  // Two particles of different muscles kept at least `distance` apart (either may be fixed).
  struct Pair {
    std::int32_t first, second;
    double distance;
  };
  // A particle kept on the outer side of a plane that does not move during the solve: n . (x - point) >= 0 with `normal`
  // of unit length. A bone's distance field linearised where the particle stood when the contacts were gathered (the
  // next gathering linearises again), so a contact is a lookup, not a set of spheres.
  struct HalfSpace {
    std::int32_t particle;
    Eigen::Vector3d point;
    Eigen::Vector3d normal;
  };
  std::vector<Obstacle> obstacles;
  std::vector<Pair> pairs;
  std::vector<HalfSpace> half_spaces;

  void clear() {
    obstacles.clear();
    pairs.clear();
    half_spaces.clear();
  }
  std::size_t size() const { return obstacles.size() + pairs.size() + half_spaces.size(); }
};

// Fills `contacts` with every pair at `state` that overlaps or is within `margin_m` of touching (replacing what it
// held). The collision stage provides it.
using ContactQuery = std::function<void(const ParticleState& state, double margin_m, ContactSet& contacts)>;

}  // namespace muscle_deformation
