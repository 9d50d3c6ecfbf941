// Specifications of the fidelity metrics: enclosed volume, the exact inside-bone test, the inside-bone count and depth
// read from the bones' distance fields, fibre length change, and refusal of open surfaces.
#include "muscle_deformation/core/surfaces/deformation_metrics.hpp"

#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

namespace md = muscle_deformation;

namespace {

constexpr double kPi = 3.14159265358979323846;

using muscle_deformation::testing::unitCube;

// A one-muscle system whose single fibre is the polyline `fibre` (systemFromParticles: one muscle, one fibre).
md::MassSpringSystem oneFibreSystem(const Eigen::Matrix3Xd& fibre) { return md::systemFromParticles(fibre, {}, 0.001, 10); }

Eigen::Matrix3Xd straightFibre(int points) {
  Eigen::Matrix3Xd fibre(3, points);
  for (int k = 0; k < points; ++k) fibre.col(k) = Eigen::Vector3d(0.5, 0.5, 0.1 + 0.8 * k / (points - 1));
  return fibre;
}

md::Muscle cubeMuscle() { return {"particles", unitCube(), {}}; }

}  // namespace

TEST(DeformationMetrics, VolumeOfAUnitCubeIsOne) {
  const md::MassSpringSystem system = oneFibreSystem(straightFibre(5));
  const md::DeformationMetrics metrics({}, {cubeMuscle()}, system);
  EXPECT_NEAR(metrics.restVolume(0), 1.0, 1e-14);
  const md::SceneMetrics scene = metrics.measure({unitCube().vertices}, system.rest_position, {});
  EXPECT_NEAR(scene.muscles[0].volume_m3, 1.0, 1e-14);
  EXPECT_NEAR(scene.muscles[0].volume_error_pct, 0.0, 1e-12);
}

TEST(DeformationMetrics, VolumeErrorOfACubeScaledByTwoIsSevenHundredPercent) {
  const md::MassSpringSystem system = oneFibreSystem(straightFibre(5));
  const md::DeformationMetrics metrics({}, {cubeMuscle()}, system);
  const md::SceneMetrics scene = metrics.measure({2.0 * unitCube().vertices}, system.rest_position, {});
  EXPECT_NEAR(scene.muscles[0].volume_error_pct, 700.0, 1e-9);
  EXPECT_NEAR(scene.volume_error_max_pct, 700.0, 1e-9);
  EXPECT_NEAR(scene.volume_error_mean_pct, 700.0, 1e-9);
}

TEST(DeformationMetrics, VolumeOfASphereMeshApproachesTheBallsVolume) {
  // An icosphere is inscribed in its sphere: slightly less volume, converging as it is refined.
  const double r = 0.05, ball = 4.0 / 3.0 * kPi * r * r * r;
  const double coarse = md::enclosedVolume(md::makeSphereMesh({0.1, 0.2, 0.3}, r, 3));
  const double fine = md::enclosedVolume(md::makeSphereMesh({0.1, 0.2, 0.3}, r, 5));
  EXPECT_LT(coarse, ball);
  EXPECT_NEAR(coarse / ball, 1.0, 0.01);
  EXPECT_NEAR(fine / ball, 1.0, 0.001);
}

TEST(ClosedSurfaceInsideTest, AgreesWithTheSphereAwayFromItsSurface) {
  // Tolerance near the surface: a subdivision-3 icosphere of radius r lies between 0.99 r and r from its centre, so
  // points with |p - c| < 0.99 r are inside and points beyond r outside; the band between is not asserted.
  const Eigen::Vector3d centre(0.01, -0.02, 0.03);
  const double r = 0.04;
  const md::ClosedSurfaceInsideTest sphere(md::makeSphereMesh(centre, r, 3), "sphere");
  std::mt19937 random(3);
  std::uniform_real_distribution<double> coordinate(-1.5 * r, 1.5 * r);
  int inside = 0, outside = 0;
  for (int i = 0; i < 5000; ++i) {
    const Eigen::Vector3d offset(coordinate(random), coordinate(random), coordinate(random));
    if (offset.norm() < 0.99 * r) {
      EXPECT_TRUE(sphere.contains(centre + offset)) << offset.transpose();
      ++inside;
    } else if (offset.norm() > r) {
      EXPECT_FALSE(sphere.contains(centre + offset)) << offset.transpose();
      ++outside;
    }
  }
  EXPECT_GT(inside, 500);
  EXPECT_GT(outside, 500);
  EXPECT_TRUE(sphere.contains(centre));  // its +z ray passes exactly through a mesh vertex
}

