// Specification of the sphere collision stage (thesis 4.3, GRAPP 2014 section 3.3).
#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/model/collision_radii.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/core/solvers/verlet_solver.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <utility>
#include <vector>

namespace md = muscle_deformation;

namespace {

// One free or fixed boundary particle of a test scene.
struct TestParticle {
  int muscle;
  Eigen::Vector3d position;
  double radius;
  bool fixed = false;
};

// A mass-spring system with only what collision reads: positions, radii, flags and muscle ranges (no springs).
md::MassSpringSystem makeSystem(std::vector<TestParticle> particles, int muscle_count) {
  std::stable_sort(particles.begin(), particles.end(),
                   [](const TestParticle& a, const TestParticle& b) { return a.muscle < b.muscle; });
  md::MassSpringSystem s;
  const auto n = static_cast<Eigen::Index>(particles.size());
  s.rest_position.resize(3, n);
  s.mass = Eigen::VectorXd::Ones(n);
  s.radius.resize(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const TestParticle& p = particles[static_cast<std::size_t>(i)];
    s.rest_position.col(i) = p.position;
    s.radius[i] = p.radius;
    s.is_fixed.push_back(p.fixed ? 1 : 0);
    s.is_boundary.push_back(1);
    s.fixed_bone.push_back(md::kNoBone);
    s.muscle_of.push_back(p.muscle);
    s.fibre_of.push_back(0);
    s.sample_of.push_back(static_cast<std::int32_t>(i));
  }
  s.muscle_begin.assign(static_cast<std::size_t>(muscle_count) + 1, 0);
  for (const TestParticle& p : particles) ++s.muscle_begin[static_cast<std::size_t>(p.muscle) + 1];
  for (int m = 0; m < muscle_count; ++m) {
    s.muscle_begin[static_cast<std::size_t>(m) + 1] += s.muscle_begin[static_cast<std::size_t>(m)];
    s.muscle_name.push_back("muscle " + std::to_string(m));
  }
  return s;
}

md::SphereSet spheres(std::vector<std::pair<Eigen::Vector3d, double>> list) {
  md::SphereSet set;
  set.resize(static_cast<Eigen::Index>(list.size()));
  for (std::size_t k = 0; k < list.size(); ++k) {
    set.centre.col(static_cast<Eigen::Index>(k)) = list[k].first;
    set.radius[static_cast<Eigen::Index>(k)] = list[k].second;
  }
  return set;
}

md::CollisionSettings settingsFor(md::BroadPhaseKind kind) {
  md::CollisionSettings s;
  s.broad_phase = kind;
  return s;
}

// Random spheres in a box, radii log-uniform over a 50:1 range so both tiny and big spheres occur.
md::SphereSet randomSpheres(std::mt19937& rng, int count, double box_m, double r_min, double r_max) {
  std::uniform_real_distribution<double> coord(0.0, box_m);
  std::uniform_real_distribution<double> log_r(std::log(r_min), std::log(r_max));
  md::SphereSet set;
  set.resize(count);
  for (int i = 0; i < count; ++i) {
    set.centre.col(i) = Eigen::Vector3d(coord(rng), coord(rng), coord(rng));
    set.radius[i] = std::exp(log_r(rng));
  }
  return set;
}

std::vector<md::SpherePair> sorted(std::vector<md::SpherePair> pairs) {
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

// Unit icosphere: an icosahedron split `levels` times, vertices pushed onto the unit sphere. Outward winding.
md::TriangleMesh unitIcosphere(int levels) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                    {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<Eigen::Vector3i> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                    {11, 10, 2}, {10, 7, 6}, {7, 1, 8},   {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                                    {3, 8, 9},  {4, 9, 5},  {2, 4, 11},  {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int level = 0; level < levels; ++level) {
    std::map<std::pair<int, int>, int> midpoint;
    auto mid = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      auto it = midpoint.find(key);
      if (it != midpoint.end()) return it->second;
      v.push_back((v[static_cast<std::size_t>(a)] + v[static_cast<std::size_t>(b)]).normalized());
      const int index = static_cast<int>(v.size()) - 1;
      midpoint[key] = index;
      return index;
    };
    std::vector<Eigen::Vector3i> next;
    for (const auto& tri : f) {
      const int a = mid(tri[0], tri[1]), b = mid(tri[1], tri[2]), c = mid(tri[2], tri[0]);
      next.push_back({tri[0], a, c});
      next.push_back({tri[1], b, a});
      next.push_back({tri[2], c, b});
      next.push_back({a, b, c});
    }
    f = next;
  }
  md::TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(v.size()));
  for (std::size_t k = 0; k < v.size(); ++k) mesh.vertices.col(static_cast<Eigen::Index>(k)) = v[k];
  mesh.triangles.resize(3, static_cast<Eigen::Index>(f.size()));
  for (std::size_t k = 0; k < f.size(); ++k) mesh.triangles.col(static_cast<Eigen::Index>(k)) = f[k];
  return mesh;
}

// A flat square plate in the z = 0 plane, `cells` x `cells` quads split into triangles, normal +z.
md::TriangleMesh plate(double size_m, int cells) {
  md::TriangleMesh mesh;
  const int side = cells + 1;
  mesh.vertices.resize(3, side * side);
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j)
      mesh.vertices.col(i * side + j) = Eigen::Vector3d(size_m * i / cells - size_m / 2, size_m * j / cells - size_m / 2, 0);
  mesh.triangles.resize(3, 2 * cells * cells);
  int t = 0;
  for (int i = 0; i < cells; ++i)
    for (int j = 0; j < cells; ++j) {
      const int a = i * side + j, b = (i + 1) * side + j, c = (i + 1) * side + j + 1, d = i * side + j + 1;
      mesh.triangles.col(t++) = Eigen::Vector3i(a, b, c);
      mesh.triangles.col(t++) = Eigen::Vector3i(a, c, d);
    }
  return mesh;
}

// Rings of `per_ring` vertices of radius r around the z axis at the given heights (a cylinder's vertices).
md::TriangleMesh cylinderVertices(double r, const std::vector<double>& heights, int per_ring) {
  md::TriangleMesh mesh;
  mesh.vertices.resize(3, static_cast<Eigen::Index>(heights.size()) * per_ring);
  Eigen::Index k = 0;
  for (const double z : heights)
    for (int i = 0; i < per_ring; ++i) {
      const double a = 2.0 * M_PI * i / per_ring;
      mesh.vertices.col(k++) = Eigen::Vector3d(r * std::cos(a), r * std::sin(a), z);
    }
  return mesh;
}

