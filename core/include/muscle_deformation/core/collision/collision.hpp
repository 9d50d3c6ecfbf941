// Sphere-based collision handling between muscles and bones (thesis 4.3, GRAPP 2014 section 3.3).
//
// Every boundary particle of a muscle is a sphere; every bone is approximated by a fixed set of spheres. After each
// mass-spring update, overlapping spheres of different objects are pushed apart (half the overlap each, or the whole
// overlap for the free one when the other is fixed), displacements are summed per particle and applied after all
// tests, and every particle that collided loses its velocity. A muscle never collides with itself.
#pragma once

#include "muscle_deformation/core/geometry.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/model/model.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace muscle_deformation {

// ---------------------------------------------------------------------------------------------------------------
// Spheres and pair queries

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

enum class BroadPhaseKind {
  octree,     // the seeds' method: per-object AABB octree split at the box midpoint, built lazily, refitted
  hash_grid,  // uniform spatial hash grid (Teschner et al. 2003), rebuilt whenever the object moved
};

const char* toString(BroadPhaseKind kind);

// Which vertices may become roots of the one-ring heuristic.
enum class OneRingRule {
  // Thesis 4.3 as written: any vertex not yet marked becomes a root, and it and its ring are marked. Two roots are
  // never neighbours, so their triangle fans are disjoint; every vertex is a root or in a root's ring, so a convex
  // surface is covered completely (at the price of overlapping spheres).
  disjoint_triangle_fans,
  // Stricter: a root's whole ring must be unmarked, so the vertex rings are disjoint. About half the spheres, but a
  // vertex can be two edges from the nearest root and left up to ~0.8 edge lengths outside every sphere.
  disjoint_vertex_rings,
};

struct CollisionSettings {
  // Default chosen by measurement (bench/collision_bench.cpp, 13 muscles x 64 fibres, 2-core shared machine, one
  // thread): the octree's muscle-muscle pass took 0.23-0.36 ms per iteration against the hash grid's 1.7-3.4 ms,
  // and its muscle-bone pass 0.38-0.55 ms against 0.45-0.72 ms, at every size from 20 to 80 particles per fibre.
  BroadPhaseKind broad_phase = BroadPhaseKind::octree;
  int octree_max_depth = 8;        // GRAPP 2014: empirically 8
  int octree_min_primitives = 10;  // a node with at most this many spheres is a leaf (GRAPP 2014: 10)
  double hash_cell_scale = 1.0;    // hash cell edge = this x the mean sphere diameter of the hashed object
  double bone_reach_margin_m = 0.0;  // a bone is tested only if its sphere bounds grown by this reach some muscle's
  // Skip muscle-bone tests whose sphere bounds do not overlap (a whole bone when it reaches no muscle): exact, since
  // spheres lie inside their bounds. false sends every muscle-bone pair to the broad phase, to measure what the
  // skip saves (bench/economy_bench.cpp); results are the same either way.
  bool skip_bones_out_of_reach = true;
  OneRingRule bone_sphere_rule = OneRingRule::disjoint_triangle_fans;  // for bones given as meshes
};

// Returns an empty string when the settings are usable, otherwise what is wrong.
std::string validate(const CollisionSettings& settings);

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

// ---------------------------------------------------------------------------------------------------------------
// Sphere radii of muscle particles and sphere sets of bones (pre-processing)

struct MuscleRadiiSummary {
  std::string name;
  int boundary_particles = 0;
  int particles_without_vertex = 0;  // no surface vertex had them as closest: half the nearest spacing used
  int reduced_pairs = 0;             // overlapping same-muscle pairs shrunk to touching
  double mean_radius_before_m = 0;   // mean over boundary particles, before the overlap reduction
  double mean_radius_m = 0;          // after
};

// The seeds' heuristic (thesis 4.3). For each muscle, every surface vertex is associated with its closest boundary
// particle (rest positions); a particle's radius is the mean distance to its associated vertices. A boundary particle
// no vertex chose gets half the distance to its nearest other boundary particle of the muscle: it lies behind
// particles nearer the surface, so it should fill the gap between its neighbours without poking out.
// Then radii are reduced until no two spheres of the same muscle overlap: overlapping pairs are visited from the
// deepest relative overlap, and both radii of a pair still overlapping are scaled by d / (r_i + r_j) so the two just
// touch. Radii only shrink, so a pair once fixed stays fixed and one pass suffices.
// Interior particles get radius 0 and never collide. `muscles` are in the order of system.muscle_name.
std::vector<MuscleRadiiSummary> assignCollisionRadii(MassSpringSystem& system, const std::vector<Muscle>& muscles);

