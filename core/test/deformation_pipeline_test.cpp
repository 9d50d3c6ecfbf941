// The pipeline the node runs per pose: solve, then skin and measure only what the caller asks for.
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;

namespace {

PipelineSettings smallSettings() {
  PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 10;
  settings.simulation.model.nearest_neighbours = 8;
  settings.simulation.verlet.max_iterations = 30;
  return settings;
}

std::vector<MuscleDescription> descriptionsOf(const std::vector<Muscle>& muscles) {
  std::vector<MuscleDescription> descriptions;
  for (const Muscle& muscle : muscles) descriptions.push_back({muscle.name, "", "", "pelvis", "tibia", {}, {}});
  return descriptions;
}

DeformationPipeline twoMusclePipeline(const PipelineSettings& settings, SyntheticScene scene = makeSyntheticThigh(2, 4)) {
  std::vector<MuscleDescription> descriptions = descriptionsOf(scene.muscles);
  return DeformationPipeline(std::move(descriptions), std::move(scene.muscles), std::move(scene.bones), settings);
}

}  // namespace

TEST(DeformationPipeline, SkinsAndMeasuresOnlyWhatTheCallerAsksFor) {
  const SyntheticScene scene = makeSyntheticThigh(2, 4);
  DeformationPipeline pipeline = twoMusclePipeline(smallSettings(), scene);
  ASSERT_TRUE(pipeline.skinningProblem().empty()) << pipeline.skinningProblem();
  ASSERT_TRUE(pipeline.metricsProblem().empty()) << pipeline.metricsProblem();
  const Pose pose = syntheticThighPose(0.3, 0.2);

  const FrameResult& bare = pipeline.solve(pose, StartMode::cold, false, false);
  EXPECT_TRUE(bare.stats.finite);
  EXPECT_EQ(bare.stats.solver.iterations, 30);
  EXPECT_FALSE(bare.has_surfaces);
  EXPECT_FALSE(bare.has_metrics);
  const BoneTransforms expected = boneTransformsOf(pipeline.simulation().bones(), pose);
  ASSERT_EQ(bare.bone_transforms.size(), expected.size());
  for (std::size_t b = 0; b < expected.size(); ++b)
    EXPECT_TRUE(bare.bone_transforms[b].isApprox(expected[b], 0.0)) << "bone " << b;

  const FrameResult& skinned = pipeline.solve(pose, StartMode::warm, true, false);
  EXPECT_TRUE(skinned.stats.warm_started);
  ASSERT_TRUE(skinned.has_surfaces);
  EXPECT_FALSE(skinned.has_metrics);
  ASSERT_EQ(skinned.surfaces.size(), 2u);
  for (std::size_t m = 0; m < 2; ++m) {
    EXPECT_EQ(skinned.surfaces[m].cols(), scene.muscles[m].surface.vertexCount());
    EXPECT_TRUE(skinned.surfaces[m].allFinite());
  }

  // Metrics need surfaces, so asking for metrics alone skins too.
  const FrameResult& measured = pipeline.solve(pose, StartMode::warm, false, true);
  EXPECT_TRUE(measured.has_surfaces);
  ASSERT_TRUE(measured.has_metrics);
  ASSERT_EQ(measured.metrics.muscles.size(), 2u);
  EXPECT_TRUE(std::isfinite(measured.metrics.volume_error_mean_pct));
  EXPECT_GE(measured.metrics.volume_error_max_pct, measured.metrics.volume_error_mean_pct);
}

TEST(DeformationPipeline, ParticlesAreExactlyThoseOfTheSimulationItWraps) {
  const PipelineSettings settings = smallSettings();
  DeformationPipeline pipeline = twoMusclePipeline(settings);
  SyntheticScene scene = makeSyntheticThigh(2, 4);
  MuscleSimulation simulation(std::move(scene.muscles), std::move(scene.bones), settings.simulation);
  for (const double hip : {0.2, 0.4}) {
    const Pose pose = syntheticThighPose(hip, 0.1);
    pipeline.solve(pose, StartMode::warm, true, true);
    simulation.solve(pose, StartMode::warm);
    EXPECT_EQ(pipeline.simulation().state().position, simulation.state().position) << "hip " << hip;
  }
}

TEST(DeformationPipeline, TheFrameResultReadsTheParticlesInPlaceWithoutCopying) {
  DeformationPipeline pipeline = twoMusclePipeline(smallSettings());
  const FrameResult& frame = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::cold, true, false);
  EXPECT_EQ(&frame.positions(), &pipeline.simulation().state().position);
  EXPECT_EQ(&frame.particles(), &pipeline.simulation().system());
  EXPECT_EQ(&frame.muscles(), &pipeline.descriptions());
  EXPECT_EQ(&frame.bones(), &pipeline.bones());
  ASSERT_TRUE(frame.has_surfaces);
  for (std::size_t m = 0; m < frame.surfaces.size(); ++m)
    EXPECT_EQ(&frame.surfaceTriangles(m), &pipeline.skinning()->muscles()[m].triangles()) << "muscle " << m;
}