const md::BroadPhaseKind kBothKinds[] = {md::BroadPhaseKind::octree, md::BroadPhaseKind::hash_grid};

}  // namespace

// ---------------------------------------------------------------------------------------------------------------
// Narrow phase and response

TEST(CollisionResponse, TwoTouchingSpheresStayPut) {
  for (const auto kind : kBothKinds) {
    const auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {1, {1.0, 0, 0}, 0.5}}, 2);
    md::CollisionWorld world(system, std::vector<md::SphereSet>{}, settingsFor(kind));
    auto state = md::restState(system);
    EXPECT_EQ(world.resolve(state), 0) << md::toString(kind);
    EXPECT_EQ(state.position, system.rest_position) << md::toString(kind);
  }
}

TEST(CollisionResponse, TwoOverlappingFreeSpheresEndExactlyTouching) {
  for (const auto kind : kBothKinds) {
    const auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {1, {0.6, 0.2, -0.1}, 0.3}}, 2);
    md::CollisionWorld world(system, std::vector<md::SphereSet>{}, settingsFor(kind));
    auto state = md::restState(system);
    EXPECT_EQ(world.resolve(state), 1);
    EXPECT_NEAR((state.position.col(0) - state.position.col(1)).norm(), 0.8, 1e-12) << md::toString(kind);
    // Half the overlap each: the midpoint does not move.
    EXPECT_TRUE((state.position.col(0) + state.position.col(1)).isApprox(
        system.rest_position.col(0) + system.rest_position.col(1), 1e-12));
  }
}

TEST(CollisionResponse, FreeSphereOverlappingFixedAttachmentIsPushedOutByWholeOverlap) {
  for (const auto kind : kBothKinds) {
    const auto system = makeSystem({{0, {0, 0, 0}, 0.5, true}, {1, {0.6, 0, 0}, 0.5}}, 2);
    md::CollisionWorld world(system, std::vector<md::SphereSet>{}, settingsFor(kind));
    auto state = md::restState(system);
    EXPECT_EQ(world.resolve(state), 1);
    EXPECT_EQ(state.position.col(0), system.rest_position.col(0));
    EXPECT_NEAR(state.position(0, 1), 1.0, 1e-12) << md::toString(kind);
  }
}

TEST(CollisionResponse, FreeSphereInsideBoneSphereIsPushedOutByWholeOverlap) {
  for (const auto kind : kBothKinds) {
    const auto system = makeSystem({{0, {0.5, 0, 0}, 0.1}}, 1);
    md::CollisionWorld world(system, {spheres({{Eigen::Vector3d(0, 0, 0), 1.0}})}, settingsFor(kind));
    auto state = md::restState(system);
    EXPECT_EQ(world.resolve(state), 1);
    EXPECT_TRUE(state.position.col(0).isApprox(Eigen::Vector3d(1.1, 0, 0), 1e-12)) << md::toString(kind);
  }
}

TEST(CollisionResponse, ParticleWithSeveralContactsGetsTheSuperposition) {
  for (const auto kind : kBothKinds) {
    // Particle at the origin overlaps two bone spheres by 0.2 (along -x) and 0.1 (along -y), and a free particle
    // of another muscle by 0.3 (along +z, half of it each).
    const auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {1, {0, 0, -0.7}, 0.5}}, 2);
    md::CollisionWorld world(system,
                             {spheres({{Eigen::Vector3d(0.8, 0, 0), 0.5}, {Eigen::Vector3d(0, 0.9, 0), 0.5}})},
                             settingsFor(kind));
    auto state = md::restState(system);
    EXPECT_EQ(world.resolve(state), 3);
    EXPECT_TRUE(state.position.col(0).isApprox(Eigen::Vector3d(-0.2, -0.1, 0.15), 1e-12))
        << md::toString(kind) << ": " << state.position.col(0).transpose();
    EXPECT_TRUE(state.position.col(1).isApprox(Eigen::Vector3d(0, 0, -0.85), 1e-12));
  }
}

TEST(CollisionResponse, CollidedParticlesHaveZeroVelocityOthersKeepTheirs) {
  const auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {1, {0.6, 0, 0}, 0.5}, {1, {5, 0, 0}, 0.5}}, 2);
  md::CollisionWorld world(system, std::vector<md::SphereSet>{});
  auto state = md::restState(system);
  state.previous_position.colwise() -= Eigen::Vector3d(0.01, 0.02, 0.03);  // every particle moving
  world.resolve(state);
  EXPECT_EQ(state.previous_position.col(0), state.position.col(0));
  EXPECT_EQ(state.previous_position.col(1), state.position.col(1));
  EXPECT_TRUE((state.position.col(2) - state.previous_position.col(2)).isApprox(Eigen::Vector3d(0.01, 0.02, 0.03)));
}

TEST(CollisionResponse, SpheresOfTheSameMuscleNeverCollide) {
  const auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {0, {0.1, 0, 0}, 0.5}}, 1);
  md::CollisionWorld world(system, std::vector<md::SphereSet>{});
  auto state = md::restState(system);
  EXPECT_EQ(world.resolve(state), 0);
  EXPECT_EQ(state.position, system.rest_position);
}

TEST(CollisionResponse, TwoFixedAttachmentsOverlappingAreLeftAlone) {
  const auto system = makeSystem({{0, {0, 0, 0}, 0.5, true}, {1, {0.1, 0, 0}, 0.5, true}}, 2);
  md::CollisionWorld world(system, {spheres({{Eigen::Vector3d(0, 0.2, 0), 0.5}})});
  auto state = md::restState(system);
  EXPECT_EQ(world.resolve(state), 0);
  EXPECT_EQ(state.position, system.rest_position);
}

TEST(CollisionResponse, InteriorParticlesNeverCollide) {
  auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {1, {0.1, 0, 0}, 0.5}}, 2);
  system.is_boundary[1] = 0;
  md::CollisionWorld world(system, std::vector<md::SphereSet>{});
  auto state = md::restState(system);
  EXPECT_EQ(world.resolve(state), 0);
  EXPECT_EQ(world.muscleSphereCount(), 1);
}

