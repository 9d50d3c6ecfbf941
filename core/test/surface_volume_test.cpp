// Specifications of the surface volume constraint: skinned muscle surfaces are projected back to their rest volume,
// never into a bone, and the pipeline applies it to what the user sees.
#include "muscle_deformation/core/surfaces/surface_volume.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;

namespace {

const TriangleMesh kCylinder = makeCylinderMesh({0, 0, 0}, {0, 0, 0.2}, 0.03, 32, 20);

double volumeOf(const Vertices& vertices, const Triangles& triangles) {
  return std::abs(enclosedVolume(vertices, triangles));
}

// The cylinder squeezed across its axis: a muscle that lost volume the way a skinned surface does.
Vertices squeezed(const TriangleMesh& mesh, double across) {
  Vertices v = mesh.vertices;
  v.row(0) *= across;
  v.row(1) *= across;
  return v;
}

SurfaceVolumeConstraint constraintFor(const TriangleMesh& mesh, BoneFields fields = {}) {
  return SurfaceVolumeConstraint({mesh.triangles}, {mesh.vertices}, std::move(fields), SurfaceVolumeSettings{});
}

}  // namespace

TEST(SurfaceVolume, ASqueezedCylinderIsProjectedBackToItsRestVolume) {
  const SurfaceVolumeConstraint constraint = constraintFor(kCylinder);
  const double rest = volumeOf(kCylinder.vertices, kCylinder.triangles);
  std::vector<Vertices> surfaces{squeezed(kCylinder, 0.9)};
  const double lost_pct = 100 * (volumeOf(surfaces[0], kCylinder.triangles) - rest) / rest;
  EXPECT_NEAR(lost_pct, -19.0, 0.1) << "0.9 x 0.9 across the axis";

  const std::vector<SurfaceVolumeCorrection> corrections = constraint.apply(surfaces, {});
  ASSERT_EQ(corrections.size(), 1u);
  EXPECT_NEAR(corrections[0].volume_error_before_pct, lost_pct, 1e-9);
  EXPECT_LE(std::abs(corrections[0].volume_error_after_pct), 0.01);
  EXPECT_NEAR(volumeOf(surfaces[0], kCylinder.triangles), rest, 1e-4 * rest);
  // Every vertex moved about the same distance outwards along its normal: a smooth 27 mm x 200 mm cylinder offset by
  // 2.62 mm on wall and caps has the 30 mm cylinder's volume.
  EXPECT_NEAR(corrections[0].mean_offset_m, 0.00262, 0.0001);
  EXPECT_LT(corrections[0].max_offset_m, 1.1 * corrections[0].mean_offset_m);
  EXPECT_EQ(corrections[0].vertices_held_by_bone, 0);
}

TEST(SurfaceVolume, AnInflatedSurfaceShrinksBackAndAnUntouchedOneStaysAsItIs) {
  const SurfaceVolumeConstraint constraint({kCylinder.triangles, kCylinder.triangles},
                                           {kCylinder.vertices, kCylinder.vertices}, {}, SurfaceVolumeSettings{});
  std::vector<Vertices> surfaces{squeezed(kCylinder, 1.1), kCylinder.vertices};
  const std::vector<SurfaceVolumeCorrection> corrections = constraint.apply(surfaces, {});
  EXPECT_GT(corrections[0].volume_error_before_pct, 20.0);
  EXPECT_LE(std::abs(corrections[0].volume_error_after_pct), 0.01);
  EXPECT_EQ(surfaces[1], kCylinder.vertices) << "a surface at its rest volume is not touched";
  EXPECT_EQ(corrections[1].max_offset_m, 0.0);
}

TEST(SurfaceVolume, InwardWoundSurfacesKeepTheirVolumeToo) {
  TriangleMesh inward = kCylinder;
  inward.triangles.row(1).swap(inward.triangles.row(2));
  const SurfaceVolumeConstraint constraint = constraintFor(inward);
  std::vector<Vertices> surfaces{squeezed(inward, 0.95)};
  const std::vector<SurfaceVolumeCorrection> corrections = constraint.apply(surfaces, {});
  EXPECT_LT(corrections[0].volume_error_before_pct, -9.0);
  EXPECT_LE(std::abs(corrections[0].volume_error_after_pct), 0.01);
  EXPECT_NEAR(volumeOf(surfaces[0], inward.triangles), constraint.restVolume(0), 1e-4 * constraint.restVolume(0));
}

