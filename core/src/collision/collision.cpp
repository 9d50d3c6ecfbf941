// The collision stage: muscle-muscle and muscle-bone sphere collision with the seeds' response (thesis 4.3).
#include "muscle_deformation/core/collision/collision.hpp"

#include "muscle_deformation/core/base/stopwatch.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

namespace muscle_deformation {

namespace {

using Clock = std::chrono::steady_clock;

bool boxesOverlap(const AlignedBox& a, const AlignedBox& b, double margin = 0.0) {
  if (a.empty() || b.empty()) return false;
  return (a.min.array() - margin <= b.max.array()).all() && (b.min.array() <= a.max.array() + margin).all();
}

// Unit direction from b to a; coincident centres get a fixed axis so the response stays deterministic.
Eigen::Vector3d separationDirection(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double& distance) {
  const Eigen::Vector3d v = a - b;
  distance = v.norm();
  if (distance > 0.0) return v / distance;
  return Eigen::Vector3d::UnitX();
}

// measureListed checks up to this many particles that moved further than the search's margin against every sphere
// alone; with more, searching again costs less.
constexpr int kMostParticlesCheckedAlone = 64;

struct PenetrationSum {
  int count = 0;
  double max = 0, sum = 0;
  void add(double depth) {
    ++count;
    max = std::max(max, depth);
    sum += depth;
  }
  double mean() const { return count > 0 ? sum / count : 0.0; }
};

// The accumulated timing of `timed` with the contacts and penetrations measured.
CollisionStats statsOf(const CollisionStats& timed, const PenetrationSum& muscle_sum, const PenetrationSum& bone_sum,
                       int bones_skipped) {
  CollisionStats result = timed;
  result.muscle_muscle_contacts = muscle_sum.count;
  result.muscle_bone_contacts = bone_sum.count;
  result.contacts = muscle_sum.count + bone_sum.count;
  result.max_penetration_muscle_muscle_m = muscle_sum.max;
  result.mean_penetration_muscle_muscle_m = muscle_sum.mean();
  result.max_penetration_muscle_bone_m = bone_sum.max;
  result.mean_penetration_muscle_bone_m = bone_sum.mean();
  result.bones_skipped = bones_skipped;
  return result;
}

}  // namespace

struct CollisionWorld::Impl {
  const MassSpringSystem& system;
  int muscle_count = 0;
  int bone_count = 0;

  // Muscle objects (broad-phase ids 0 .. muscle_count-1): the particle behind each sphere and current spheres.
  std::vector<std::vector<std::int32_t>> sphere_particle;
  std::vector<std::vector<std::uint8_t>> sphere_fixed;
  std::vector<std::int32_t> sphere_index_of_particle;  // its index in its muscle's sphere set; -1: no sphere
  std::vector<SphereSet> muscle_spheres;  // radii grown by `inflation` while contacts are found with a margin
  std::vector<Eigen::VectorXd> muscle_radius;  // the spheres' own radii
  double inflation = 0;
  std::vector<AlignedBox> muscle_box;
  bool rebuild_muscle_hierarchies = false;  // set by a new pose, consumed by the next gather

  // Bone objects (broad-phase ids muscle_count + b): fixed spheres, rest frame and current pose.
  std::vector<std::string> bone_names;
  std::vector<SphereSet> bone_rest;
  std::vector<SphereSet> bone_world;
  std::vector<AlignedBox> bone_box;
  std::vector<Eigen::Isometry3d> bone_transform;

  // Bone objects as distance fields (empty with sphere proxies): the free particles, each one's clearance from each
  // bone (its radius, or its rest distance where smaller), and each field's reach in the current pose.
  std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields;
  std::vector<std::int32_t> field_particles;
  std::vector<std::int32_t> field_index_of_particle;  // its index in field_particles; -1: none (a fixed particle)
  std::vector<Eigen::VectorXd> field_clearance;  // [bone][k] for particle field_particles[k]
  std::vector<AlignedBox> field_reach;           // [bone], world frame
  int closer_than_radius_at_rest = 0;
  CollisionWorld::RestPenetration deepest_at_rest;
  // What the last read of each (bone, particle) proved (seeded with the rest distances): a particle is read again only
  // once it may have come within reach. Skipping is exact, the contacts found are the same.
  mutable std::vector<FieldReadCache> field_reads;  // [bone], indexed like field_particles

  std::unique_ptr<BroadPhase> broad;
  std::vector<SpherePair> pairs;
  std::vector<int> muscle_ids;                  // broad-phase ids of the muscles: 0 .. muscle_count-1
  std::vector<std::uint8_t> muscle_test_pair;   // muscle_count^2: bounds overlap this iteration
  std::vector<ObjectSpherePair> muscle_pairs;