TEST(CollisionResponse, BoneSpheresFollowTheBoneTransform) {
  const auto system = makeSystem({{0, {2.0, 0, 0}, 0.5}}, 1);
  md::CollisionWorld world(system, {spheres({{Eigen::Vector3d(0, 0, 0), 1.0}})}, {}, {"femur_r"});
  auto state = md::restState(system);
  EXPECT_EQ(world.resolve(state), 0);  // at rest the bone is 2 m away, touching would need 1.5 m
  md::Pose pose;
  pose.bone_transforms["femur_r"] = Eigen::Isometry3d(Eigen::Translation3d(1.0, 0, 0));
  world.setPose(pose);
  EXPECT_EQ(world.resolve(state), 1);
  EXPECT_TRUE(state.position.col(0).isApprox(Eigen::Vector3d(2.5, 0, 0), 1e-12));
}

TEST(CollisionWorld, BoneOutOfReachIsSkipped) {
  const auto system = makeSystem({{0, {0, 0, 0}, 0.01}, {0, {0.1, 0, 0}, 0.01}}, 1);
  md::CollisionWorld world(system, {spheres({{Eigen::Vector3d(0.05, 0.015, 0), 0.01}}),   // within reach
                                    spheres({{Eigen::Vector3d(3.0, 0, 0), 0.2}})});       // other leg
  auto state = md::restState(system);
  world.resolve(state);
  EXPECT_EQ(world.accumulatedStats().bones_skipped, 1);
  EXPECT_EQ(world.measure(state).bones_skipped, 1);
}

// Skipping bones out of reach must change nothing but the work done: the same contacts (as many as brute force finds)
// and bit-identical positions as sending every muscle-bone pair to the broad phase.
TEST(CollisionWorld, SkippingBonesOutOfReachMatchesTestingEveryBone) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> coordinate(0.0, 0.1), radius(0.004, 0.012);
  std::vector<TestParticle> particles;
  for (int k = 0; k < 60; ++k)
    particles.push_back({k % 3, {coordinate(rng), coordinate(rng), coordinate(rng)}, radius(rng), k % 7 == 0});
  const auto system = makeSystem(particles, 3);
  md::SphereSet near_bone, far_bone;  // near: inside the muscles' region; far: a metre away (the other leg, say)
  near_bone.resize(20);
  far_bone.resize(20);
  for (Eigen::Index k = 0; k < 20; ++k) {
    near_bone.centre.col(k) = Eigen::Vector3d(coordinate(rng), coordinate(rng), coordinate(rng));
    near_bone.radius[k] = radius(rng);
    far_bone.centre.col(k) = near_bone.centre.col(k) + Eigen::Vector3d(1.0, 0, 0);
    far_bone.radius[k] = near_bone.radius[k];
  }
  // Brute force over every sphere pair: muscle-bone pairs with a free particle count as contacts.
  int expected_bone_contacts = 0;
  for (const TestParticle& p : particles) {
    if (p.fixed) continue;
    md::SphereSet one = spheres({{p.position, p.radius}});
    std::vector<md::SpherePair> pairs;
    md::overlappingPairsBruteForce(one, near_bone, pairs);
    expected_bone_contacts += static_cast<int>(pairs.size());
    md::overlappingPairsBruteForce(one, far_bone, pairs);
    EXPECT_TRUE(pairs.empty());
  }
  ASSERT_GT(expected_bone_contacts, 0);

  for (const md::BroadPhaseKind kind : {md::BroadPhaseKind::octree, md::BroadPhaseKind::hash_grid}) {
    md::CollisionSettings skipping = settingsFor(kind), testing_all = settingsFor(kind);
    testing_all.skip_bones_out_of_reach = false;
    md::CollisionWorld skip_world(system, {near_bone, far_bone}, skipping);
    md::CollisionWorld all_world(system, {near_bone, far_bone}, testing_all);
    auto skip_state = md::restState(system);
    auto all_state = md::restState(system);
    const int skip_contacts = skip_world.resolve(skip_state);
    const int all_contacts = all_world.resolve(all_state);
    EXPECT_EQ(skip_contacts, all_contacts) << md::toString(kind);
    EXPECT_EQ(skip_world.accumulatedStats().muscle_bone_contacts, expected_bone_contacts) << md::toString(kind);
    EXPECT_EQ(all_world.accumulatedStats().muscle_bone_contacts, expected_bone_contacts) << md::toString(kind);
    EXPECT_EQ(skip_world.accumulatedStats().bones_skipped, 1) << md::toString(kind);  // the far bone only
    EXPECT_EQ(all_world.accumulatedStats().bones_skipped, 0) << md::toString(kind);
    EXPECT_TRUE(skip_state.position == all_state.position) << md::toString(kind);
  }
}

TEST(CollisionWorld, SetBoneTransformsRejectsAWrongCount) {
  const auto system = makeSystem({{0, {0, 0, 0}, 0.01}}, 1);
  md::CollisionWorld world(system, {spheres({{Eigen::Vector3d(1, 0, 0), 0.1}})});
  EXPECT_THROW(world.setBoneTransforms({}), std::invalid_argument);
}

TEST(CollisionWorld, MeasureReportsRemainingPenetrationWithoutChangingTheState) {
  const auto system = makeSystem({{0, {0, 0, 0}, 0.5}, {1, {0.6, 0, 0}, 0.5}, {1, {0, 1.2, 0}, 0.1}}, 2);
  md::CollisionWorld world(system, {spheres({{Eigen::Vector3d(0, 1.5, 0), 0.25}})});
  const auto state = md::restState(system);
  const md::CollisionStats stats = world.measure(state);
  EXPECT_EQ(stats.muscle_muscle_contacts, 1);
  EXPECT_NEAR(stats.max_penetration_muscle_muscle_m, 0.4, 1e-12);
  EXPECT_EQ(stats.muscle_bone_contacts, 1);
  EXPECT_NEAR(stats.max_penetration_muscle_bone_m, 0.05, 1e-12);
  EXPECT_NEAR(stats.mean_penetration_muscle_bone_m, 0.05, 1e-12);
}