TEST(ClosedSurfaceInsideTest, IsRightWhenTheRayPassesExactlyThroughVerticesAndEdges) {
  const double r = 1.0;
  const md::TriangleMesh mesh = md::makeSphereMesh(Eigen::Vector3d::Zero(), r, 2);
  const md::ClosedSurfaceInsideTest sphere(mesh, "sphere");
  auto check = [&](const Eigen::Vector3d& on_ray) {
    const Eigen::Vector3d point = on_ray - Eigen::Vector3d(0, 0, 0.3 * r);  // the +z ray from here hits on_ray
    if (point.norm() < 0.98 * r) {
      EXPECT_TRUE(sphere.contains(point)) << point.transpose();
    } else if (point.norm() > r) {
      EXPECT_FALSE(sphere.contains(point)) << point.transpose();
    }
  };
  for (Eigen::Index v = 0; v < mesh.vertexCount(); ++v) check(mesh.vertices.col(v));
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t)
    for (int e = 0; e < 3; ++e)
      check(0.5 * (mesh.vertices.col(mesh.triangles(e, t)) + mesh.vertices.col(mesh.triangles((e + 1) % 3, t))));
}

TEST(ClosedSurfaceInsideTest, DepthIsTheDistanceToTheBoneSurface) {
  const md::ClosedSurfaceInsideTest sphere(md::makeSphereMesh(Eigen::Vector3d::Zero(), 1.0, 4), "sphere");
  // Within the mesh's sagitta (under 0.002 r at subdivision 4) of the analytic r - |p|.
  EXPECT_NEAR(sphere.distanceToSurface(Eigen::Vector3d(0.2, 0.1, -0.3)), 1.0 - Eigen::Vector3d(0.2, 0.1, -0.3).norm(), 2e-3);
}

TEST(ClosedSurfaceInsideTest, RefusesAnOpenSurface) {
  md::TriangleMesh open = md::makeSphereMesh(Eigen::Vector3d::Zero(), 1.0, 1);
  open.triangles.conservativeResize(3, open.triangles.cols() - 2);
  try {
    md::ClosedSurfaceInsideTest test(open, "bone 'femur'");
    FAIL() << "an open surface was accepted";
  } catch (const md::OpenSurfaceError& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("femur"), std::string::npos) << message;
    EXPECT_NE(message.find("not closed"), std::string::npos) << message;
  }
}

TEST(DeformationMetrics, RefusesAnOpenMuscleSurface) {
  md::Muscle muscle = cubeMuscle();
  muscle.surface.triangles.conservativeResize(3, 11);
  EXPECT_THROW(md::DeformationMetrics({}, {muscle}, oneFibreSystem(straightFibre(5))), md::MetricsError);
}

TEST(DeformationMetrics, CountsSurfaceVerticesInsideAPosedBoneWithTheirDepth) {
  // A unit-cube muscle and a sphere bone of radius 2 moved (by the pose) so that its centre is the cube's centre: all
  // 8 corners are inside, at depth 2 - sqrt(3)/2 from the sphere.
  const md::Bone bone{0, "ball", md::makeSphereMesh(Eigen::Vector3d(5, 0, 0), 2.0, 4)};
  const md::MassSpringSystem system = oneFibreSystem(straightFibre(5));
  const md::DeformationMetrics metrics({bone}, {cubeMuscle()}, system);
  const md::BoneTransforms pose = {Eigen::Isometry3d(Eigen::Translation3d(-4.5, 0.5, 0.5))};
  const md::SceneMetrics scene = metrics.measure({unitCube().vertices}, system.rest_position, pose);
  EXPECT_EQ(scene.muscles[0].vertices_inside_bone, 8);
  EXPECT_EQ(scene.vertices_inside_bone, 8);
  EXPECT_NEAR(scene.max_inside_bone_depth_m, 2.0 - std::sqrt(3.0) / 2, 0.005);
  EXPECT_EQ(scene.muscles[0].deepest_bone, "ball");

  const md::SceneMetrics at_rest = metrics.measure({unitCube().vertices}, system.rest_position, {});
  EXPECT_EQ(at_rest.vertices_inside_bone, 0);  // the bone at rest is far away
  EXPECT_EQ(at_rest.max_inside_bone_depth_m, 0.0);
}