  // What the last findContacts listed, with its margin and the positions it searched at, kept so that measureListed()
  // can measure the penetrations over them alone while no particle has since moved as far as the margin; cleared when
  // the bones move.
  std::vector<ContactSet::Pair> listed_pairs;
  std::vector<ContactSet::Obstacle> listed_obstacles;
  std::vector<std::pair<int, Eigen::Index>> listed_field;  // (bone, index into field_particles)
  Eigen::Matrix3Xd listed_position;
  double listed_margin = 0;
  bool has_listed = false;
  std::vector<std::int32_t> far_particles;  // measureListed's scratch: moved at least the margin since, ascending
  // findContacts' scratch: the bone fields' contacts, found beside the muscle pairs and entered after them.
  struct FieldContact {
    std::int32_t particle;
    Eigen::Vector3d point, normal;
    int bone;
    Eigen::Index k;
  };
  std::vector<FieldContact> field_found;

  // Response accumulators, per particle; only touched entries are reset after each pass.
  Eigen::Matrix3Xd displacement;
  std::vector<std::int32_t> contact_count;
  std::vector<std::int32_t> touched;

  Impl(const MassSpringSystem& s, std::vector<SphereSet> bones, std::vector<std::string> names,
       const CollisionSettings& settings)
      : system(s), bone_names(std::move(names)), bone_rest(std::move(bones)) {
    muscle_count = system.muscleCount();
    bone_count = static_cast<int>(bone_rest.size());
    const Eigen::Index n = system.particleCount();
    if (system.radius.size() != n || static_cast<Eigen::Index>(system.is_boundary.size()) != n ||
        static_cast<Eigen::Index>(system.is_fixed.size()) != n ||
        static_cast<int>(system.muscle_begin.size()) != muscle_count + 1)
      throw std::invalid_argument(
          "CollisionWorld: the mass-spring system's radius, is_boundary, is_fixed or muscle_begin arrays do not match "
          "its particle and muscle counts (call assignCollisionRadii after building the system)");
    if (bone_names.empty()) {
      for (int b = 0; b < bone_count; ++b) bone_names.push_back("bone " + std::to_string(b));
    } else if (static_cast<int>(bone_names.size()) != bone_count) {
      throw std::invalid_argument("CollisionWorld: bone name count differs from bone sphere set count");
    }
    broad = makeBroadPhase(settings);

    sphere_particle.resize(static_cast<std::size_t>(muscle_count));
    sphere_fixed.resize(static_cast<std::size_t>(muscle_count));
    muscle_spheres.resize(static_cast<std::size_t>(muscle_count));
    muscle_box.resize(static_cast<std::size_t>(muscle_count));
    sphere_index_of_particle.assign(static_cast<std::size_t>(n), -1);
    for (int m = 0; m < muscle_count; ++m) {
      auto& particles = sphere_particle[static_cast<std::size_t>(m)];
      for (std::int32_t p = system.muscle_begin[static_cast<std::size_t>(m)];
           p < system.muscle_begin[static_cast<std::size_t>(m) + 1]; ++p)
        if (system.is_boundary[static_cast<std::size_t>(p)] && system.radius[p] > 0.0) particles.push_back(p);
      SphereSet& spheres = muscle_spheres[static_cast<std::size_t>(m)];
      spheres.resize(static_cast<Eigen::Index>(particles.size()));
      for (std::size_t k = 0; k < particles.size(); ++k) {
        sphere_index_of_particle[static_cast<std::size_t>(particles[k])] = static_cast<std::int32_t>(k);
        spheres.centre.col(static_cast<Eigen::Index>(k)) = system.rest_position.col(particles[k]);
        spheres.radius[static_cast<Eigen::Index>(k)] = system.radius[particles[k]];
        sphere_fixed[static_cast<std::size_t>(m)].push_back(system.is_fixed[static_cast<std::size_t>(particles[k])]);
      }
      muscle_radius.push_back(spheres.radius);
      broad->update(m, spheres, true);
    }

    bone_world = bone_rest;
    bone_box.resize(static_cast<std::size_t>(bone_count));
    bone_transform.assign(static_cast<std::size_t>(bone_count), Eigen::Isometry3d::Identity());
    for (int b = 0; b < bone_count; ++b) {
      if (bone_rest[static_cast<std::size_t>(b)].radius.size() != bone_rest[static_cast<std::size_t>(b)].size())
        throw std::invalid_argument("CollisionWorld: bone '" + bone_names[static_cast<std::size_t>(b)] +
                                    "' sphere set has different centre and radius counts");
      bone_box[static_cast<std::size_t>(b)] = sphereBounds(bone_world[static_cast<std::size_t>(b)]);
      broad->update(muscle_count + b, bone_world[static_cast<std::size_t>(b)], true);
    }

    for (int m = 0; m < muscle_count; ++m) muscle_ids.push_back(m);
    muscle_test_pair.assign(static_cast<std::size_t>(muscle_count) * static_cast<std::size_t>(muscle_count), 0);
    displacement = Eigen::Matrix3Xd::Zero(3, n);
    contact_count.assign(static_cast<std::size_t>(n), 0);
    touched.reserve(static_cast<std::size_t>(n));
  }