TEST(CollisionWorld, BothBroadPhasesGiveTheSameResponseOnARandomScene) {
  std::mt19937 rng(7);
  std::vector<TestParticle> particles;
  std::uniform_real_distribution<double> coord(0.0, 0.1), radius(0.001, 0.006);
  for (int i = 0; i < 3000; ++i)
    particles.push_back({i % 5, Eigen::Vector3d(coord(rng), coord(rng), coord(rng)), radius(rng), i % 37 == 0});
  const auto system = makeSystem(particles, 5);
  const auto bone = randomSpheres(rng, 800, 0.1, 0.002, 0.01);
  md::CollisionWorld octree(system, {bone}, settingsFor(md::BroadPhaseKind::octree));
  md::CollisionWorld grid(system, {bone}, settingsFor(md::BroadPhaseKind::hash_grid));
  auto a = md::restState(system), b = md::restState(system);
  for (int iteration = 0; iteration < 3; ++iteration) {
    const int ca = octree.resolve(a), cb = grid.resolve(b);
    EXPECT_EQ(ca, cb);
    EXPECT_GT(ca, 0);
    // Summation order differs between broad phases: equal up to rounding.
    EXPECT_LT((a.position - b.position).cwiseAbs().maxCoeff(), 1e-12);
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Broad phases

TEST(BroadPhase, BothMatchBruteForceOnRandomSetsOfThousandsOfSpheres) {
  struct Case {
    int count_a, count_b;
    double box_m, r_min, r_max;
  };
  const Case cases[] = {{3000, 2000, 1.0, 0.002, 0.1}, {5000, 800, 0.5, 0.001, 0.05}, {200, 4000, 0.3, 0.0005, 0.03}};
  std::vector<md::CollisionSettings> settings;
  settings.push_back(settingsFor(md::BroadPhaseKind::hash_grid));
  settings.push_back(settingsFor(md::BroadPhaseKind::octree));
  md::CollisionSettings deep = settingsFor(md::BroadPhaseKind::octree);
  deep.octree_max_depth = 12;
  deep.octree_min_primitives = 1;
  settings.push_back(deep);
  md::CollisionSettings coarse_grid = settingsFor(md::BroadPhaseKind::hash_grid);
  coarse_grid.hash_cell_scale = 0.3;
  settings.push_back(coarse_grid);

  for (const std::uint32_t seed : {1u, 2u, 3u}) {
    for (const Case& c : cases) {
      std::mt19937 rng(seed);
      md::SphereSet a = randomSpheres(rng, c.count_a, c.box_m, c.r_min, c.r_max);
      md::SphereSet b = randomSpheres(rng, c.count_b, c.box_m, c.r_min, c.r_max);
      std::vector<md::SpherePair> expected, found;
      md::overlappingPairsBruteForce(a, b, expected);
      ASSERT_GT(expected.size(), 100u);
      for (const auto& s : settings) {
        auto broad = md::makeBroadPhase(s);
        broad->update(0, a, true);
        broad->update(1, b, true);
        broad->findPairs(0, 1, found);
        EXPECT_EQ(sorted(found), expected) << md::toString(s.broad_phase) << " seed " << seed;
        broad->findPairs(1, 0, found);
        std::vector<md::SpherePair> swapped;
        for (const auto& p : found) swapped.push_back({p.second, p.first});
        EXPECT_EQ(sorted(swapped), expected) << md::toString(s.broad_phase) << " swapped, seed " << seed;
      }
    }
  }
}

TEST(BroadPhase, BothStayExactAfterTheSpheresMove) {
  // The octree is only refitted after motion: its hierarchy stays, its boxes must still bound everything.
  std::mt19937 rng(11);
  md::SphereSet a = randomSpheres(rng, 3000, 0.5, 0.001, 0.03);
  md::SphereSet b = randomSpheres(rng, 3000, 0.5, 0.001, 0.03);
  std::normal_distribution<double> jitter(0.0, 0.02);
  for (const auto kind : kBothKinds) {
    auto broad = md::makeBroadPhase(settingsFor(kind));
    md::SphereSet ma = a, mb = b;
    broad->update(0, ma, true);
    broad->update(1, mb, true);
    std::vector<md::SpherePair> expected, found;
    for (int step = 0; step < 4; ++step) {
      broad->findPairs(0, 1, found);
      md::overlappingPairsBruteForce(ma, mb, expected);
      EXPECT_EQ(sorted(found), expected) << md::toString(kind) << " step " << step;
      for (Eigen::Index i = 0; i < ma.size(); ++i) ma.centre.col(i) += Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
      mb.centre.array() += 0.01;  // a rigid shift of the whole set
      broad->update(0, ma, false);
      broad->update(1, mb, false);
    }
  }
}

TEST(BroadPhase, GroupQueryMatchesBruteForceForTheTestedObjectPairsOnly) {
  std::mt19937 rng(23);
  std::vector<md::SphereSet> sets;
  for (int k = 0; k < 4; ++k) sets.push_back(randomSpheres(rng, 1500 + 300 * k, 0.4, 0.001, 0.03));
  const std::vector<int> ids = {3, 0, 2, 1};  // not sorted: output must still put the lower id first
  std::vector<std::uint8_t> test_pair(16, 1);
  test_pair[0 * 4 + 2] = 0;  // ids 3 and 2 are not tested
  for (const auto kind : kBothKinds) {
    auto broad = md::makeBroadPhase(settingsFor(kind));
    for (int k = 0; k < 4; ++k) broad->update(k, sets[static_cast<std::size_t>(k)], true);
    std::vector<md::ObjectSpherePair> found;
    broad->findPairsAmong(ids, test_pair, found);
    std::map<std::pair<int, int>, std::vector<md::SpherePair>> by_objects;
    for (const auto& p : found) {
      EXPECT_LT(p.first_object, p.second_object);
      by_objects[{p.first_object, p.second_object}].push_back({p.first, p.second});
    }
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) {
        std::vector<md::SpherePair> expected;
        if (!(a == 2 && b == 3)) md::overlappingPairsBruteForce(sets[static_cast<std::size_t>(a)], sets[static_cast<std::size_t>(b)], expected);
        EXPECT_EQ(sorted(by_objects[{a, b}]), expected) << md::toString(kind) << " objects " << a << " " << b;
      }
  }
}

TEST(BroadPhase, EmptySetsGiveNoPairs) {
  md::SphereSet empty;
  std::mt19937 rng(5);
  md::SphereSet some = randomSpheres(rng, 50, 0.1, 0.01, 0.02);
  for (const auto kind : kBothKinds) {
    auto broad = md::makeBroadPhase(settingsFor(kind));
    broad->update(0, empty, true);
    broad->update(1, some, true);
    std::vector<md::SpherePair> found = {{1, 2}};
    broad->findPairs(0, 1, found);
    EXPECT_TRUE(found.empty());
  }
}

TEST(BroadPhase, InvalidSettingsAreRejectedWithAReason) {
  md::CollisionSettings s;
  s.hash_cell_scale = 0.0;
  EXPECT_NE(md::validate(s), "");
  EXPECT_THROW(md::makeBroadPhase(s), std::invalid_argument);
  EXPECT_EQ(md::validate(md::CollisionSettings{}), "");
}

// ---------------------------------------------------------------------------------------------------------------
// Radii of muscle particles

TEST(CollisionRadii, ParticleOnTheAxisOfACylinderGetsTheCylinderRadius) {
  // One fibre on the axis; vertex rings exactly at the particles' heights, 30 mm apart, cylinder radius 10 mm:
  // each ring's vertices are closest to the particle in its plane, all at 10 mm, and 10 + 10 < 30 so nothing shrinks.
  const double r = 0.01;
  std::vector<TestParticle> particles;
  std::vector<double> heights;
  for (int k = 0; k < 4; ++k) {
    particles.push_back({0, Eigen::Vector3d(0, 0, 0.03 * k), 0.0});
    heights.push_back(0.03 * k);
  }
  auto system = makeSystem(particles, 1);
  md::Muscle muscle;
  muscle.surface = cylinderVertices(r, heights, 24);
  const auto summary = md::assignCollisionRadii(system, {muscle});
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) EXPECT_NEAR(system.radius[i], r, 1e-12);
  EXPECT_EQ(summary[0].reduced_pairs, 0);
  EXPECT_EQ(summary[0].particles_without_vertex, 0);
}