TEST(DeformationMetrics, TheInsideBoneCountFromTheBonesFieldIsTheExactTestsAwayFromTheSurface) {
  // A bone-sized ball (25 mm) and a "surface" of the unit cube's corners (a metre away) plus 3000 random vertices
  // around the ball: every vertex more than a fifth of a millimetre from the ball's mesh is counted as the exact ray
  // test says, and the deepest is as deep (it lies within the narrow band where the field's distances are exact).
  const Eigen::Vector3d centre(-1, -1, -1);
  const md::Bone bone{0, "ball", md::makeSphereMesh(centre, 0.025, 4)};
  const md::ClosedSurfaceInsideTest exact(bone.surface, "ball");
  const md::MassSpringSystem system = oneFibreSystem(straightFibre(5));
  const md::DeformationMetrics metrics({bone}, {cubeMuscle()}, system);
  std::mt19937 random(11);
  std::uniform_real_distribution<double> coordinate(-0.03, 0.03);
  md::Vertices surface = unitCube().vertices;
  int exact_inside = 0;
  double exact_deepest = 0;
  for (int i = 0; i < 3000;) {
    const Eigen::Vector3d point = centre + Eigen::Vector3d(coordinate(random), coordinate(random), coordinate(random));
    const double distance = exact.distanceToSurface(point);
    if (distance < 2e-4 || (exact.contains(point) && distance > 0.012)) continue;
    surface.conservativeResize(3, surface.cols() + 1);
    surface.col(surface.cols() - 1) = point;
    if (exact.contains(point)) {
      ++exact_inside;
      exact_deepest = std::max(exact_deepest, distance);
    }
    ++i;
  }
  const md::SceneMetrics scene = metrics.measure({surface}, system.rest_position, {});
  EXPECT_EQ(scene.vertices_inside_bone, exact_inside);
  EXPECT_NEAR(scene.max_inside_bone_depth_m, exact_deepest, 1e-4);
}

TEST(DeformationMetrics, CountsParticlesInsideABoneWithTheirDepthButNotAttachmentsToItOrATendonsBoneAnchor) {
  // A fibre through a bone-sized ball (radius 25 mm): its particles at z = +-15 mm lie 10 mm deep, the two at +-30 mm
  // outside. A fifth particle at the ball's centre is a tendon's anchor, the bone's own point: not a muscle particle.
  Eigen::Matrix3Xd particles(3, 5);
  particles << 0, 0, 0, 0, 0,  //
      0, 0, 0, 0, 0,           //
      -0.03, -0.015, 0.015, 0.03, 0;
  md::MassSpringSystem system = oneFibreSystem(particles);
  system.fibre_of[4] = md::kTendonAnchor;
  const md::Bone bone{0, "ball", md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.025, 4)};
  const md::DeformationMetrics metrics({bone}, {cubeMuscle()}, system);

  const md::SceneMetrics scene = metrics.measure({unitCube().vertices}, system.rest_position, {});
  EXPECT_EQ(scene.muscles[0].particles_inside_bone, 2);
  EXPECT_EQ(scene.particles_inside_bone, 2);
  EXPECT_NEAR(scene.muscles[0].max_particle_inside_bone_depth_m, 0.010, 2e-4);  // the mesh is inscribed in the ball
  EXPECT_EQ(scene.max_particle_inside_bone_depth_m, scene.muscles[0].max_particle_inside_bone_depth_m);
  EXPECT_EQ(scene.muscles[0].deepest_particle_bone, "ball");

  // Fixed to the ball, the deeper particles are its attachment there, not a penetration.
  md::MassSpringSystem attached = system;
  attached.is_fixed[1] = attached.is_fixed[2] = 1;
  attached.fixed_bone[1] = attached.fixed_bone[2] = 0;
  const md::DeformationMetrics attached_metrics({bone}, {cubeMuscle()}, attached);
  const md::SceneMetrics at_attachment = attached_metrics.measure({unitCube().vertices}, attached.rest_position, {});
  EXPECT_EQ(at_attachment.particles_inside_bone, 0);
  EXPECT_EQ(at_attachment.max_particle_inside_bone_depth_m, 0.0);

  // The same particles with the bone moved 1 m away by the pose: none inside, depth 0, no bone named.
  const md::SceneMetrics moved =
      metrics.measure({unitCube().vertices}, system.rest_position, {Eigen::Isometry3d(Eigen::Translation3d(1, 0, 0))});
  EXPECT_EQ(moved.particles_inside_bone, 0);
  EXPECT_EQ(moved.max_particle_inside_bone_depth_m, 0.0);
  EXPECT_EQ(moved.muscles[0].deepest_particle_bone, "");
}