TEST(SurfaceVolume, VerticesTheProjectionWouldPutIntoABoneStayWhereTheyAre) {
  // A squeezed cylinder whose side touches a box bone: inflating it back would push that side into the bone.
  const BoneFields fields{std::make_shared<BoneDistanceField>(makeBoxMesh({0.0275, -0.04, -0.01}, {0.06, 0.04, 0.21}, 0.01),
                                                               BoneFieldSettings{}, "box")};
  const SurfaceVolumeConstraint constraint = constraintFor(kCylinder, fields);
  std::vector<Vertices> surfaces{squeezed(kCylinder, 0.9)};  // its wall now at x = 27 mm, 0.5 mm from the bone
  const std::vector<SurfaceVolumeCorrection> corrections = constraint.apply(surfaces, {Eigen::Isometry3d::Identity()});
  EXPECT_GT(corrections[0].vertices_held_by_bone, 0);
  EXPECT_LE(std::abs(corrections[0].volume_error_after_pct), 0.01) << "the other vertices make up the volume";
  const BoneDistanceField::Probe probe = fields[0]->probe();
  double deepest = 0;
  for (Eigen::Index i = 0; i < surfaces[0].cols(); ++i) deepest = std::min(deepest, probe.distance(surfaces[0].col(i)));
  // Moves shorter than a quarter voxel are not checked: nothing deeper than that.
  EXPECT_GE(deepest, -0.25 * fields[0]->voxel());

  // Without the bone the same side goes 2 mm into where the bone is.
  const SurfaceVolumeConstraint free = constraintFor(kCylinder);
  std::vector<Vertices> unguarded{squeezed(kCylinder, 0.9)};
  free.apply(unguarded, {});
  double deepest_unguarded = 0;
  for (Eigen::Index i = 0; i < unguarded[0].cols(); ++i)
    deepest_unguarded = std::min(deepest_unguarded, probe.distance(unguarded[0].col(i)));
  EXPECT_LT(deepest_unguarded, -0.001);
}

TEST(SurfaceVolume, ABoneMovedByItsTransformIsWhereItIsLookedFor) {
  // The box bone at rest is far from the cylinder; its pose brings it to touch the squeezed wall.
  const BoneFields fields{std::make_shared<BoneDistanceField>(makeBoxMesh({0.5275, -0.04, -0.01}, {0.56, 0.04, 0.21}, 0.01),
                                                               BoneFieldSettings{}, "box")};
  const SurfaceVolumeConstraint constraint = constraintFor(kCylinder, fields);
  std::vector<Vertices> surfaces{squeezed(kCylinder, 0.9)};
  const Eigen::Isometry3d moved(Eigen::Translation3d(-0.5, 0, 0));
  const std::vector<SurfaceVolumeCorrection> corrections = constraint.apply(surfaces, {moved});
  EXPECT_GT(corrections[0].vertices_held_by_bone, 0);
}

TEST(SurfaceVolume, RefusesASurfaceWithoutVolumeAndMismatchedInput) {
  TriangleMesh flat = kCylinder;
  flat.vertices.row(0).setZero();
  EXPECT_THROW(constraintFor(flat), std::invalid_argument);
  const SurfaceVolumeConstraint constraint = constraintFor(kCylinder);
  std::vector<Vertices> two{kCylinder.vertices, kCylinder.vertices};
  EXPECT_THROW(constraint.apply(two, {}), std::invalid_argument);
  SurfaceVolumeSettings bad;
  bad.max_rounds = 0;
  EXPECT_FALSE(validate(bad).empty());
  EXPECT_THROW(SurfaceVolumeConstraint({kCylinder.triangles}, {kCylinder.vertices}, {}, bad), std::invalid_argument);
}

TEST(SurfaceVolume, ThePipelineKeepsTheVolumeOfWhatTheUserSeesAndSaysWhatItChanged) {
  // The synthetic thigh bent at hip and knee: with the constraint every skinned muscle keeps its rest volume; without
  // it the same particles give surfaces that do not.
  PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 10;
  settings.simulation.model.nearest_neighbours = 8;
  const FrameStopping stopping = FrameStopping::of(StoppingSettings::afterIterations(60));
  const Pose pose = syntheticThighPose(0.8, 1.2);
  auto run = [&](bool keep) {
    PipelineSettings s = settings;
    s.surface_volume.keep_volume = keep;
    SyntheticScene scene = makeSyntheticThigh(3, 4);
    std::vector<MuscleDescription> descriptions;
    for (const Muscle& muscle : scene.muscles) descriptions.push_back({muscle.name, "", "", "pelvis", "tibia", {}, {}});
    DeformationPipeline pipeline(std::move(descriptions), std::move(scene.muscles), std::move(scene.bones), s);
    const FrameResult& frame =
        pipeline.solve(boneTransformsOf(pipeline.bones(), pose), StartMode::cold, stopping, true, true);
    EXPECT_TRUE(frame.has_metrics);
    return std::make_pair(frame.metrics, frame.volume_corrections);
  };
  const auto [without, no_corrections] = run(false);
  const auto [with, corrections] = run(true);
  EXPECT_TRUE(no_corrections.empty());
  ASSERT_EQ(corrections.size(), 3u);
  EXPECT_GT(without.volume_error_max_pct, 0.5) << "the skinned surfaces alone change volume";
  EXPECT_LE(with.volume_error_max_pct, 0.01);
  for (std::size_t m = 0; m < 3; ++m)
    EXPECT_NEAR(corrections[m].volume_error_before_pct, without.muscles[m].volume_error_pct, 1e-9)
        << "the correction reports the skinned surface's own error";
}