TEST(CollisionRadii, ParticleBetweenRingsGetsTheMeanDistanceToItsVertices) {
  // Rings every 2 mm: a particle collects the rings nearer to it than to its neighbours, so its radius is the mean
  // of sqrt(r^2 + dz^2) over those rings.
  const double r = 0.01;
  std::vector<TestParticle> particles;
  for (int k = 0; k < 4; ++k) particles.push_back({0, Eigen::Vector3d(0, 0, 0.015 + 0.03 * k), 0.0});
  std::vector<double> heights;
  for (int k = 0; k <= 60; ++k) heights.push_back(0.002 * k + 0.001);
  auto system = makeSystem(particles, 1);
  md::Muscle muscle;
  muscle.surface = cylinderVertices(r, heights, 16);
  md::assignCollisionRadii(system, {muscle});
  // Inner particles (30 mm apart) collect the rings at dz = 0, +-2, ..., +-14 mm; exact mean of their distances.
  double expected = r;
  for (int k = 1; k <= 7; ++k) expected += 2 * std::sqrt(r * r + std::pow(0.002 * k, 2));
  expected /= 15;
  EXPECT_NEAR(system.radius[1], expected, 1e-12);
  EXPECT_NEAR(system.radius[2], expected, 1e-12);
}

TEST(CollisionRadii, ParticleWithNoVertexGetsHalfItsNearestSpacing) {
  // Rings only at both ends: the two middle particles collect no vertex.
  const double r = 0.01;
  std::vector<TestParticle> particles;
  for (int k = 0; k < 4; ++k) particles.push_back({0, Eigen::Vector3d(0, 0, 0.03 * k), 0.0});
  auto system = makeSystem(particles, 1);
  md::Muscle muscle;
  muscle.surface = cylinderVertices(r, {0.0, 0.09}, 12);
  const auto summary = md::assignCollisionRadii(system, {muscle});
  EXPECT_EQ(summary[0].particles_without_vertex, 2);
  EXPECT_NEAR(system.radius[0], r, 1e-9);
  EXPECT_NEAR(system.radius[1], 0.015, 1e-9);
  EXPECT_NEAR(system.radius[2], 0.015, 1e-9);
}

TEST(CollisionRadii, NoTwoSpheresOfAMuscleOverlapAfterReductionAndInteriorParticlesGetZero) {
  // Seven fibres in a 10 mm cylinder: one on the axis (interior), six on a 4 mm hexagon (boundary, 4 mm apart).
  // Raw radii are about 6-7 mm, so neighbouring boundary spheres overlap and must be shrunk.
  std::vector<TestParticle> particles;
  std::vector<double> heights;
  for (int k = 0; k < 10; ++k) {
    const double z = 0.005 * k;
    heights.push_back(z);
    particles.push_back({0, Eigen::Vector3d(0, 0, z), 0.0});
    for (int f = 0; f < 6; ++f) {
      const double a = M_PI / 3 * f;
      particles.push_back({0, Eigen::Vector3d(0.004 * std::cos(a), 0.004 * std::sin(a), z), 0.0});
    }
  }
  auto system = makeSystem(particles, 1);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    system.is_boundary[static_cast<std::size_t>(i)] = system.rest_position.col(i).head<2>().norm() > 0.001;
  md::Muscle muscle;
  muscle.surface = cylinderVertices(0.01, heights, 36);
  const auto summary = md::assignCollisionRadii(system, {muscle});
  EXPECT_GT(summary[0].reduced_pairs, 0);
  EXPECT_LT(summary[0].mean_radius_m, summary[0].mean_radius_before_m);
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (!system.is_boundary[static_cast<std::size_t>(i)]) {
      EXPECT_EQ(system.radius[i], 0.0);
      continue;
    }
    EXPECT_GT(system.radius[i], 0.0);
    for (Eigen::Index j = i + 1; j < system.particleCount(); ++j)
      EXPECT_GE((system.rest_position.col(i) - system.rest_position.col(j)).norm(), system.radius[i] + system.radius[j])
          << i << " " << j;
  }
}

