// Spheres, and the broad phases that find overlapping pairs between sphere sets: the seeds' AABB octree and a
// uniform spatial hash grid, plus the brute-force reference both must agree with.
#pragma once

#include "muscle_deformation/core/collision/collision_settings.hpp"
#include "muscle_deformation/core/base/geometry.hpp"

#include <Eigen/Core>

#include <cstdint>
#include <memory>
#include <vector>

namespace muscle_deformation {

// A set of spheres, e.g. one muscle's boundary particles or one bone's surface approximation. Metres.
struct SphereSet {
  Eigen::Matrix3Xd centre = Eigen::Matrix3Xd(3, 0);
  Eigen::VectorXd radius;

  Eigen::Index size() const { return centre.cols(); }
  void resize(Eigen::Index n) {
    centre.resize(3, n);
    radius.resize(n);
  }
};

// Bounds of the spheres (not just their centres). Empty box for an empty set.
AlignedBox sphereBounds(const SphereSet& spheres);

// Two spheres, one from each set, that overlap: |c_a - c_b| < r_a + r_b (touching spheres do not collide).
struct SpherePair {
  std::int32_t first;   // index in the first set
  std::int32_t second;  // index in the second set
  bool operator==(const SpherePair& o) const { return first == o.first && second == o.second; }
  bool operator<(const SpherePair& o) const { return first != o.first ? first < o.first : second < o.second; }
};

// An overlapping pair between two objects of a group query: objects by broad-phase id, spheres by index in each.
struct ObjectSpherePair {
  std::int32_t first_object, second_object;  // first_object < second_object
  std::int32_t first, second;                // sphere indices in those objects
};

// Reference answer: tests every sphere of `a` against every sphere of `b`. Clears `pairs` first.
void overlappingPairsBruteForce(const SphereSet& a, const SphereSet& b, std::vector<SpherePair>& pairs);

// Finds all overlapping sphere pairs between two objects. Objects are registered by id; the broad phase keeps a
// pointer to each object's SphereSet, which the caller owns and keeps alive and at the same size.
// Every implementation returns exactly the pairs overlappingPairsBruteForce returns (sorted order not guaranteed).
class BroadPhase {
 public:
  virtual ~BroadPhase() = default;
  virtual BroadPhaseKind kind() const = 0;
  // Registers object `id` or tells that its spheres moved. `rebuild` discards any hierarchy (use it when the shape
  // changed a lot, e.g. a new bone pose); otherwise the octree is only refitted. Work is deferred to the next query.
  virtual void update(int id, const SphereSet& spheres, bool rebuild) = 0;
  // Clears `pairs`, then fills it with (index in a, index in b). a != b.
  virtual void findPairs(int a, int b, std::vector<SpherePair>& pairs) = 0;
  // Clears `pairs`, then fills it with every overlapping pair between objects ids[i] and ids[j], i < j, for which
  // test_pair[i * ids.size() + j] is nonzero (e.g. all muscles against each other where their bounds overlap).
  // The default runs findPairs per allowed pair; the hash grid hashes all the objects into one table instead, so
  // its cost follows the number of spheres, not the number of object pairs (Teschner et al.).
  virtual void findPairsAmong(const std::vector<int>& ids, const std::vector<std::uint8_t>& test_pair,
                              std::vector<ObjectSpherePair>& pairs);

 protected:
  std::vector<SpherePair> scratch_pairs_;
};

std::unique_ptr<BroadPhase> makeBroadPhase(const CollisionSettings& settings);

}  // namespace muscle_deformation