  void setFields(std::vector<std::shared_ptr<const BoneDistanceField>> fields) {
    bone_fields = std::move(fields);
    field_index_of_particle.assign(static_cast<std::size_t>(system.particleCount()), -1);
    for (Eigen::Index p = 0; p < system.particleCount(); ++p)
      if (!system.is_fixed[static_cast<std::size_t>(p)]) {
        field_index_of_particle[static_cast<std::size_t>(p)] = static_cast<std::int32_t>(field_particles.size());
        field_particles.push_back(static_cast<std::int32_t>(p));
      }
    std::vector<std::uint8_t> closer(static_cast<std::size_t>(system.particleCount()), 0);
    for (std::size_t b = 0; b < bone_fields.size(); ++b) {
      if (!bone_fields[b]) throw std::invalid_argument("CollisionWorld: bone '" + bone_names[b] + "' has no distance field");
      const BoneDistanceField::Probe probe = bone_fields[b]->probe();
      const Eigen::Index count = static_cast<Eigen::Index>(field_particles.size());
      Eigen::VectorXd clearance(count);
      FieldReadCache reads(count);
      for (std::size_t k = 0; k < field_particles.size(); ++k) {
        const std::int32_t p = field_particles[k];
        const Eigen::Index kk = static_cast<Eigen::Index>(k);
        const double radius = system.radius[p];
        const double at_rest = probe.distance(system.rest_position.col(p));
        clearance[kk] = std::min(radius, at_rest);
        if (at_rest < radius) closer[static_cast<std::size_t>(p)] = 1;
        if (-at_rest > deepest_at_rest.depth_m) deepest_at_rest = {-at_rest, p, static_cast<int>(b)};
        reads.remember(kk, system.rest_position.col(p), at_rest);
      }
      field_clearance.push_back(std::move(clearance));
      field_reads.push_back(std::move(reads));
      field_reach.push_back(bone_fields[b]->reach());
    }
    for (const std::uint8_t c : closer) closer_than_radius_at_rest += c;
  }

  // Every free particle within `margin` of its clearance from a bone field: visit(particle, depth, normal, bone, k)
  // with depth = clearance - distance (> 0: too close), the field's outward unit normal in the world frame, the bone and
  // the particle's index in field_particles.
  template <class Visit>
  int forEachFieldContact(const ParticleState& state, double margin, Visit&& visit) const {
    int contacts = 0;
    for (std::size_t b = 0; b < bone_fields.size(); ++b) {
      const BoneDistanceField::Probe probe = bone_fields[b]->probe();
      const Eigen::Isometry3d to_rest = bone_transform[b].inverse();
      const Eigen::Matrix3d rotation = bone_transform[b].linear();
      const AlignedBox& reach = field_reach[b];
      const Eigen::VectorXd& clearance = field_clearance[b];
      FieldReadCache& reads = field_reads[b];
      for (std::size_t k = 0; k < field_particles.size(); ++k) {
        const std::int32_t p = field_particles[k];
        const Eigen::Index kk = static_cast<Eigen::Index>(k);
        const Eigen::Vector3d x = state.position.col(p);
        const double clear = clearance[kk];
        const Eigen::Vector3d local = to_rest * x;
        if (reads.provenBeyond(kk, local, clear + margin)) continue;
        if ((x.array() < reach.min.array()).any() || (x.array() > reach.max.array()).any()) continue;
        Eigen::Vector3d gradient;
        double distance = 0;
        const bool closer = probe.closerThan(local, clear + margin, distance, gradient);
        reads.remember(kk, local, distance);
        if (!closer) continue;
        const double depth = clear - distance;
        if (depth <= -margin) continue;
        const double length = gradient.norm();
        if (!(length > 1e-9)) continue;  // on the field's medial axis or beyond its band: no way out is defined
        visit(p, depth, Eigen::Vector3d(rotation * gradient / length), static_cast<int>(b), kk);
        ++contacts;
      }
    }
    return contacts;
  }

  // The depth of field_particles[k] in bone b at `x`, as forEachFieldContact finds it without a margin (0: none).
  double fieldDepth(int b, Eigen::Index k, const Eigen::Vector3d& x) const {
    const std::size_t ub = static_cast<std::size_t>(b);
    const AlignedBox& reach = field_reach[ub];
    if ((x.array() < reach.min.array()).any() || (x.array() > reach.max.array()).any()) return 0;
    const double clear = field_clearance[ub][k];
    const Eigen::Vector3d local = bone_transform[ub].inverse() * x;
    Eigen::Vector3d gradient;
    double distance = 0;
    if (!bone_fields[ub]->probe().closerThan(local, clear, distance, gradient)) return 0;
    const double depth = clear - distance;
    return depth > 0 && gradient.norm() > 1e-9 ? depth : 0;
  }