TEST(CollisionRadii, RejectsAMuscleCountMismatch) {
  auto system = makeSystem({{0, {0, 0, 0}, 0.0}}, 1);
  EXPECT_THROW(md::assignCollisionRadii(system, {}), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------------------------
// Bone spheres

namespace {
struct EdgeRange {
  double min = 1e9, max = 0;
};
EdgeRange edgeRange(const md::TriangleMesh& mesh) {
  EdgeRange r;
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int e = 0; e < 3; ++e) {
      const double len = (mesh.vertices.col(mesh.triangles(e, t)) - mesh.vertices.col(mesh.triangles((e + 1) % 3, t))).norm();
      r.min = std::min(r.min, len);
      r.max = std::max(r.max, len);
    }
  return r;
}
// Largest distance by which a vertex lies outside every sphere (0 when all are covered).
double worstUncovered(const md::TriangleMesh& mesh, const md::SphereSet& s) {
  double worst = 0;
  for (Eigen::Index v = 0; v < mesh.vertexCount(); ++v) {
    double outside = 1e9;
    for (Eigen::Index k = 0; k < s.size(); ++k)
      outside = std::min(outside, (mesh.vertices.col(v) - s.centre.col(k)).norm() - s.radius[k]);
    worst = std::max(worst, outside);
  }
  return worst;
}
}  // namespace

TEST(BoneSpheres, TriangleFanRuleCoversEveryVertexOfAUnitSphereMesh) {
  // Every vertex is a root or in a root's ring (an unmarked vertex becomes a root), so it lies within D <= L of the
  // root v, L the longest edge at v. With centre c = v - L n: |u - c|^2 = D^2 + L^2 + 2 L n.(u - v), and on a
  // convex surface the chord points inward, n.(u - v) <= 0, so |u - c| <= sqrt(2) L = radius: bound 0. The
  // area-weighted normal is not exactly radial, hence a tolerance of 1e-3 edge lengths.
  const md::TriangleMesh mesh = unitIcosphere(3);
  const EdgeRange edges = edgeRange(mesh);
  const md::SphereSet s = md::boneSpheresOneRing(mesh, md::OneRingRule::disjoint_triangle_fans);
  ASSERT_GT(s.size(), 0);
  EXPECT_LE(worstUncovered(mesh, s), 1e-3 * edges.min);
  for (Eigen::Index k = 0; k < s.size(); ++k) EXPECT_LT(s.centre.col(k).norm(), 1.0);  // moved inward
}

TEST(BoneSpheres, VertexRingRuleLeavesNoVertexFartherThanTwoEdgesFromASphere) {
  // A vertex skipped by the stricter rule has a neighbour in some root's ring, so it is within D <= 2 e_max of that
  // root. With n.(u - v) <= 0 as above, it is at most sqrt(D^2 + L^2) - sqrt(2) L outside the root's sphere, which
  // falls as L grows: bound sqrt(4 e_max^2 + e_min^2) - sqrt(2) e_min (about 0.8 e on a uniform mesh).
  const md::TriangleMesh mesh = unitIcosphere(3);
  const EdgeRange edges = edgeRange(mesh);
  const double bound = std::sqrt(4 * edges.max * edges.max + edges.min * edges.min) - std::sqrt(2.0) * edges.min;
  const md::SphereSet strict = md::boneSpheresOneRing(mesh, md::OneRingRule::disjoint_vertex_rings);
  const md::SphereSet fans = md::boneSpheresOneRing(mesh, md::OneRingRule::disjoint_triangle_fans);
  ASSERT_GT(strict.size(), 0);
  EXPECT_LT(strict.size(), fans.size());
  // Disjoint rings of at least 6 vertices (5 at the icosahedron's corners): at most V / 5 spheres.
  EXPECT_LE(strict.size(), mesh.vertexCount() / 5);
  EXPECT_LE(worstUncovered(mesh, strict), bound + 1e-12) << "e_min " << edges.min << " e_max " << edges.max;
}

TEST(BoneSpheres, SphereSitsBelowTheRootByTheLongestEdgeWithRadiusSqrtTwoTimesIt) {
  // 2 x 2 cells of 0.1 m. Vertex 0 is visited first; its ring is 1, 3 and 4 (the cell's diagonal 0-4 is an edge),
  // so its longest edge is the diagonal, 0.1 sqrt(2) m, and the plate normal is +z.
  const md::TriangleMesh mesh = plate(0.2, 2);
  const md::SphereSet s = md::boneSpheresOneRing(mesh);
  ASSERT_GE(s.size(), 1);
  const double diagonal = 0.1 * std::sqrt(2.0);
  EXPECT_TRUE(s.centre.col(0).isApprox(mesh.vertices.col(0) - Eigen::Vector3d(0, 0, diagonal), 1e-9))
      << s.centre.col(0).transpose();
  EXPECT_NEAR(s.radius[0], diagonal * std::sqrt(2.0), 1e-12);
}

TEST(BoneSpheres, WorldReportsSphereCountPerBone) {
  const auto system = makeSystem({{0, {0, 0, 5}, 0.01}}, 1);
  std::vector<md::Bone> bones(2);
  bones[0].name = "ball";
  bones[0].surface = unitIcosphere(2);
  bones[1].name = "plate";
  bones[1].surface = plate(0.2, 4);
  md::CollisionWorld world(system, bones);
  ASSERT_EQ(world.boneSphereCounts().size(), 2u);
  EXPECT_EQ(world.boneSphereCounts()[0], md::boneSpheresOneRing(bones[0].surface).size());
  EXPECT_EQ(world.boneSphereCounts()[1], md::boneSpheresOneRing(bones[1].surface).size());
  EXPECT_GT(world.boneSphereCounts()[1], 0);
}

// ---------------------------------------------------------------------------------------------------------------
// Integration with the solver

TEST(CollisionIntegration, SmallMusclePressedAgainstABonePlateEndsOutsideThePlateSpheres) {
  // A 80 mm spindle muscle lying along x, 12 mm above a 60 mm plate of 2.5 mm cells; fibre ends fixed in space (no
  // bones in the build) beyond the plate's edges. The plate is then raised 8 mm into the muscle's belly and the
  // solver runs with the collision hook.
  md::Muscle muscle = md::makeSpindleMuscle("pressed", {-0.04, 0, 0.012}, {0.04, 0, 0.012}, 0.008, 1.0, 4, 40);
  md::ModelSettings model;
  model.particles_per_fibre = 20;
  md::MassSpringSystem system = md::buildMassSpringSystem({muscle}, {}, model);
  md::assignCollisionRadii(system, {muscle});

  md::Bone plate_bone;
  plate_bone.id = 0;
  plate_bone.name = "plate";
  plate_bone.surface = plate(0.06, 24);
  md::CollisionWorld world(system, {plate_bone});
  world.setBoneTransforms({Eigen::Isometry3d(Eigen::Translation3d(0, 0, 0.008))});

  md::VerletSolver solver(system, md::VerletSettings{});
  auto state = md::restState(system);
  const md::CollisionStats before = world.measure(state);
  ASSERT_GT(before.muscle_bone_contacts, 0) << "the raised plate must press into the muscle";
  const md::SolveStats solve = solver.solve(state, md::StoppingSettings::afterIterations(400),
                                            [&](md::ParticleState& s) { return world.resolve(s); });
  const md::CollisionStats after = world.measure(state);

  // Tolerance: collision runs last in every iteration and resolves each contact exactly, so what can remain is only
  // the error of superposing the pushes of several plate spheres a particle touches at once (their directions
  // differ). We accept 5 % of the smallest particle radius, far below the sphere size that represents the surface
  // (measured: about 1e-18 m left, from 4.3 mm before).
  double min_radius = 1e9;
  for (Eigen::Index i = 0; i < system.particleCount(); ++i)
    if (system.radius[i] > 0) min_radius = std::min(min_radius, system.radius[i]);
  EXPECT_LE(after.max_penetration_muscle_bone_m, 0.05 * min_radius)
      << "before: " << before.max_penetration_muscle_bone_m << " m over " << before.muscle_bone_contacts
      << " contacts; after " << solve.iterations << " iterations: " << after.muscle_bone_contacts << " contacts";
  EXPECT_LT(after.max_penetration_muscle_bone_m, 0.1 * before.max_penetration_muscle_bone_m);
  // Fixed ends never moved.
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    if (system.is_fixed[static_cast<std::size_t>(i)]) {
      EXPECT_EQ(state.position.col(i), system.rest_position.col(i));
    }
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Bones as distance fields

namespace {

// A ball bone of 25 mm radius at the origin, as a field.
std::shared_ptr<const md::BoneDistanceField> ballField() {
  return std::make_shared<const md::BoneDistanceField>(md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.025, 4));
}

}  // namespace

TEST(CollisionWorldWithBoneFields, ResolvePutsAParticleItsRadiusOutsideTheBoneAndInteriorParticlesCollideToo) {
  // A boundary particle (2 mm radius) and an interior one (radius 0), about 10 mm from the bone at rest.
  md::MassSpringSystem system = makeSystem({{0, Eigen::Vector3d(0.035, 0, 0), 0.002},
                                            {0, Eigen::Vector3d(0.035, 0, 0.003), 0.0}}, 1);
  system.is_boundary[1] = 0;
  md::CollisionWorld world(system, {ballField()}, {}, {"ball"});
  EXPECT_TRUE(world.everyParticleCollides());
  auto state = md::restState(system);
  EXPECT_EQ(world.measure(state).muscle_bone_contacts, 0) << "no contact at rest";
  // The bone moves 15 mm towards both: they end about 5 mm deep.
  world.setBoneTransforms({Eigen::Isometry3d(Eigen::Translation3d(0.015, 0, 0))});
  const md::CollisionStats pressed = world.measure(state);
  EXPECT_EQ(pressed.muscle_bone_contacts, 2);
  EXPECT_NEAR(pressed.max_penetration_muscle_bone_m, 0.007, 3e-4);  // 5 mm inside plus the 2 mm radius
  EXPECT_EQ(world.resolve(state), 2);
  const Eigen::Vector3d bone_centre(0.015, 0, 0);
  EXPECT_NEAR((state.position.col(0) - bone_centre).norm(), 0.025 + 0.002, 3e-4);
  EXPECT_NEAR((state.position.col(1) - bone_centre).norm(), 0.025, 3e-4);
  EXPECT_LT(world.measure(state).max_penetration_muscle_bone_m, 3e-4);
}

TEST(CollisionWorldWithBoneFields, ParticlesABoxBoneMovesIntoArePushedOutThroughTheFaceTheyAreNearest) {
  // A 40 mm box bone; three particles of 1.5 mm radius 5 mm outside three of its faces at rest. The bone then moves
  // 8 mm diagonally, which takes each particle about 3 mm inside its face: each must come out through that face to its
  // radius outside, not through another face (the field's gradient points to the nearest face).
  md::TriangleMesh box = md::testing::unitCube();
  box.vertices *= 0.04;
  const auto field = std::make_shared<const md::BoneDistanceField>(box);
  const double radius = 0.0015;
  md::MassSpringSystem system = makeSystem({{0, Eigen::Vector3d(0.045, 0.02, 0.02), radius},
                                            {0, Eigen::Vector3d(0.02, 0.045, 0.02), radius},
                                            {0, Eigen::Vector3d(0.02, 0.02, 0.045), radius}}, 1);
  md::CollisionWorld world(system, {field}, {}, {"box"});
  auto state = md::restState(system);
  EXPECT_EQ(world.measure(state).muscle_bone_contacts, 0) << "no contact at rest";
  const Eigen::Vector3d shift(0.008, 0.008, 0.008);
  world.setBoneTransforms({Eigen::Isometry3d(Eigen::Translation3d(shift))});
  EXPECT_EQ(world.measure(state).muscle_bone_contacts, 3);
  EXPECT_EQ(world.resolve(state), 3);
  const double far_face = 0.04 + 0.008;  // each particle's nearest face, moved with the bone
  for (int axis = 0; axis < 3; ++axis) {
    const Eigen::Vector3d p = state.position.col(axis);
    EXPECT_NEAR(p[axis], far_face + radius, 3e-4) << "particle " << axis << " out through its own face";
    for (int other = 0; other < 3; ++other)
      if (other != axis) EXPECT_NEAR(p[other], 0.02, 1e-3) << "particle " << axis << " moved along the face normal";
  }
  EXPECT_LT(world.measure(state).max_penetration_muscle_bone_m, 3e-4);
}

TEST(CollisionWorldWithBoneFields, AParticleInsideTheBoneAtRestMayNotGoDeeperButIsNotPushedOut) {
  // 3 mm inside the bone at rest (the data put it there): no contact at rest, nothing dropped.
  md::MassSpringSystem system = makeSystem({{0, Eigen::Vector3d(0.022, 0, 0), 0.002}}, 1);
  md::CollisionWorld world(system, {ballField()}, {}, {"ball"});
  EXPECT_EQ(world.particlesCloserThanRadiusAtRest(), 1);
  auto state = md::restState(system);
  EXPECT_EQ(world.measure(state).muscle_bone_contacts, 0);
  EXPECT_EQ(world.resolve(state), 0);
  EXPECT_EQ(state.position.col(0), system.rest_position.col(0));
  // Pushed 2 mm deeper, it is put back at its rest depth.
  state.position.col(0) = Eigen::Vector3d(0.020, 0, 0);
  EXPECT_EQ(world.resolve(state), 1);
  EXPECT_NEAR(state.position.col(0).x(), 0.022, 3e-4);
}

TEST(CollisionWorldWithBoneFields, ContactsAreHalfSpacesFoundWithinTheMarginAndFixedParticlesHaveNone) {
  md::MassSpringSystem system = makeSystem({{0, Eigen::Vector3d(0.030, 0, 0), 0.002},         // 3 mm gap
                                            {0, Eigen::Vector3d(0, 0, 0.040), 0.002},         // 13 mm gap
                                            {0, Eigen::Vector3d(0, -0.026, 0), 0.002, true}}, // fixed, touching
                                           1);
  md::CollisionWorld world(system, {ballField()}, {}, {"ball"});
  md::ContactSet contacts;
  world.findContacts(md::restState(system), contacts, 0.004);
  ASSERT_EQ(contacts.half_spaces.size(), 1u);
  EXPECT_TRUE(contacts.obstacles.empty());
  const md::ContactSet::HalfSpace& contact = contacts.half_spaces[0];
  EXPECT_EQ(contact.particle, 0);
  // The normal is the gradient of the trilinear interpolant: within a few degrees of radial on a ball 25 voxels wide
  // (measured 3 degrees here).
  EXPECT_GT(contact.normal.dot(Eigen::Vector3d::UnitX()), 0.995);
  // The plane is where the particle's sphere touches the bone: 27 mm from the centre along x.
  EXPECT_NEAR(contact.normal.dot(contact.point), 0.027, 3e-4);
}

namespace {

void expectSameFigures(const md::CollisionStats& listed, const md::CollisionStats& searched, const std::string& what) {
  EXPECT_EQ(listed.muscle_muscle_contacts, searched.muscle_muscle_contacts) << what;
  EXPECT_EQ(listed.muscle_bone_contacts, searched.muscle_bone_contacts) << what;
  EXPECT_EQ(listed.contacts, searched.contacts) << what;
  EXPECT_EQ(listed.max_penetration_muscle_muscle_m, searched.max_penetration_muscle_muscle_m) << what;
  EXPECT_EQ(listed.max_penetration_muscle_bone_m, searched.max_penetration_muscle_bone_m) << what;
  // Sums in a different order: equal up to rounding.
  EXPECT_NEAR(listed.mean_penetration_muscle_muscle_m, searched.mean_penetration_muscle_muscle_m, 1e-15) << what;
  EXPECT_NEAR(listed.mean_penetration_muscle_bone_m, searched.mean_penetration_muscle_bone_m, 1e-15) << what;
}

}  // namespace

TEST(CollisionWorldWithBoneFields, MeasuringTheListedContactsFindsAContactMadeByAParticleThatMovedBeyondTheMargin) {
  // Two muscles' particles (2 mm radius) 10 mm apart and a third 5 mm off the ball bone's surface beyond its radius:
  // none is listed with a 1 mm margin. Two then move 7 mm (beyond the margin): into a 1 mm overlap with the other
  // muscle's particle, and 2 mm into the bone's clearance.
  md::MassSpringSystem system = makeSystem({{0, Eigen::Vector3d(0.060, 0, 0), 0.002},
                                            {1, Eigen::Vector3d(0.070, 0, 0), 0.002},
                                            {1, Eigen::Vector3d(0, 0.032, 0), 0.002}}, 2);
  md::CollisionWorld world(system, {ballField()}, {}, {"ball"});
  auto state = md::restState(system);
  md::ContactSet contacts;
  world.findContacts(state, contacts, 0.001);
  EXPECT_TRUE(contacts.pairs.empty());
  EXPECT_TRUE(contacts.half_spaces.empty());
  state.position.col(0) += Eigen::Vector3d(0.007, 0, 0);
  state.position.col(2) -= Eigen::Vector3d(0, 0.007, 0);
  const md::CollisionStats listed = world.measureListed(state);
  EXPECT_EQ(listed.muscle_muscle_contacts, 1);
  EXPECT_NEAR(listed.max_penetration_muscle_muscle_m, 0.001, 1e-12);
  EXPECT_EQ(listed.muscle_bone_contacts, 1);
  EXPECT_NEAR(listed.max_penetration_muscle_bone_m, 0.002, 3e-4);  // the field's interpolation, as measure() reads it
  expectSameFigures(listed, world.measure(state), "two particles moved beyond the margin");
}

TEST(CollisionWorldWithBoneFields, MeasuringTheListedContactsGivesMeasuresFiguresWhateverTheParticlesDidSince) {
  // Five muscles of random particles around a ball bone; contacts listed with a 1 mm margin, then the particles moved
  // (a) all within the margin, (b) a few of them beyond it, (c) more than can be checked alone; and (d) the bone moved.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> coord(-0.045, 0.045), radius(0.001, 0.004), unit(-1.0, 1.0);
  std::vector<TestParticle> particles;
  for (int i = 0; i < 2000; ++i)
    particles.push_back({i % 5, Eigen::Vector3d(coord(rng), coord(rng), coord(rng)), radius(rng), i % 41 == 0});
  const md::MassSpringSystem system = makeSystem(particles, 5);
  md::CollisionWorld world(system, {ballField()}, {}, {"ball"});
  const double margin = 0.001;
  const auto start = md::restState(system);
  const auto moved = [&](double step, int every) {
    auto state = start;
    for (Eigen::Index p = 0; p < state.position.cols(); ++p) {
      if (system.is_fixed[static_cast<std::size_t>(p)]) continue;
      const Eigen::Vector3d direction = Eigen::Vector3d(unit(rng), unit(rng), unit(rng)).normalized();
      state.position.col(p) += (p % every == 0 ? 4.0 * margin : step) * direction;
    }
    return state;
  };
  md::ContactSet contacts;
  const struct {
    const char* what;
    double step;
    int every;
  } cases[] = {{"within the margin", 0.9 * margin, 1 << 30}, {"a few beyond it", 0.5 * margin, 97},
               {"many beyond it", 0.5 * margin, 3}};
  for (const auto& c : cases) {
    world.findContacts(start, contacts, margin);
    const auto state = moved(c.step, c.every);
    const md::CollisionStats listed = world.measureListed(state);
    EXPECT_GT(listed.muscle_muscle_contacts, 0) << c.what;
    EXPECT_GT(listed.muscle_bone_contacts, 0) << c.what;
    expectSameFigures(listed, world.measure(state), c.what);
  }
  world.findContacts(start, contacts, margin);
  world.setBoneTransforms({Eigen::Isometry3d(Eigen::Translation3d(0.004, 0, 0))});
  expectSameFigures(world.measureListed(start), world.measure(start), "after the bone moved");
}

TEST(CollisionWorldWithBoneFields, RejectsFieldsAndNamesOfDifferentCounts) {
  const md::MassSpringSystem system = makeSystem({{0, Eigen::Vector3d(0.035, 0, 0), 0.002}}, 1);
  EXPECT_THROW(md::CollisionWorld(system, std::vector<std::shared_ptr<const md::BoneDistanceField>>{ballField()},
                                  md::CollisionSettings{}, std::vector<std::string>{}),
               std::invalid_argument);
}
