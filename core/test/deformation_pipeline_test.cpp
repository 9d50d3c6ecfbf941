// The pipeline the node runs per pose: solve, then skin and measure only what the caller asks for.
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "../src/pipeline/muscle_simulation.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;

namespace {

PipelineSettings smallSettings() {
  PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 10;
  settings.simulation.model.nearest_neighbours = 8;
  return settings;
}

// 30 iterations a frame.
FrameStopping smallStopping() { return FrameStopping::of(StoppingSettings::afterIterations(30)); }

// The pipeline's solve of `pose` (its bone transforms).
const FrameResult& solvePose(DeformationPipeline& pipeline, const Pose& pose, StartMode start, bool want_surfaces,
                             bool want_metrics, const FrameStopping& stopping = smallStopping()) {
  return pipeline.solve(boneTransformsOf(pipeline.bones(), pose), start, stopping, want_surfaces, want_metrics);
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

  const FrameResult& bare = solvePose(pipeline, pose, StartMode::cold, false, false);
  EXPECT_TRUE(bare.stats.finite);
  EXPECT_EQ(bare.stats.solver.iterations, 30);
  EXPECT_FALSE(bare.has_surfaces);
  EXPECT_FALSE(bare.has_metrics);
  const BoneTransforms expected = boneTransformsOf(scene.bones, pose);
  ASSERT_EQ(bare.bone_transforms.size(), expected.size());
  for (std::size_t b = 0; b < expected.size(); ++b)
    EXPECT_TRUE(bare.bone_transforms[b].isApprox(expected[b], 0.0)) << "bone " << b;

  const FrameResult& skinned = solvePose(pipeline, pose, StartMode::warm, true, false);
  EXPECT_TRUE(skinned.stats.warm_started);
  ASSERT_TRUE(skinned.has_surfaces);
  EXPECT_FALSE(skinned.has_metrics);
  ASSERT_EQ(skinned.surfaces.size(), 2u);
  for (std::size_t m = 0; m < 2; ++m) {
    EXPECT_EQ(skinned.surfaces[m].cols(), scene.muscles[m].surface.vertexCount());
    EXPECT_TRUE(skinned.surfaces[m].allFinite());
  }

  // Metrics need surfaces, so asking for metrics alone skins too.
  const FrameResult& measured = solvePose(pipeline, pose, StartMode::warm, false, true);
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
    solvePose(pipeline, pose, StartMode::warm, true, true);
    muscle_deformation::testing::solvePose(simulation, pose, StartMode::warm, smallStopping());
    EXPECT_EQ(pipeline.state().position, simulation.state().position) << "hip " << hip;
  }
}

TEST(DeformationPipeline, TheFrameResultReadsTheParticlesInPlaceWithoutCopying) {
  DeformationPipeline pipeline = twoMusclePipeline(smallSettings());
  const FrameResult& frame = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::cold, true, false);
  EXPECT_EQ(&frame.positions(), &pipeline.state().position);
  EXPECT_EQ(&frame.particles(), &pipeline.system());
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
  const FrameResult& frame = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
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
  const FrameResult& frame = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
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

  const FrameResult& frame = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::cold, true, true);
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

  // Block descent's own default rule before stopping came with each solve: the force residual 1e-3, 100 sweeps.
  const FrameResult& frame = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::cold, true, true,
                                       FrameStopping::of(StoppingSettings::atResidual(1e-3, 100)));
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
  const FrameResult& frame = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::cold, true, false);
  EXPECT_FALSE(frame.has_metrics);
  EXPECT_EQ(frame.metrics_absent_reason, "not asked for in this solve");
  const FrameResult& measured = solvePose(pipeline, syntheticThighPose(0.3, 0.2), StartMode::warm, false, true);
  EXPECT_TRUE(measured.has_metrics);
  EXPECT_EQ(measured.metrics_absent_reason, "");
}