TEST(DeformationPipeline, AnOpenMuscleSurfaceTurnsSurfacesOffWithTheReasonAndTheParticlesStillSolve) {
  SyntheticScene scene = makeSyntheticThigh(2, 4);
  TriangleMesh& surface = scene.muscles[1].surface;
  surface.triangles.conservativeResize(Eigen::NoChange, surface.triangleCount() - 1);  // a hole
  DeformationPipeline pipeline = twoMusclePipeline(smallSettings(), scene);
  EXPECT_NE(pipeline.skinningProblem().find("not a closed 2-manifold"), std::string::npos)
      << pipeline.skinningProblem();
  EXPECT_NE(pipeline.metricsProblem().find("needs the surface skinning"), std::string::npos)
      << pipeline.metricsProblem();
  EXPECT_EQ(pipeline.skinning(), nullptr);
  EXPECT_EQ(pipeline.metrics(), nullptr);
  const FrameResult& frame = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
  EXPECT_TRUE(frame.stats.finite);
  EXPECT_FALSE(frame.has_surfaces);
  EXPECT_FALSE(frame.has_metrics);
  EXPECT_NE(pipeline.describe().find("no surfaces: "), std::string::npos) << pipeline.describe();
}

TEST(DeformationPipeline, SurfacesAndMetricsTurnedOffBySettingsSaySo) {
  PipelineSettings settings = smallSettings();
  settings.skin_surfaces = false;
  settings.measure_fidelity = false;
  DeformationPipeline pipeline = twoMusclePipeline(settings);
  EXPECT_EQ(pipeline.skinningProblem(), "turned off (surfaces and surface_metrics are false)");
  EXPECT_EQ(pipeline.metricsProblem(), "turned off (surface_metrics is false)");
  const FrameResult& frame = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
  EXPECT_FALSE(frame.has_surfaces);
  EXPECT_FALSE(frame.has_metrics);
  const std::string description = pipeline.describe();
  EXPECT_NE(description.find("2 muscles, 3 bones"), std::string::npos) << description;
  EXPECT_NE(description.find("solver verlet"), std::string::npos) << description;
}

TEST(DeformationPipeline, FiguresTurnedOffBySettingsAreListedWithTheSettingThatTurnsThemOn) {
  PipelineSettings settings = smallSettings();  // the Verlet solver: no force residual
  settings.simulation.collisions = false;
  settings.measure_fidelity = false;
  DeformationPipeline pipeline = twoMusclePipeline(settings);
  const std::vector<AbsentMetric> absent = pipeline.absentMetrics();
  ASSERT_EQ(absent.size(), 3u);
  EXPECT_EQ(absent[0].figures, "force_residual");
  EXPECT_EQ(absent[0].remedy, "set solver: block_descent");
  EXPECT_NE(absent[1].figures.find("contacts"), std::string::npos);
  EXPECT_EQ(absent[1].remedy, "set collisions: true");
  EXPECT_NE(absent[2].figures.find("volume_error"), std::string::npos);
  EXPECT_EQ(absent[2].reason, "turned off (surface_metrics is false)");
  EXPECT_EQ(absent[2].remedy, "set surface_metrics: true");
  for (const AbsentMetric& a : absent) EXPECT_TRUE(a.turned_off) << a.describe();

  const FrameResult& frame = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
  EXPECT_LT(frame.stats.solver.residual, 0);
  EXPECT_NE(frame.residual_absent_reason.find("verlet solver does not measure it"), std::string::npos);
  EXPECT_FALSE(frame.stats.has_collision);
  EXPECT_EQ(frame.collision_absent_reason, "collisions are off");
  EXPECT_FALSE(frame.has_metrics);
  EXPECT_EQ(frame.metrics_absent_reason, "turned off (surface_metrics is false)");
}

TEST(DeformationPipeline, ADefectiveBoneTurnsTheSurfaceMetricsOffWithAReasonNamingItAndAWayToTurnThemOn) {
  SyntheticScene scene = makeSyntheticThigh(2, 4);
  TriangleMesh& femur = scene.bones[1].surface;
  femur.triangles.conservativeResize(Eigen::NoChange, femur.triangleCount() - 1);  // a hole
  PipelineSettings settings = smallSettings();
  settings.simulation.solver_kind = SolverKind::block_descent;
  DeformationPipeline pipeline = twoMusclePipeline(settings, scene);
  EXPECT_NE(pipeline.skinning(), nullptr);  // the muscles are fine: surfaces still work
  EXPECT_EQ(pipeline.metrics(), nullptr);
  const std::vector<AbsentMetric> absent = pipeline.absentMetrics();
  ASSERT_EQ(absent.size(), 1u);
  EXPECT_FALSE(absent[0].turned_off);
  EXPECT_NE(absent[0].reason.find("bone '" + scene.bones[1].name + "'"), std::string::npos) << absent[0].reason;
  EXPECT_NE(absent[0].remedy.find("closed surface"), std::string::npos) << absent[0].remedy;

  const FrameResult& frame = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
  EXPECT_TRUE(frame.has_surfaces);
  EXPECT_FALSE(frame.has_metrics);
  EXPECT_EQ(frame.metrics_absent_reason, absent[0].reason);
  EXPECT_GE(frame.stats.solver.residual, 0);
  EXPECT_EQ(frame.residual_absent_reason, "");
  EXPECT_TRUE(frame.stats.has_collision);
  EXPECT_EQ(frame.collision_absent_reason, "");
}

