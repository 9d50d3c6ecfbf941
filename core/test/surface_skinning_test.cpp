// Specifications of the surface skinning: affine motions of the particles move the surface exactly, rest gives rest,
// mean value coordinates behave inside, outside and on a cage, and open surfaces are refused.
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"

#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

namespace md = muscle_deformation;

namespace {

using muscle_deformation::testing::unitCube;

// One spindle muscle, 8 x 8 fibres of 20 particles, no bones (fibre ends fixed in space).
struct SpindleFixture {
  md::Muscle muscle = md::makeSpindleMuscle("spindle", {0, 0, 0}, {0.02, 0.01, 0.20}, 0.02, 0.8, 8, 50, 32, 40);
  md::MassSpringSystem system = md::buildMassSpringSystem({muscle}, {}, md::ModelSettings{});
};

const SpindleFixture& spindle() {
  static const SpindleFixture fixture;
  return fixture;
}

md::MuscleSkin skinOf(md::SkinningMethod method, md::CageKind cage = md::CageKind::fibre_tube) {
  md::SkinningSettings settings;
  settings.method = method;
  settings.cage = cage;
  return md::MuscleSkin(spindle().system, 0, spindle().muscle.surface, settings);
}

double largestDistance(const md::Vertices& a, const md::Vertices& b) { return (a - b).colwise().norm().maxCoeff(); }

const md::SkinningMethod kAffineMethods[] = {md::SkinningMethod::mean_value, md::SkinningMethod::embedded};

}  // namespace

TEST(SkinningMethodNames, RoundTripThroughStrings) {
  for (auto method : {md::SkinningMethod::nearest_average, md::SkinningMethod::mean_value, md::SkinningMethod::embedded})
    EXPECT_EQ(md::skinningMethodFromString(md::toString(method)), method);
  EXPECT_THROW(md::skinningMethodFromString("linear_blend"), std::invalid_argument);
}

TEST(MeanValueCoordinates, ReproducePointsInsideAndOutsideAClosedCube) {
  const md::TriangleMesh cube = unitCube();
  std::mt19937 random(7);
  std::uniform_real_distribution<double> coordinate(-1.0, 2.0);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d point(coordinate(random), coordinate(random), coordinate(random));
    const Eigen::VectorXd w = md::meanValueCoordinates(cube, point);
    ASSERT_TRUE(w.allFinite());
    EXPECT_NEAR(w.sum(), 1.0, 1e-12);
    EXPECT_LT((cube.vertices * w - point).norm(), 1e-10) << point.transpose();
  }
}

TEST(MeanValueCoordinates, AreNonNegativeInsideAConvexCage) {
  const Eigen::VectorXd w = md::meanValueCoordinates(unitCube(), Eigen::Vector3d(0.3, 0.6, 0.2));
  EXPECT_GE(w.minCoeff(), 0.0);
}

TEST(MeanValueCoordinates, OnACageTriangleAreThatTrianglesBarycentricCoordinates) {
  const md::TriangleMesh cube = unitCube();
  bool on_cage = false;
  const Eigen::Vector3d point(0.2, 0.1, 0.0);  // on the bottom face, inside its triangle (0, 2, 1)
  const Eigen::VectorXd w = md::meanValueCoordinates(cube, point, &on_cage);
  EXPECT_TRUE(on_cage);
  EXPECT_LT((cube.vertices * w - point).norm(), 1e-14);
  EXPECT_EQ((w.array().abs() > 0).count(), 3);  // only the three corners of the triangle it lies on
}

TEST(MeanValueCoordinates, AtACageCornerAreThatCornersIndicator) {
  bool on_cage = false;
  const Eigen::VectorXd w = md::meanValueCoordinates(unitCube(), Eigen::Vector3d(1, 1, 0), &on_cage);
  EXPECT_TRUE(on_cage);
  EXPECT_DOUBLE_EQ(w[2], 1.0);
}