  // Grows every muscle sphere by `margin` for detection (pairs that may touch within a step), or restores it (0).
  void inflate(double margin) {
    if (margin == inflation) return;
    for (int m = 0; m < muscle_count; ++m)
      muscle_spheres[static_cast<std::size_t>(m)].radius =
          muscle_radius[static_cast<std::size_t>(m)].array() + margin;
    inflation = margin;
    rebuild_muscle_hierarchies = true;
  }

  void gatherMuscles(const ParticleState& state) {
    if (state.position.cols() != system.particleCount())
      throw std::invalid_argument("CollisionWorld: state has " + std::to_string(state.position.cols()) +
                                  " particles, the system " + std::to_string(system.particleCount()));
    for (int m = 0; m < muscle_count; ++m) {
      const auto& particles = sphere_particle[static_cast<std::size_t>(m)];
      SphereSet& spheres = muscle_spheres[static_cast<std::size_t>(m)];
      AlignedBox box;
      for (std::size_t k = 0; k < particles.size(); ++k) {
        const Eigen::Index kk = static_cast<Eigen::Index>(k);
        spheres.centre.col(kk) = state.position.col(particles[k]);
        const double r = spheres.radius[kk];
        box.min = box.min.cwiseMin((spheres.centre.col(kk).array() - r).matrix());
        box.max = box.max.cwiseMax((spheres.centre.col(kk).array() + r).matrix());
      }
      muscle_box[static_cast<std::size_t>(m)] = box;
      broad->update(m, spheres, rebuild_muscle_hierarchies);
    }
    rebuild_muscle_hierarchies = false;
  }

  // Muscle pairs whose sphere bounds overlap; the others cannot touch this iteration.
  void findMusclePairs() {
    const std::size_t n = static_cast<std::size_t>(muscle_count);
    for (std::size_t a = 0; a < n; ++a)
      for (std::size_t b = a + 1; b < n; ++b) muscle_test_pair[a * n + b] = boxesOverlap(muscle_box[a], muscle_box[b]);
    broad->findPairsAmong(muscle_ids, muscle_test_pair, muscle_pairs);
  }

  bool boneReachesAnyMuscle(int b, double margin) const {
    for (int m = 0; m < muscle_count; ++m)
      if (boxesOverlap(bone_box[static_cast<std::size_t>(b)], muscle_box[static_cast<std::size_t>(m)], margin))
        return true;
    return false;
  }

  // For every bone within reach of some muscle and every muscle whose bounds overlap it, fills `pairs` with their
  // overlapping spheres and calls visit(muscle, bone). Returns the number of bones skipped as out of reach.
  template <class Visit>
  int forEachMuscleBoneOverlap(double margin, bool skip_out_of_reach, Visit&& visit) {
    int skipped = 0;
    for (int b = 0; b < bone_count; ++b) {
      if (skip_out_of_reach && !boneReachesAnyMuscle(b, margin)) {
        ++skipped;
        continue;
      }
      for (int m = 0; m < muscle_count; ++m) {
        if (skip_out_of_reach &&
            !boxesOverlap(bone_box[static_cast<std::size_t>(b)], muscle_box[static_cast<std::size_t>(m)]))
          continue;
        broad->findPairs(m, muscle_count + b, pairs);
        visit(m, b);
      }
    }
    return skipped;
  }


  void addDisplacement(std::int32_t particle, const Eigen::Vector3d& d) {
    if (contact_count[static_cast<std::size_t>(particle)]++ == 0) touched.push_back(particle);
    displacement.col(particle) += d;
  }

  // Seeds' response for one muscle-muscle pair; returns whether anything was moved.
  bool respondMuscleMuscle(int a, int b, const SpherePair& pair) {
    const std::size_t ua = static_cast<std::size_t>(a), ub = static_cast<std::size_t>(b);
    const bool fixed_a = sphere_fixed[ua][static_cast<std::size_t>(pair.first)];
    const bool fixed_b = sphere_fixed[ub][static_cast<std::size_t>(pair.second)];
    if (fixed_a && fixed_b) return false;  // two attachments: neither may move
    const SphereSet& sa = muscle_spheres[ua];
    const SphereSet& sb = muscle_spheres[ub];
    double distance = 0;
    const Eigen::Vector3d dir = separationDirection(sa.centre.col(pair.first), sb.centre.col(pair.second), distance);
    const double overlap = sa.radius[pair.first] + sb.radius[pair.second] - distance;
    const std::int32_t pa = sphere_particle[ua][static_cast<std::size_t>(pair.first)];
    const std::int32_t pb = sphere_particle[ub][static_cast<std::size_t>(pair.second)];
    if (fixed_b) {
      addDisplacement(pa, dir * overlap);
    } else if (fixed_a) {
      addDisplacement(pb, -dir * overlap);
    } else {
      addDisplacement(pa, dir * (0.5 * overlap));
      addDisplacement(pb, -dir * (0.5 * overlap));
    }
    return true;
  }