struct RestOverlapSummary {
  int muscle_muscle_pairs = 0;  // sphere pairs of different muscles overlapping at rest, shrunk to touching
  int muscle_bone_pairs = 0;    // muscle spheres overlapping a bone sphere at rest, shrunk to touching it
  int spheres_removed = 0;      // muscle particles whose centre lies inside a bone sphere: radius 0, no collision
};

// The rest pose must be free of contacts, or the solver deforms muscles that nothing has moved. Real anatomy is
// packed tight (neighbouring muscles touch, registered bones graze muscles), so the radii from
// assignCollisionRadii can overlap spheres of other muscles and of bones at rest. This shrinks them until they
// just touch: both spheres of a muscle-muscle pair by the same factor (as within a muscle), a muscle sphere against
// a (fixed) bone sphere on its own. Bone spheres are in the rest frame (as boneSpheresOneRing gives them).
RestOverlapSummary clearRestOverlaps(MassSpringSystem& system, const std::vector<SphereSet>& bone_spheres_rest);

// The seeds' one-ring heuristic (thesis 4.3): vertices are visited in index order; a vertex allowed by `rule` becomes
// a root and it and its ring are marked. Its sphere is centred at the root moved inward (against the area-weighted
// vertex normal) by the longest edge L at the root, radius L sqrt(2) (touches the far end of that edge when it lies
// in the tangent plane). Centres are in the bone's rest frame (the mesh's frame).
SphereSet boneSpheresOneRing(const TriangleMesh& surface,
                              OneRingRule rule = OneRingRule::disjoint_triangle_fans);

// ---------------------------------------------------------------------------------------------------------------
// The collision stage the solver calls after every mass-spring update

struct CollisionStats {
  // Contacts: overlapping pairs with at least one free particle (pairs of two fixed particles cannot be resolved).
  int contacts = 0;
  int muscle_muscle_contacts = 0;
  int muscle_bone_contacts = 0;
  // Remaining penetration depth r_a + r_b - |c_a - c_b| over those contacts (metres), filled by measure().
  double max_penetration_muscle_muscle_m = 0, mean_penetration_muscle_muscle_m = 0;
  double max_penetration_muscle_bone_m = 0, mean_penetration_muscle_bone_m = 0;
  // Wall time accumulated over resolve() calls since construction or resetTiming().
  double muscle_cd_ms = 0;  // muscle-muscle broad and narrow phase
  double bone_cd_ms = 0;    // muscle-bone broad and narrow phase
  double response_ms = 0;   // gathering sphere centres and applying the summed displacements
  long resolve_calls = 0;
  int bones_skipped = 0;    // in the last resolve(): bones whose spheres reach no muscle
};

class CollisionWorld {
 public:
  // Muscle spheres: boundary particles with radius > 0 (call assignCollisionRadii first). Bone spheres from
  // boneSpheresOneRing(bones[i].surface); bone i is index i of `bones` (and of setBoneTransforms).
  CollisionWorld(const MassSpringSystem& system, const std::vector<Bone>& bones, CollisionSettings settings = {});
  // Same with bone sphere sets given directly (rest frame), e.g. from a cache or a synthetic benchmark.
  CollisionWorld(const MassSpringSystem& system, std::vector<SphereSet> bone_spheres_rest,
                 CollisionSettings settings = {}, std::vector<std::string> bone_names = {});
  ~CollisionWorld();
  CollisionWorld(const CollisionWorld&) = delete;
  CollisionWorld& operator=(const CollisionWorld&) = delete;

  // Rigid transform of every bone from rest to the current pose, by bone index. Call once per solve (before it).
  // Throws std::invalid_argument on a size mismatch.
  void setBoneTransforms(const std::vector<Eigen::Isometry3d>& per_bone_index);
  // Same, by bone name (bones missing from the pose stay at rest).
  void setPose(const Pose& pose);

  // One collision pass: detect, accumulate, apply, zero the velocity of collided particles. Returns the number of
  // contacts resolved. Matches VerletSolver's AfterUpdateHook. Allocates nothing once buffers have grown.
  int resolve(ParticleState& state);

  // Contacts and remaining penetration in `state` (does not change it); timing fields are the accumulated ones.
  CollisionStats measure(const ParticleState& state) const;

  const CollisionStats& accumulatedStats() const { return stats_; }
  void resetTiming();

  const CollisionSettings& settings() const { return settings_; }
  const std::vector<int>& boneSphereCounts() const { return bone_sphere_counts_; }
  const SphereSet& boneSpheresRest(int bone) const;
  int muscleSphereCount() const;  // boundary particles taking part in collision, all muscles
  std::int64_t lastPairTests() const { return last_pairs_found_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  CollisionSettings settings_;
  CollisionStats stats_;
  std::vector<int> bone_sphere_counts_;
  std::int64_t last_pairs_found_ = 0;
};

}  // namespace muscle_deformation
