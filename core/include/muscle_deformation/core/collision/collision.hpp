// Sphere-based collision handling between muscles and bones (thesis 4.3, GRAPP 2014 section 3.3), with bones either
// as the seeds' sphere sets or as signed distance fields.
//
// Every boundary particle of a muscle is a sphere; every bone is approximated by a fixed set of spheres. After each
// mass-spring update, overlapping spheres of different objects are pushed apart (half the overlap each, or the whole
// overlap for the free one when the other is fixed), displacements are summed per particle and applied after all
// tests, and every particle that collided loses its velocity. A muscle never collides with itself.
#pragma once

#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/collision/collision_broad_phase.hpp"
#include "muscle_deformation/core/collision/collision_settings.hpp"
#include "muscle_deformation/core/collision/collision_spheres.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/collision/contact_set.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace muscle_deformation {

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
  // Bones as signed distance fields (rest frame; shared, e.g. with the surface metrics): every free particle, interior
  // ones too, is kept its sphere radius outside each bone, or no deeper than it lay at rest where the data put it
  // closer (so the rest pose has no contact and no sphere is dropped). A muscle-bone contact is then a half-space: the
  // field linearised at the particle. Muscle-muscle contacts stay sphere pairs.
  CollisionWorld(const MassSpringSystem& system, std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields,
                 CollisionSettings settings, std::vector<std::string> bone_names);
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

  // The sphere pairs at `state` with at least one free particle that overlap or come within `margin_m` of touching, as
  // contacts for a solver that keeps them in its solve (block descent): a contact's energy is one-sided, so a pair
  // found within the margin costs nothing until it touches, and a particle that reaches it within a sweep meets it.
  // Does not change the state. Same detection as resolve(), timed alike.
  void findContacts(const ParticleState& state, ContactSet& contacts, double margin_m = 0.0);

  // Contacts and remaining penetration in `state` (does not change it); timing fields are the accumulated ones.
  CollisionStats measure(const ParticleState& state) const;
  // The same figures, measured over the contacts the last findContacts() listed when no particle has moved as far as
  // that call's margin since (then every contact now overlapping was listed: its spheres were grown by the margin),
  // and by measure() otherwise, or when nothing was listed since the bones last moved.
  CollisionStats measureListed(const ParticleState& state) const;

  const CollisionStats& accumulatedStats() const { return stats_; }
  void resetTiming();
  // Threads findContacts may use (>= 2: the muscle pairs and the bone fields' contacts are searched side by side; the
  // contacts found are the same). 1 by default.
  void setThreads(int threads) { threads_ = threads; }

  const CollisionSettings& settings() const { return settings_; }
  // True with bone distance fields: contacts may involve any free particle, not only those with a sphere radius.
  bool everyParticleCollides() const;
  // Free particles lying closer to a bone at rest than their radius (or inside it): they may not go deeper than that.
  int particlesCloserThanRadiusAtRest() const;
  // The free particle whose centre lies deepest inside a bone at rest (bone distance fields only): a segmentation's
  // muscle and bone that overlap put particles there, and the contacts keep them no deeper, never out.
  struct RestPenetration {
    double depth_m = 0;  // 0: no particle centre inside a bone at rest
    int particle = -1, bone = -1;
  };
  RestPenetration deepestParticleInsideBoneAtRest() const;
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
  int threads_ = 1;
};

}  // namespace muscle_deformation