TEST(DeformationPipeline, MetricsNotAskedForInASolveSaySo) {
  DeformationPipeline pipeline = twoMusclePipeline(smallSettings());
  ASSERT_NE(pipeline.metrics(), nullptr);
  const FrameResult& frame = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::cold, true, false);
  EXPECT_FALSE(frame.has_metrics);
  EXPECT_EQ(frame.metrics_absent_reason, "not asked for in this solve");
  const FrameResult& measured = pipeline.solve(syntheticThighPose(0.3, 0.2), StartMode::warm, false, true);
  EXPECT_TRUE(measured.has_metrics);
  EXPECT_EQ(measured.metrics_absent_reason, "");
}

TEST(DeformationPipeline, AFrameFromBoneTransformsIsTheFrameFromThePose) {
  DeformationPipeline from_pose = twoMusclePipeline(smallSettings());
  DeformationPipeline from_transforms = twoMusclePipeline(smallSettings());
  for (const double hip : {0.2, 0.5}) {
    const Pose pose = syntheticThighPose(hip, 0.3);
    const BoneTransforms transforms = boneTransformsOf(from_transforms.simulation().bones(), pose);
    const FrameResult& a = from_pose.solve(pose, StartMode::warm, true, false);
    const FrameResult& b = from_transforms.solve(transforms, StartMode::warm, true, false);
    EXPECT_EQ(from_pose.simulation().state().position, from_transforms.simulation().state().position);
    ASSERT_TRUE(a.has_surfaces && b.has_surfaces);
    EXPECT_EQ(a.surfaces[0], b.surfaces[0]);
  }
  const BoneTransforms too_few(1, Eigen::Isometry3d::Identity());
  EXPECT_THROW(from_transforms.solve(too_few, StartMode::cold, false, false), std::invalid_argument);
}

TEST(DeformationPipeline, SurfacesAndMetricsDoNotDependOnTheThreadCount) {
  // The surface stages and metrics share the muscles out on the solver's threads; every figure must come out the same.
  PipelineSettings settings = smallSettings();
  settings.simulation.solver_kind = SolverKind::block_descent;
  settings.simulation.stopping.rule = StoppingRule::iterations;
  settings.simulation.stopping.max_iterations = 3;
  settings.simulation.collision.bone_proxy = BoneProxyKind::distance_field;
  shareStoppingRule(settings.simulation);
  PipelineSettings two_threads = settings;
  settings.simulation.block_descent.threads = 1;
  two_threads.simulation.block_descent.threads = 2;
  DeformationPipeline one = twoMusclePipeline(settings, makeSyntheticThigh(4, 4));
  DeformationPipeline two = twoMusclePipeline(two_threads, makeSyntheticThigh(4, 4));
  for (const double hip : {0.4, 0.9}) {
    const Pose pose = syntheticThighPose(hip, 0.6);
    const FrameResult& a = one.solve(pose, StartMode::warm, true, true);
    const FrameResult& b = two.solve(pose, StartMode::warm, true, true);
    ASSERT_TRUE(a.has_metrics && b.has_metrics);
    ASSERT_EQ(a.volume_corrections.size(), 4u);
    ASSERT_EQ(a.surfaces.size(), b.surfaces.size());
    for (std::size_t m = 0; m < a.surfaces.size(); ++m) EXPECT_EQ(a.surfaces[m], b.surfaces[m]) << "muscle " << m;
    EXPECT_EQ(a.metrics.volume_error_mean_pct, b.metrics.volume_error_mean_pct);
    EXPECT_EQ(a.metrics.max_inside_bone_depth_m, b.metrics.max_inside_bone_depth_m);
    EXPECT_EQ(a.metrics.vertices_inside_bone, b.metrics.vertices_inside_bone);
    EXPECT_EQ(a.metrics.particles_inside_bone, b.metrics.particles_inside_bone);
    EXPECT_EQ(a.metrics.max_particle_inside_bone_depth_m, b.metrics.max_particle_inside_bone_depth_m);
    for (std::size_t m = 0; m < a.metrics.muscles.size(); ++m) {
      EXPECT_EQ(a.metrics.muscles[m].volume_m3, b.metrics.muscles[m].volume_m3) << "muscle " << m;
      EXPECT_EQ(a.metrics.muscles[m].deepest_bone, b.metrics.muscles[m].deepest_bone) << "muscle " << m;
      EXPECT_EQ(a.bone_corrections[m].vertices_moved, b.bone_corrections[m].vertices_moved) << "muscle " << m;
    }
  }
}