TEST(FibreTubeCage, IsClosedAndUsesTheWholeOuterRingOfFibres) {
  const md::ParticleCage cage = md::buildParticleCage(spindle().system, 0, md::CageKind::fibre_tube);
  EXPECT_EQ(cage.kind, md::CageKind::fibre_tube);
  EXPECT_TRUE(md::checkSurfaceTopology(cage.mesh).closedManifold());
  EXPECT_GT(md::enclosedVolume(cage.mesh), 0);
  // 8 x 8 grid: 28 outer fibres of 20 particles, plus one fan centre at each end.
  EXPECT_EQ(cage.mesh.vertexCount(), 28 * 20 + 2);
}

TEST(ConvexHullCage, IsClosedAndWoundOutwards) {
  const md::ParticleCage cage = md::buildParticleCage(spindle().system, 0, md::CageKind::convex_hull);
  EXPECT_TRUE(md::checkSurfaceTopology(cage.mesh).closedManifold());
  EXPECT_GT(md::enclosedVolume(cage.mesh), 0);
}

TEST(SurfaceSkinning, ParticlesAtRestGiveTheRestSurfaceForEveryMethod) {
  // Exact up to rounding for all three: the weights reproduce every vertex from the rest particles (mean value and
  // barycentric coordinates have linear precision; nearest_average adds back the vertex's offset).
  for (auto method : {md::SkinningMethod::nearest_average, md::SkinningMethod::mean_value, md::SkinningMethod::embedded}) {
    const md::MuscleSkin skin = skinOf(method);
    md::Vertices surface;
    skin.update(spindle().system.rest_position, {}, surface);
    EXPECT_LT(largestDistance(surface, spindle().muscle.surface.vertices), 1e-9) << md::toString(method);
  }
}

TEST(SurfaceSkinning, RigidMotionOfAllParticlesMovesTheSurfaceRigidly) {
  const Eigen::Isometry3d motion =
      Eigen::Translation3d(0.3, -0.1, 0.05) * Eigen::AngleAxisd(1.1, Eigen::Vector3d(1, 2, -0.5).normalized());
  const Eigen::Matrix3Xd moved = motion * spindle().system.rest_position;
  const md::Vertices expected = motion * spindle().muscle.surface.vertices;
  for (auto method : kAffineMethods) {
    md::Vertices surface;
    skinOf(method).update(moved, {}, surface);
    EXPECT_LT(largestDistance(surface, expected), 1e-9) << md::toString(method);
  }
}

TEST(SurfaceSkinning, RigidMotionHoldsForTheConvexHullCageToo) {
  const Eigen::Isometry3d motion = Eigen::Translation3d(-0.2, 0, 0.1) * Eigen::AngleAxisd(-0.7, Eigen::Vector3d::UnitX());
  md::Vertices surface;
  skinOf(md::SkinningMethod::mean_value, md::CageKind::convex_hull).update(motion * spindle().system.rest_position, {}, surface);
  EXPECT_LT(largestDistance(surface, motion * spindle().muscle.surface.vertices), 1e-9);
}

TEST(SurfaceSkinning, UniformScalingOfTheParticlesScalesTheVolumeByTheCube) {
  // Exact for mean_value and embedded (affine invariance); nearest_average only translates vertices, so it is not.
  const double s = 1.3;
  const Eigen::Vector3d centre(0.01, 0.0, 0.1);
  const Eigen::Matrix3Xd scaled = (s * (spindle().system.rest_position.colwise() - centre)).colwise() + centre;
  const double rest_volume = md::enclosedVolume(spindle().muscle.surface);
  for (auto method : kAffineMethods) {
    const md::MuscleSkin skin = skinOf(method);
    md::Vertices surface;
    skin.update(scaled, {}, surface);
    EXPECT_NEAR(md::enclosedVolume(surface, skin.triangles()) / rest_volume, s * s * s, 1e-9) << md::toString(method);
  }
}

TEST(SurfaceSkinning, WeightsOfEveryVertexSumToOne) {
  for (auto method : kAffineMethods) {
    const md::MuscleSkin skin = skinOf(method);
    const Eigen::VectorXd sums = skin.weights() * Eigen::VectorXd::Ones(skin.weights().cols());
    EXPECT_LT((sums.array() - 1).abs().maxCoeff(), 1e-12) << md::toString(method);
  }
}