TEST(DeformationMetrics, RememberingWhatItReadOfTheBonesChangesNoFigure) {
  // Points scattered around a bone-sized ball (surface vertices and particles alike) while the ball moves through them
  // in 2 mm steps, turns, and jumps back: the metrics that skip points their last reads proved out of the ball give, in
  // every frame, exactly what a fresh instance reading every point gives.
  const md::Bone bone{0, "ball", md::makeSphereMesh(Eigen::Vector3d::Zero(), 0.025, 4)};
  std::mt19937 random(5);
  std::uniform_real_distribution<double> coordinate(-0.05, 0.05);
  Eigen::Matrix3Xd points(3, 2000);
  for (Eigen::Index i = 0; i < points.cols(); ++i)
    points.col(i) = Eigen::Vector3d(coordinate(random), coordinate(random), coordinate(random));
  md::Vertices surface = unitCube().vertices;
  surface.conservativeResize(3, 8 + points.cols());
  surface.rightCols(points.cols()) = points;
  const md::MassSpringSystem system = oneFibreSystem(points);
  const md::DeformationMetrics remembering({bone}, {cubeMuscle()}, system);
  for (int frame = 0; frame < 25; ++frame) {
    const double shift = frame < 24 ? 0.002 * frame : 0.0;  // the last frame jumps back
    const Eigen::Isometry3d pose = Eigen::Translation3d(shift, 0.5 * shift, 0) *
                                   Eigen::AngleAxisd(0.05 * frame, Eigen::Vector3d(0, 0.6, 0.8));
    const md::SceneMetrics cached = remembering.measure({surface}, points, {pose});
    const md::DeformationMetrics fresh_metrics({bone}, {cubeMuscle()}, system);
    const md::SceneMetrics fresh = fresh_metrics.measure({surface}, points, {pose});
    ASSERT_GT(fresh.vertices_inside_bone, 0) << "frame " << frame;
    EXPECT_EQ(cached.vertices_inside_bone, fresh.vertices_inside_bone) << "frame " << frame;
    EXPECT_EQ(cached.max_inside_bone_depth_m, fresh.max_inside_bone_depth_m) << "frame " << frame;
    EXPECT_EQ(cached.particles_inside_bone, fresh.particles_inside_bone) << "frame " << frame;
    EXPECT_EQ(cached.max_particle_inside_bone_depth_m, fresh.max_particle_inside_bone_depth_m) << "frame " << frame;
  }
}

TEST(DeformationMetrics, FibreLengthChangeOfAStretchedFibreIsItsStretch) {
  const md::MassSpringSystem system = oneFibreSystem(straightFibre(7));
  const md::DeformationMetrics metrics({}, {cubeMuscle()}, system);
  Eigen::Matrix3Xd stretched = system.rest_position;
  stretched.row(2) = (stretched.row(2).array() - 0.1) * 1.1 + 0.1;
  const md::SceneMetrics scene = metrics.measure({unitCube().vertices}, stretched, {});
  EXPECT_EQ(scene.muscles[0].fibres, 1);
  EXPECT_NEAR(scene.muscles[0].fibre_length_change_mean_pct, 10.0, 1e-9);
  EXPECT_NEAR(scene.muscles[0].fibre_length_change_min_pct, 10.0, 1e-9);
  EXPECT_NEAR(scene.muscles[0].fibre_length_change_max_pct, 10.0, 1e-9);
}

TEST(DeformationMetrics, ReportsTheRangeOfFibreLengthChangeOverAMusclesFibres) {
  const md::SyntheticScene scene = md::makeSyntheticThigh(1, 3);
  const md::MassSpringSystem system = md::buildMassSpringSystem(scene.muscles, scene.bones, md::ModelSettings{});
  const md::DeformationMetrics metrics(scene.bones, scene.muscles, system);
  Eigen::Matrix3Xd moved = system.rest_position;
  // Shorten the first fibre by moving all its particles but the first towards the first: 20 % shorter.
  const Eigen::Vector3d first = moved.col(0);
  for (Eigen::Index i = 1; i < moved.cols() && system.fibre_of[i] == system.fibre_of[0]; ++i)
    moved.col(i) = first + 0.8 * (moved.col(i) - first);
  const md::SceneMetrics result = metrics.measure({scene.muscles[0].surface.vertices}, moved, {});
  EXPECT_EQ(result.muscles[0].fibres, 9);
  EXPECT_NEAR(result.muscles[0].fibre_length_change_min_pct, -20.0, 1e-9);
  EXPECT_NEAR(result.muscles[0].fibre_length_change_max_pct, 0.0, 1e-9);
  EXPECT_NEAR(result.muscles[0].fibre_length_change_mean_pct, -20.0 / 9, 1e-9);
}
