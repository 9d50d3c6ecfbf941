// Specification of a bone's signed distance field: the collision proxy that is the bone, and the inside-bone test.
#include "muscle_deformation/core/collision/bone_distance_field.hpp"
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace md = muscle_deformation;

namespace {

// A femoral-head-sized ball (25 mm radius, 4 subdivisions: its facets lie within 0.2 mm of the sphere).
const Eigen::Vector3d kCentre(0.01, -0.02, 0.03);
constexpr double kRadius = 0.025;
md::TriangleMesh ball() { return md::makeSphereMesh(kCentre, kRadius, 4); }

}  // namespace

TEST(BoneDistanceField, AgreesWithTheExactDistanceToTheMeshWithinATenthOfAVoxel) {
  const md::TriangleMesh mesh = ball();
  const md::BoneDistanceField field(mesh);
  const md::ClosedSurfaceInsideTest exact(mesh, "ball");
  const md::BoneDistanceField::Probe probe = field.probe();
  std::mt19937 random(7);
  std::uniform_real_distribution<double> offset(-0.012, 0.012);
  double worst = 0;
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector3d point = kCentre + Eigen::Vector3d(offset(random), offset(random), offset(random)) +
                                  kRadius * Eigen::Vector3d::Random().normalized();
    const double signed_exact = exact.distanceToSurface(point) * (exact.contains(point) ? -1.0 : 1.0);
    if (signed_exact > 0.5 * field.exteriorBand()) continue;  // beyond the band the field only says "far"
    worst = std::max(worst, std::abs(probe.distance(point) - signed_exact));
  }
  EXPECT_LT(worst, 0.1 * field.voxel());
}

TEST(BoneDistanceField, IsNegativeInsideAndItsGradientPointsOut) {
  const md::BoneDistanceField field(ball());
  const md::BoneDistanceField::Probe probe = field.probe();
  for (const Eigen::Vector3d& direction : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, -1, 0),
                                           Eigen::Vector3d(1, 1, 1).normalized()}) {
    for (const double from_centre : {0.005, 0.015, 0.022, 0.027, 0.032}) {
      Eigen::Vector3d gradient;
      const double distance = probe.distance(kCentre + from_centre * direction, gradient);
      EXPECT_NEAR(distance, from_centre - kRadius, 3e-4) << from_centre;
      EXPECT_GT(gradient.normalized().dot(direction), 0.99) << from_centre;
      // Within the narrow band the distances are exact and the gradient has unit length; deeper (20 mm here) the inside
      // is filled by a sweep that keeps the sign and the way out but not the unit slope (measured 0.91).
      if (std::abs(distance) <= 0.012) EXPECT_NEAR(gradient.norm(), 1.0, 0.05) << from_centre;
    }
  }
}

TEST(BoneDistanceField, BeyondItsBandReadsTheBandWidthWithNoGradient) {
  const md::BoneDistanceField field(ball());
  Eigen::Vector3d gradient;
  const double distance = field.probe().distance(kCentre + Eigen::Vector3d(0.1, 0, 0), gradient);
  EXPECT_NEAR(distance, field.exteriorBand(), 1e-6);  // stored as float
  EXPECT_EQ(gradient, Eigen::Vector3d::Zero());
  EXPECT_GT(field.exteriorBand(), 0.010);
}

TEST(BoneDistanceField, CloserThanNeverMissesWhatTheFullLookupFinds) {
  const md::BoneDistanceField field(ball());
  const md::BoneDistanceField::Probe probe = field.probe();
  std::mt19937 random(3);
  std::uniform_real_distribution<double> coordinate(-0.04, 0.04);
  for (int i = 0; i < 5000; ++i) {
    const Eigen::Vector3d point = kCentre + Eigen::Vector3d(coordinate(random), coordinate(random), coordinate(random));
    for (const double limit : {-0.002, 0.0, 0.003}) {
      double distance = 0;
      Eigen::Vector3d gradient;
      const bool closer = probe.closerThan(point, limit, distance, gradient);
      EXPECT_EQ(closer, probe.distance(point) < limit) << point.transpose() << " limit " << limit;
    }
  }
}

TEST(BoneDistanceField, AnOpenSurfaceIsRefusedNamingTheBone) {
  md::TriangleMesh open = ball();
  open.triangles.conservativeResize(3, open.triangles.cols() - 1);
  const std::string message = md::testing::errorMessageOf<md::BoneFieldError>([&] { md::BoneDistanceField field(open, {}, "bone 'femur_r'"); });
  EXPECT_NE(message.find("bone 'femur_r'"), std::string::npos) << message;
  EXPECT_NE(message.find("boundary edges"), std::string::npos) << message;
}

TEST(BoneDistanceField, ASurfaceMetresAcrossGetsCoarserVoxelsInsteadOfGigabytes) {
  const md::BoneDistanceField field(md::makeSphereMesh(Eigen::Vector3d::Zero(), 1.0, 3));
  EXPECT_GT(field.voxel(), 0.001);
  EXPECT_LT(field.memoryBytes(), std::size_t(200) << 20);
  EXPECT_NEAR(field.probe().distance(Eigen::Vector3d::Zero()), -1.0, 0.05);
}

TEST(BoneDistanceField, InvalidSettingsAreNamed) {
  md::BoneFieldSettings settings;
  settings.voxel_m = 0;
  EXPECT_NE(md::validate(settings).find("voxel"), std::string::npos);
  settings.voxel_m = 0.001;
  settings.exterior_band_m = 0.001;
  EXPECT_NE(md::validate(settings).find("band"), std::string::npos);
  EXPECT_THROW(md::BoneDistanceField(ball(), settings, "bone"), md::BoneFieldError);
}