  bool respondMuscleBone(int m, int b, const SpherePair& pair) {
    const std::size_t um = static_cast<std::size_t>(m);
    if (sphere_fixed[um][static_cast<std::size_t>(pair.first)]) return false;  // attachment against its bone
    const SphereSet& sm = muscle_spheres[um];
    const SphereSet& sb = bone_world[static_cast<std::size_t>(b)];
    double distance = 0;
    const Eigen::Vector3d dir = separationDirection(sm.centre.col(pair.first), sb.centre.col(pair.second), distance);
    const double overlap = sm.radius[pair.first] + sb.radius[pair.second] - distance;
    addDisplacement(sphere_particle[um][static_cast<std::size_t>(pair.first)], dir * overlap);
    return true;
  }

  double penetration(const SphereSet& a, std::int32_t i, const SphereSet& b, std::int32_t j) const {
    return a.radius[i] + b.radius[j] - (a.centre.col(i) - b.centre.col(j)).norm();
  }
};

CollisionWorld::CollisionWorld(const MassSpringSystem& system, const std::vector<Bone>& bones,
                               CollisionSettings settings)
    : settings_(settings) {
  std::vector<SphereSet> spheres;
  std::vector<std::string> names;
  spheres.reserve(bones.size());
  for (const Bone& bone : bones) {
    spheres.push_back(boneSpheresOneRing(bone.surface, settings_.bone_sphere_rule));
    names.push_back(bone.name);
  }
  impl_ = std::make_unique<Impl>(system, std::move(spheres), std::move(names), settings_);
  for (const SphereSet& s : impl_->bone_rest) bone_sphere_counts_.push_back(static_cast<int>(s.size()));
}

CollisionWorld::CollisionWorld(const MassSpringSystem& system, std::vector<SphereSet> bone_spheres_rest,
                               CollisionSettings settings, std::vector<std::string> bone_names)
    : settings_(settings) {
  impl_ = std::make_unique<Impl>(system, std::move(bone_spheres_rest), std::move(bone_names), settings_);
  for (const SphereSet& s : impl_->bone_rest) bone_sphere_counts_.push_back(static_cast<int>(s.size()));
}

CollisionWorld::CollisionWorld(const MassSpringSystem& system,
                               std::vector<std::shared_ptr<const BoneDistanceField>> bone_fields,
                               CollisionSettings settings, std::vector<std::string> bone_names)
    : settings_(settings) {
  if (bone_names.size() != bone_fields.size())
    throw std::invalid_argument("CollisionWorld: " + std::to_string(bone_names.size()) + " bone names for " +
                                std::to_string(bone_fields.size()) + " bone distance fields");
  // The broad phase sees each bone as an empty sphere set: muscle-bone pairs come from the fields.
  impl_ = std::make_unique<Impl>(system, std::vector<SphereSet>(bone_fields.size()), std::move(bone_names), settings_);
  impl_->setFields(std::move(bone_fields));
  bone_sphere_counts_.assign(impl_->bone_fields.size(), 0);
}

CollisionWorld::~CollisionWorld() = default;

bool CollisionWorld::everyParticleCollides() const { return !impl_->bone_fields.empty(); }

int CollisionWorld::particlesCloserThanRadiusAtRest() const { return impl_->closer_than_radius_at_rest; }
CollisionWorld::RestPenetration CollisionWorld::deepestParticleInsideBoneAtRest() const {
  return impl_->deepest_at_rest;
}

void CollisionWorld::setBoneTransforms(const std::vector<Eigen::Isometry3d>& per_bone_index) {
  Impl& w = *impl_;
  if (static_cast<int>(per_bone_index.size()) != w.bone_count)
    throw std::invalid_argument("CollisionWorld::setBoneTransforms: " + std::to_string(per_bone_index.size()) +
                                " transforms for " + std::to_string(w.bone_count) + " bones");
  // A new pose starts a new solve: muscle hierarchies are rebuilt once from the pre-transformed particles and only
  // refitted during the solve's iterations, as in the seeds (a refitted tree grows loose as the shape drifts).
  w.rebuild_muscle_hierarchies = true;
  w.has_listed = false;  // the listed obstacles and field contacts belong to the previous pose
  for (int b = 0; b < w.bone_count; ++b) {
    const std::size_t ub = static_cast<std::size_t>(b);
    const Eigen::Isometry3d& t = per_bone_index[ub];
    // Unchanged pose: keep the bone's hierarchy or grid (the seeds never update bone structures within a step).
    if (t.matrix() == w.bone_transform[ub].matrix()) continue;
    w.bone_transform[ub] = t;
    if (!w.bone_fields.empty()) w.field_reach[ub] = w.bone_fields[ub]->reachIn(t);
    w.bone_world[ub].centre = t * w.bone_rest[ub].centre;
    w.bone_box[ub] = sphereBounds(w.bone_world[ub]);
    w.broad->update(w.muscle_count + b, w.bone_world[ub], true);
  }
}

void CollisionWorld::setPose(const Pose& pose) {
  std::vector<Eigen::Isometry3d> transforms;
  transforms.reserve(impl_->bone_names.size());
  for (const std::string& name : impl_->bone_names) transforms.push_back(pose.transformOf(name));
  setBoneTransforms(transforms);
}

int CollisionWorld::resolve(ParticleState& state) {
  Impl& w = *impl_;
  w.inflate(0);
  auto start = Clock::now();
  w.gatherMuscles(state);
  stats_.response_ms += millisecondsSince(start);

  int contacts = 0, muscle_contacts = 0, bone_contacts = 0;
  std::int64_t pairs_found = 0;

  start = Clock::now();
  w.findMusclePairs();
  pairs_found += static_cast<std::int64_t>(w.muscle_pairs.size());
  for (const ObjectSpherePair& p : w.muscle_pairs)
    muscle_contacts += w.respondMuscleMuscle(p.first_object, p.second_object, {p.first, p.second}) ? 1 : 0;
  stats_.muscle_cd_ms += millisecondsSince(start);

  start = Clock::now();
  const int skipped = w.forEachMuscleBoneOverlap(
      settings_.bone_reach_margin_m, settings_.skip_bones_out_of_reach, [&](int m, int b) {
    pairs_found += static_cast<std::int64_t>(w.pairs.size());
    for (const SpherePair& pair : w.pairs) bone_contacts += w.respondMuscleBone(m, b, pair) ? 1 : 0;
  });
  bone_contacts += w.forEachFieldContact(
      state, 0.0, [&](std::int32_t particle, double depth, const Eigen::Vector3d& normal, int, Eigen::Index) {
        w.addDisplacement(particle, depth * normal);
      });
  stats_.bone_cd_ms += millisecondsSince(start);

  // Apply the superposition of every particle's displacements, then stop the particles that collided.
  start = Clock::now();
  for (const std::int32_t p : w.touched) {
    state.position.col(p) += w.displacement.col(p);
    state.previous_position.col(p) = state.position.col(p);
    w.displacement.col(p).setZero();
    w.contact_count[static_cast<std::size_t>(p)] = 0;
  }
  w.touched.clear();
  stats_.response_ms += millisecondsSince(start);

  contacts = muscle_contacts + bone_contacts;
  stats_.contacts = contacts;
  stats_.muscle_muscle_contacts = muscle_contacts;
  stats_.muscle_bone_contacts = bone_contacts;
  stats_.bones_skipped = skipped;
  ++stats_.resolve_calls;
  last_pairs_found_ = pairs_found;
  return contacts;
}

void CollisionWorld::findContacts(const ParticleState& state, ContactSet& contacts, double margin_m) {
  Impl& w = *impl_;
  contacts.clear();
  auto start = Clock::now();
  w.inflate(std::max(0.0, margin_m));
  w.gatherMuscles(state);
  stats_.response_ms += millisecondsSince(start);

  // The muscle pairs (the octree's traversal) and the bone fields' contacts read the same positions and write apart:
  // on two threads they run side by side, each into its own list, and the lists are the same as one after the other.
  std::vector<Impl::FieldContact>& field_found = w.field_found;
  field_found.clear();
  double muscle_ms = 0, field_ms = 0;
  const auto findMuscleContacts = [&] {
    const auto muscle_start = Clock::now();
    w.findMusclePairs();
    for (const ObjectSpherePair& p : w.muscle_pairs) {
      const std::size_t a = static_cast<std::size_t>(p.first_object), b = static_cast<std::size_t>(p.second_object);
      if (w.sphere_fixed[a][static_cast<std::size_t>(p.first)] && w.sphere_fixed[b][static_cast<std::size_t>(p.second)])
        continue;
      contacts.pairs.push_back({w.sphere_particle[a][static_cast<std::size_t>(p.first)],
                                w.sphere_particle[b][static_cast<std::size_t>(p.second)],
                                w.muscle_radius[a][p.first] + w.muscle_radius[b][p.second]});
    }
    muscle_ms = millisecondsSince(muscle_start);
  };
  const auto findFieldContacts = [&] {
    const auto field_start = Clock::now();
    w.forEachFieldContact(state, std::max(0.0, margin_m),
                          [&](std::int32_t particle, double depth, const Eigen::Vector3d& normal, int bone,
                              Eigen::Index k) {
      field_found.push_back({particle, Eigen::Vector3d(state.position.col(particle) + depth * normal), normal, bone, k});
    });
    field_ms = millisecondsSince(field_start);
  };
  if (threads_ > 1 && !w.bone_fields.empty()) {
#pragma omp parallel sections num_threads(2)
    {
#pragma omp section
      findMuscleContacts();
#pragma omp section
      findFieldContacts();
    }
  } else {
    findMuscleContacts();
    findFieldContacts();
  }
  std::int64_t pairs_found = static_cast<std::int64_t>(w.muscle_pairs.size());
  const int muscle_contacts = static_cast<int>(contacts.pairs.size());
  stats_.muscle_cd_ms += muscle_ms;

  start = Clock::now();
  int bone_contacts = 0;
  const int skipped = w.forEachMuscleBoneOverlap(
      settings_.bone_reach_margin_m, settings_.skip_bones_out_of_reach, [&](int m, int b) {
    pairs_found += static_cast<std::int64_t>(w.pairs.size());
    const std::size_t um = static_cast<std::size_t>(m);
    const SphereSet& bone = w.bone_world[static_cast<std::size_t>(b)];
    for (const SpherePair& pair : w.pairs) {
      if (w.sphere_fixed[um][static_cast<std::size_t>(pair.first)]) continue;  // attachment against its bone
      contacts.obstacles.push_back({w.sphere_particle[um][static_cast<std::size_t>(pair.first)],
                                    bone.centre.col(pair.second),
                                    w.muscle_radius[um][pair.first] + bone.radius[pair.second]});
      ++bone_contacts;
    }
  });
  w.listed_field.clear();
  for (const Impl::FieldContact& found : field_found) {
    contacts.half_spaces.push_back({found.particle, found.point, found.normal});
    w.listed_field.emplace_back(found.bone, found.k);
  }
  bone_contacts += static_cast<int>(field_found.size());
  stats_.bone_cd_ms += millisecondsSince(start) + field_ms;

  stats_.contacts = muscle_contacts + bone_contacts;
  stats_.muscle_muscle_contacts = muscle_contacts;
  stats_.muscle_bone_contacts = bone_contacts;
  stats_.bones_skipped = skipped;
  ++stats_.resolve_calls;
  last_pairs_found_ = pairs_found;
  w.listed_pairs.assign(contacts.pairs.begin(), contacts.pairs.end());
  w.listed_obstacles.assign(contacts.obstacles.begin(), contacts.obstacles.end());
  w.listed_position = state.position;
  w.listed_margin = std::max(0.0, margin_m);
  w.has_listed = true;
}

CollisionStats CollisionWorld::measure(const ParticleState& state) const {
  Impl& w = *impl_;  // the broad phase's trees and grids are caches: refreshing them does not change the world
  w.inflate(0);
  w.gatherMuscles(state);
  PenetrationSum muscle_sum, bone_sum;
  w.findMusclePairs();
  for (const ObjectSpherePair& p : w.muscle_pairs) {
    const std::size_t a = static_cast<std::size_t>(p.first_object), b = static_cast<std::size_t>(p.second_object);
    if (w.sphere_fixed[a][static_cast<std::size_t>(p.first)] && w.sphere_fixed[b][static_cast<std::size_t>(p.second)])
      continue;
    muscle_sum.add(w.penetration(w.muscle_spheres[a], p.first, w.muscle_spheres[b], p.second));
  }
  const int skipped = w.forEachMuscleBoneOverlap(
      settings_.bone_reach_margin_m, settings_.skip_bones_out_of_reach, [&](int m, int b) {
    for (const SpherePair& pair : w.pairs) {
      if (w.sphere_fixed[static_cast<std::size_t>(m)][static_cast<std::size_t>(pair.first)]) continue;
      bone_sum.add(w.penetration(w.muscle_spheres[static_cast<std::size_t>(m)], pair.first,
                                 w.bone_world[static_cast<std::size_t>(b)], pair.second));
    }
  });
  w.forEachFieldContact(state, 0.0, [&](std::int32_t, double depth, const Eigen::Vector3d&, int, Eigen::Index) {
    bone_sum.add(depth);
  });
  return statsOf(stats_, muscle_sum, bone_sum, skipped);
}

CollisionStats CollisionWorld::measureListed(const ParticleState& state) const {
  Impl& w = *impl_;  // scratch only: what measureListed finds does not change the world
  const Eigen::Matrix3Xd& x = state.position;
  if (!w.has_listed || x.cols() != w.listed_position.cols() || !(w.listed_margin > 0)) return measure(state);
  // A contact overlapping now that the search did not list has a particle that moved at least the margin since: the
  // search grew every sphere by it and reached the bones' fields that much further. Those few particles are checked
  // against everything here; when there are many (a jump) or bones are spheres, measure() searches again.
  const double margin_squared = w.listed_margin * w.listed_margin;
  w.far_particles.clear();
  for (Eigen::Index p = 0; p < x.cols(); ++p)
    if ((x.col(p) - w.listed_position.col(p)).squaredNorm() >= margin_squared) {
      if (static_cast<int>(w.far_particles.size()) == kMostParticlesCheckedAlone) return measure(state);
      w.far_particles.push_back(static_cast<std::int32_t>(p));
    }
  if (!w.far_particles.empty())
    for (const SphereSet& bone : w.bone_rest)
      if (bone.size() > 0) return measure(state);

  PenetrationSum muscle_sum, bone_sum;
  for (const ContactSet::Pair& pair : w.listed_pairs) {
    const double depth = pair.distance - (x.col(pair.first) - x.col(pair.second)).norm();
    if (depth > 0) muscle_sum.add(depth);
  }
  for (const ContactSet::Obstacle& obstacle : w.listed_obstacles) {
    const double depth = obstacle.distance - (x.col(obstacle.particle) - obstacle.centre).norm();
    if (depth > 0) bone_sum.add(depth);
  }
  for (const auto& [bone, k] : w.listed_field) {
    const double depth = w.fieldDepth(bone, k, x.col(w.field_particles[static_cast<std::size_t>(k)]));
    if (depth > 0) bone_sum.add(depth);
  }
  if (w.far_particles.empty()) return statsOf(stats_, muscle_sum, bone_sum, stats_.bones_skipped);

  // The far particles' contacts that were not listed (the listed ones are counted above).
  const auto is_far = [&](std::int32_t p) {
    return std::binary_search(w.far_particles.begin(), w.far_particles.end(), p);
  };
  std::vector<std::pair<std::int32_t, std::int32_t>> listed_far_pairs;
  for (const ContactSet::Pair& pair : w.listed_pairs)
    if (is_far(pair.first) || is_far(pair.second))
      listed_far_pairs.emplace_back(std::min(pair.first, pair.second), std::max(pair.first, pair.second));
  std::sort(listed_far_pairs.begin(), listed_far_pairs.end());
  std::vector<std::pair<int, std::int32_t>> listed_far_fields;  // (bone, particle)
  for (const auto& [bone, k] : w.listed_field) {
    const std::int32_t p = w.field_particles[static_cast<std::size_t>(k)];
    if (is_far(p)) listed_far_fields.emplace_back(bone, p);
  }
  std::sort(listed_far_fields.begin(), listed_far_fields.end());
  for (const std::int32_t p : w.far_particles) {
    const std::size_t up = static_cast<std::size_t>(p);
    const std::int32_t k = w.field_index_of_particle.empty() ? -1 : w.field_index_of_particle[up];
    for (int b = 0; k >= 0 && b < static_cast<int>(w.bone_fields.size()); ++b) {
      if (std::binary_search(listed_far_fields.begin(), listed_far_fields.end(), std::make_pair(b, p))) continue;
      const double depth = w.fieldDepth(b, k, x.col(p));
      if (depth > 0) bone_sum.add(depth);
    }
    const std::int32_t i = w.sphere_index_of_particle[up];
    if (i < 0) continue;
    const int own = w.system.muscle_of[up];
    const double radius = w.muscle_radius[static_cast<std::size_t>(own)][i];
    for (int m = 0; m < w.muscle_count; ++m) {
      if (m == own) continue;
      const std::vector<std::int32_t>& others = w.sphere_particle[static_cast<std::size_t>(m)];
      const Eigen::VectorXd& other_radius = w.muscle_radius[static_cast<std::size_t>(m)];
      for (std::size_t j = 0; j < others.size(); ++j) {
        const std::int32_t q = others[j];
        const double depth = radius + other_radius[static_cast<Eigen::Index>(j)] - (x.col(p) - x.col(q)).norm();
        if (!(depth > 0)) continue;
        if (is_far(q) && q < p) continue;  // both far: counted once, from the lower index
        if (std::binary_search(listed_far_pairs.begin(), listed_far_pairs.end(),
                               std::make_pair(std::min(p, q), std::max(p, q))))
          continue;
        muscle_sum.add(depth);
      }
    }
  }
  return statsOf(stats_, muscle_sum, bone_sum, stats_.bones_skipped);
}

void CollisionWorld::resetTiming() {
  stats_.muscle_cd_ms = 0;
  stats_.bone_cd_ms = 0;
  stats_.response_ms = 0;
  stats_.resolve_calls = 0;
}

const SphereSet& CollisionWorld::boneSpheresRest(int bone) const {
  if (bone < 0 || bone >= impl_->bone_count)
    throw std::out_of_range("CollisionWorld::boneSpheresRest: no bone " + std::to_string(bone));
  return impl_->bone_rest[static_cast<std::size_t>(bone)];
}

int CollisionWorld::muscleSphereCount() const {
  int total = 0;
  for (const auto& particles : impl_->sphere_particle) total += static_cast<int>(particles.size());
  return total;
}

}  // namespace muscle_deformation