TEST(SurfaceSkinning, MeanValueWeightsStayModerateForVerticesOutsideTheCage) {
  // The spindle's surface lies outside its boundary fibres, so every vertex is extrapolated; sum |w| measures how much
  // particle noise is amplified. A few, not hundreds.
  const md::SkinningDiagnostics& diagnostics = skinOf(md::SkinningMethod::mean_value).diagnostics();
  EXPECT_GT(diagnostics.vertices_outside, 0);
  EXPECT_LT(diagnostics.max_abs_weight_sum, 10.0);
}

TEST(SurfaceSkinning, NearestAverageFollowsTheBoneWhenEveryParticleFollowsThatBoneAlone) {
  // One bone: every particle's pre-transform is that bone's motion, so particles left at their pre-transform carry
  // the surface rigidly with the bone (thesis 4.4.4).
  const md::Muscle muscle = md::makeSpindleMuscle("spindle", {0, 0, 0}, {0, 0, 0.2}, 0.02, 0.8, 6, 40, 24, 30);
  const std::vector<md::Bone> bones = {{0, "bone", md::makeCylinderMesh({0.05, 0, -0.01}, {0.05, 0, 0.21}, 0.01)}};
  const md::MassSpringSystem system = md::buildMassSpringSystem({muscle}, bones, md::ModelSettings{});
  md::SkinningSettings settings;
  settings.method = md::SkinningMethod::nearest_average;
  const md::MuscleSkin skin(system, 0, muscle.surface, settings);
  const md::BoneTransforms transforms = {Eigen::Isometry3d(Eigen::Translation3d(0.1, 0.2, 0) *
                                                           Eigen::AngleAxisd(0.8, Eigen::Vector3d::UnitY()))};
  md::ParticleState state;
  md::rigidPretransform(system, transforms, state);
  md::Vertices surface;
  skin.update(state.position, transforms, surface);
  EXPECT_LT(largestDistance(surface, transforms[0] * muscle.surface.vertices), 1e-9);
}

TEST(SurfaceSkinning, NearestAverageAddsTheMeanDisplacementOfTheNearestParticles) {
  const md::MuscleSkin skin = skinOf(md::SkinningMethod::nearest_average);
  const Eigen::Vector3d shift(0.001, -0.002, 0.003);
  md::Vertices surface;
  skin.update(spindle().system.rest_position.colwise() + shift, {}, surface);
  EXPECT_LT(largestDistance(surface, spindle().muscle.surface.vertices.colwise() + shift), 1e-12);
}

TEST(SurfaceSkinning, RefusesAnOpenSurfaceNamingTheMuscleAndTheHole) {
  md::TriangleMesh open = spindle().muscle.surface;
  open.triangles.conservativeResize(3, open.triangles.cols() - 1);
  md::SkinningSettings settings;
  try {
    md::MuscleSkin skin(spindle().system, 0, open, settings);
    FAIL() << "an open surface was accepted";
  } catch (const md::SkinningError& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("spindle"), std::string::npos) << message;
    EXPECT_NE(message.find("closed"), std::string::npos) << message;
    EXPECT_NE(message.find("boundary edges"), std::string::npos) << message;
  }
}

TEST(SurfaceSkinning, UpdatesEveryMuscleOfTheSceneInOrder) {
  const md::SyntheticScene scene = md::makeSyntheticThigh(3, 4);
  const md::MassSpringSystem system = md::buildMassSpringSystem(scene.muscles, scene.bones, md::ModelSettings{});
  const md::SurfaceSkinning skinning(system, scene.muscles, md::SkinningSettings{});
  std::vector<md::Vertices> surfaces;
  skinning.update(system.rest_position, md::boneTransformsOf(scene.bones, md::Pose{}), surfaces);
  ASSERT_EQ(surfaces.size(), 3u);
  for (std::size_t m = 0; m < 3; ++m)
    EXPECT_LT(largestDistance(surfaces[m], scene.muscles[m].surface.vertices), 1e-9) << m;
}