TEST(DeformationPipeline, AFrameFromThePosesBoneTransformsOfTheSceneIsTheFrameOfThePipelinesBones) {
  // A pose is solved as bone transforms (there is no pose overload): the transforms a caller makes from the scene's
  // bones and those made from the pipeline's own bones() give the same frame, which reports the transforms it solved.
  const SyntheticScene scene = makeSyntheticThigh(2, 4);
  DeformationPipeline from_pipeline_bones = twoMusclePipeline(smallSettings(), scene);
  DeformationPipeline from_scene_bones = twoMusclePipeline(smallSettings(), scene);
  for (const double hip : {0.2, 0.5}) {
    const Pose pose = syntheticThighPose(hip, 0.3);
    const BoneTransforms transforms = boneTransformsOf(scene.bones, pose);
    const FrameResult& a = solvePose(from_pipeline_bones, pose, StartMode::warm, true, false);
    const FrameResult& b = from_scene_bones.solve(transforms, StartMode::warm, smallStopping(), true, false);
    EXPECT_EQ(from_pipeline_bones.state().position, from_scene_bones.state().position);
    ASSERT_TRUE(a.has_surfaces && b.has_surfaces);
    EXPECT_EQ(a.surfaces[0], b.surfaces[0]);
    ASSERT_EQ(b.bone_transforms.size(), transforms.size());
    for (std::size_t bone = 0; bone < transforms.size(); ++bone)
      EXPECT_TRUE(b.bone_transforms[bone].isApprox(transforms[bone], 0.0)) << "bone " << bone;
  }
  const BoneTransforms too_few(1, Eigen::Isometry3d::Identity());
  EXPECT_THROW(from_scene_bones.solve(too_few, StartMode::cold, smallStopping(), false, false), std::invalid_argument);
}

TEST(DeformationPipeline, SurfacesAndMetricsDoNotDependOnTheThreadCount) {
  // The surface stages and metrics share the muscles out on the solver's threads; every figure must come out the same.
  PipelineSettings settings = smallSettings();
  settings.simulation.solver_kind = SolverKind::block_descent;
  const FrameStopping three = FrameStopping::of(StoppingSettings::afterIterations(3));
  settings.simulation.collision.bone_proxy = BoneProxyKind::distance_field;
  PipelineSettings two_threads = settings;
  settings.threads = 1;
  two_threads.threads = 2;
  DeformationPipeline one = twoMusclePipeline(settings, makeSyntheticThigh(4, 4));
  DeformationPipeline two = twoMusclePipeline(two_threads, makeSyntheticThigh(4, 4));
  for (const double hip : {0.4, 0.9}) {
    const Pose pose = syntheticThighPose(hip, 0.6);
    const FrameResult& a = solvePose(one, pose, StartMode::warm, true, true, three);
    const FrameResult& b = solvePose(two, pose, StartMode::warm, true, true, three);
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

TEST(DeformationPipeline, RefineContinuesTheLastFramesSolveAtTheSamePoseAndNeedsAFrame) {
  PipelineSettings settings = smallSettings();
  settings.simulation.solver_kind = SolverKind::block_descent;
  settings.simulation.block_descent.tissue_relaxation_s = 0.0005;
  settings.skin_surfaces = false;  // the particles alone: quick to set up
  settings.measure_fidelity = false;
  DeformationPipeline pipeline = twoMusclePipeline(settings);
  const FrameStopping one_sweep = FrameStopping::of(StoppingSettings::afterIterations(1));
  EXPECT_THROW(pipeline.refine(one_sweep, false, false), std::logic_error);

  const Pose pose = syntheticThighPose(0.3, 0.2);
  const double first_residual =
      solvePose(pipeline, pose, StartMode::cold, false, false, one_sweep).stats.solver.residual;
  const BoneTransforms solved_at = pipeline.boneTransforms();
  const FrameResult& refined = pipeline.refine(one_sweep, false, false);
  EXPECT_EQ(refined.stats.solver.iterations, 1);
  EXPECT_LT(refined.stats.solver.residual, first_residual) << "the sweeps continue towards the same answer";
  ASSERT_EQ(refined.bone_transforms.size(), solved_at.size());
  for (std::size_t b = 0; b < solved_at.size(); ++b)
    EXPECT_TRUE(refined.bone_transforms[b].isApprox(solved_at[b], 0.0)) << "bone " << b;
  pipeline.reset();
  EXPECT_THROW(pipeline.refine(one_sweep, false, false), std::logic_error) << "reset forgets the frame";
}
