// The converters between core results and ROS messages, without a roscore.
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/node/conversions.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include <gtest/gtest.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace md = muscle_deformation;
namespace node = muscle_deformation::node;

namespace {

geometry_msgs::Transform transformOf(const Eigen::Quaterniond& rotation, const Eigen::Vector3d& translation) {
  geometry_msgs::Transform transform;
  transform.rotation.w = rotation.w();
  transform.rotation.x = rotation.x();
  transform.rotation.y = rotation.y();
  transform.rotation.z = rotation.z();
  transform.translation.x = translation.x();
  transform.translation.y = translation.y();
  transform.translation.z = translation.z();
  return transform;
}

}  // namespace

TEST(Conversions, ANonUnitQuaternionGivesARigidTransformAndItsLength) {
  const Eigen::Quaterniond unit(Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()));
  const Eigen::Quaterniond scaled(unit.coeffs() * 1.004);
  double length = 0;
  const Eigen::Isometry3d transform =
      node::rigidTransformFromMessage(transformOf(scaled, Eigen::Vector3d(1, 2, 3)), length);
  EXPECT_NEAR(length, 1.004, 1e-12);
  EXPECT_TRUE((transform.linear() * transform.linear().transpose()).isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  EXPECT_NEAR(transform.linear().determinant(), 1.0, 1e-12);
  EXPECT_TRUE(transform.linear().isApprox(unit.toRotationMatrix(), 1e-12));
  EXPECT_TRUE(transform.translation().isApprox(Eigen::Vector3d(1, 2, 3)));
}

TEST(Conversions, ServiceTransformsAreNormalisedAndFarFromUnitOnesRefused) {
  const Eigen::Quaterniond unit(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
  double length = 0;
  const Eigen::Isometry3d normalised =
      node::isometryFromMessage(transformOf(Eigen::Quaterniond(unit.coeffs() * 1.05), Eigen::Vector3d::Zero()),
                                "bone_poses[0]", &length);
  EXPECT_NEAR(length, 1.05, 1e-12);
  EXPECT_TRUE(normalised.linear().isApprox(unit.toRotationMatrix(), 1e-12));
  try {
    node::isometryFromMessage(transformOf(Eigen::Quaterniond(unit.coeffs() * 2.0), Eigen::Vector3d::Zero()),
                              "bone_poses[3]");
    ADD_FAILURE() << "a quaternion of length 2 was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("bone_poses[3]"), std::string::npos) << e.what();
  }
  geometry_msgs::Transform nan = transformOf(unit, Eigen::Vector3d::Zero());
  nan.translation.y = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(node::isometryFromMessage(nan, "x"), std::invalid_argument);
}

TEST(Conversions, JointStatesNameTheirProblem) {
  sensor_msgs::JointState state;
  state.name = {"hip", "knee"};
  state.position = {0.1, 0.2};
  const md::JointValues values = node::jointValuesFromMessage(state);
  EXPECT_EQ(values.at("knee"), 0.2);
  state.position = {0.1};
  EXPECT_THROW(node::jointValuesFromMessage(state), std::invalid_argument);
  state.position = {0.1, std::numeric_limits<double>::infinity()};
  try {
    node::jointValuesFromMessage(state);
    ADD_FAILURE() << "an infinite position was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'knee'"), std::string::npos) << e.what();
  }
}

TEST(Conversions, StatsSayConvergedOnlyWhenTheSolverDidAndCarryTheRobustStrain) {
  md::FrameResult frame;
  frame.stats.solver.iterations = 30;
  frame.stats.solver.stopping_rule_met = true;  // the iterations rule ran its count
  frame.stats.solver.converged = false;
  frame.stats.solver.max_strain = 4.5e4;
  frame.stats.solver.strain_p99 = 0.12;
  frame.stats.solver.time_limit_reached = true;
  std_msgs::Header header;
  header.frame_id = "pelvis";
  const muscle_deformation::DeformationStats stats = node::statsToMessage(frame, header);
  EXPECT_FALSE(stats.converged);
  EXPECT_TRUE(stats.time_limit_reached);
  EXPECT_EQ(stats.iterations, 30);
  EXPECT_EQ(stats.max_strain, 4.5e4);
  EXPECT_EQ(stats.strain_p99, 0.12);
  EXPECT_FALSE(stats.has_surface_metrics);
  EXPECT_EQ(stats.header.frame_id, "pelvis");
  EXPECT_FALSE(stats.has_residual);  // this solver measured none (SolveStats::residual < 0): absent, not 0
  frame.stats.solver.converged = true;
  frame.stats.solver.residual = 2.5e-3;
  const muscle_deformation::DeformationStats measured = node::statsToMessage(frame, header);
  EXPECT_TRUE(measured.converged);
  EXPECT_TRUE(measured.has_residual);
  EXPECT_EQ(measured.force_residual, 2.5e-3);
  EXPECT_EQ(measured.residual_absent_reason, "");
}

TEST(Conversions, FiguresThatWereNotMeasuredAreNaNWithTheirFlagAndReasonNeverZero) {
  md::FrameResult frame;  // solver without a residual, collisions off, no surface metrics
  frame.residual_absent_reason = "the verlet solver does not measure it (only block_descent and newton_krylov do)";
  frame.collision_absent_reason = "collisions are off";
  frame.metrics_absent_reason = "bone 'pelvis': surface is not closed (3 boundary edges)";
  const muscle_deformation::DeformationStats stats = node::statsToMessage(frame, std_msgs::Header());
  EXPECT_FALSE(stats.has_residual);
  EXPECT_TRUE(std::isnan(stats.force_residual));
  EXPECT_EQ(stats.residual_absent_reason, frame.residual_absent_reason);
  EXPECT_FALSE(stats.has_collision_metrics);
  EXPECT_EQ(stats.contacts, -1);
  EXPECT_TRUE(std::isnan(stats.max_penetration_sphere_bone_m));
  EXPECT_TRUE(std::isnan(stats.max_penetration_sphere_muscle_m));
  EXPECT_EQ(stats.collision_absent_reason, "collisions are off");
  EXPECT_FALSE(stats.has_surface_metrics);
  EXPECT_TRUE(std::isnan(stats.volume_error_mean_pct));
  EXPECT_TRUE(std::isnan(stats.volume_error_max_pct));
  EXPECT_EQ(stats.volume_error_max_muscle, "");
  EXPECT_EQ(stats.surface_vertices_inside_bone, -1);
  EXPECT_TRUE(std::isnan(stats.max_surface_inside_bone_m));
  EXPECT_EQ(stats.particles_inside_bone, -1);
  EXPECT_TRUE(std::isnan(stats.max_particle_inside_bone_m));
  EXPECT_EQ(stats.max_particle_inside_bone_muscle, "");
  EXPECT_TRUE(stats.muscle_names.empty());
  EXPECT_TRUE(stats.muscle_volume_error_pct.empty());
  EXPECT_TRUE(stats.muscle_max_particle_inside_bone_m.empty());
  EXPECT_EQ(stats.surface_metrics_absent_reason, frame.metrics_absent_reason);

  // A frame without reasons still says the figures were not measured.
  const muscle_deformation::DeformationStats bare = node::statsToMessage(md::FrameResult(), std_msgs::Header());
  EXPECT_EQ(bare.residual_absent_reason, "not measured");
  EXPECT_EQ(bare.surface_metrics_absent_reason, "not measured");
}

TEST(Conversions, MeasuredFiguresAreCopiedWithTheirFlagsAndNoReason) {
  md::FrameResult frame;
  frame.stats.has_collision = true;
  frame.stats.collision.contacts = 0;  // measured: no contact is a result, not a missing figure
  frame.stats.collision.max_penetration_muscle_bone_m = 0.0;
  frame.stats.collision.max_penetration_muscle_muscle_m = 4e-4;
  frame.has_metrics = true;
  frame.metrics.volume_error_mean_pct = 0.0;
  frame.metrics.volume_error_max_pct = 1.5;
  frame.metrics.vertices_inside_bone = 0;
  frame.metrics.max_inside_bone_depth_m = 0.0;
  md::MuscleMetrics worst;
  worst.name = "iliacus";
  worst.volume_error_pct = -1.5;
  frame.metrics.muscles = {worst};
  const muscle_deformation::DeformationStats stats = node::statsToMessage(frame, std_msgs::Header());
  EXPECT_TRUE(stats.has_collision_metrics);
  EXPECT_EQ(stats.collision_absent_reason, "");
  EXPECT_EQ(stats.contacts, 0);
  EXPECT_EQ(stats.max_penetration_sphere_bone_m, 0.0);
  EXPECT_EQ(stats.max_penetration_sphere_muscle_m, 4e-4);
  EXPECT_TRUE(stats.has_surface_metrics);
  EXPECT_EQ(stats.surface_metrics_absent_reason, "");
  EXPECT_EQ(stats.volume_error_mean_pct, 0.0);
  EXPECT_EQ(stats.volume_error_max_pct, 1.5);
  EXPECT_EQ(stats.volume_error_max_muscle, "iliacus");
  EXPECT_EQ(stats.surface_vertices_inside_bone, 0);
  EXPECT_EQ(stats.max_surface_inside_bone_m, 0.0);
  EXPECT_EQ(stats.max_surface_inside_bone_muscle, "") << "no vertex is inside a bone";
}

TEST(Conversions, TheDeepestSurfaceVertexInsideABoneIsNamedWithItsMuscleAndBone) {
  md::FrameResult frame;
  frame.has_metrics = true;
  md::MuscleMetrics shallow, deep, clear;
  shallow.name = "piriformis";
  shallow.vertices_inside_bone = 12;
  shallow.max_inside_bone_depth_m = 0.002;
  shallow.deepest_bone = "pelvis";
  deep.name = "iliacus";
  deep.vertices_inside_bone = 3;
  deep.max_inside_bone_depth_m = 0.009;
  deep.deepest_bone = "pelvis";
  clear.name = "sartorius";
  frame.metrics.muscles = {shallow, deep, clear};
  frame.metrics.vertices_inside_bone = 15;
  frame.metrics.max_inside_bone_depth_m = 0.009;
  const muscle_deformation::DeformationStats stats = node::statsToMessage(frame, std_msgs::Header());
  EXPECT_EQ(stats.max_surface_inside_bone_muscle, "iliacus");
  EXPECT_EQ(stats.max_surface_inside_bone_bone, "pelvis");
  EXPECT_EQ(stats.max_surface_inside_bone_m, 0.009);
}

TEST(Conversions, TheDeepestParticleInsideABoneIsNamedAndEveryMusclesFiguresAreListedInOrder) {
  md::FrameResult frame;
  frame.has_metrics = true;
  md::MuscleMetrics iliacus, psoas;
  iliacus.name = "iliacus";
  iliacus.volume_error_pct = -0.4;
  iliacus.vertices_inside_bone = 2;
  iliacus.max_inside_bone_depth_m = 0.0005;
  iliacus.deepest_bone = "hip_r";
  iliacus.particles_inside_bone = 1;
  iliacus.max_particle_inside_bone_depth_m = 0.0003;
  iliacus.deepest_particle_bone = "hip_r";
  psoas.name = "psoas_major";
  psoas.volume_error_pct = 0.2;
  psoas.particles_inside_bone = 4;
  psoas.max_particle_inside_bone_depth_m = 0.0012;
  psoas.deepest_particle_bone = "sacrum";
  frame.metrics.muscles = {iliacus, psoas};
  frame.metrics.particles_inside_bone = 5;
  frame.metrics.max_particle_inside_bone_depth_m = 0.0012;
  md::SurfaceVolumeCorrection iliacus_correction, psoas_correction;
  iliacus_correction.volume_error_before_pct = -3.5;
  psoas_correction.volume_error_before_pct = 1.25;
  iliacus_correction.mean_offset_m = 0.0002;
  iliacus_correction.max_offset_m = 0.0011;
  frame.volume_corrections = {iliacus_correction, psoas_correction};
  md::SurfaceBoneCorrection iliacus_contact, psoas_contact;
  iliacus_contact.vertices_moved = 40;
  iliacus_contact.max_depth_before_m = 0.009;  // the skinning put the iliacus 9 mm into the pelvis; moved out
  frame.bone_corrections = {iliacus_contact, psoas_contact};

  const muscle_deformation::DeformationStats stats = node::statsToMessage(frame, std_msgs::Header());
  EXPECT_EQ(stats.particles_inside_bone, 5);
  EXPECT_EQ(stats.max_particle_inside_bone_m, 0.0012);
  EXPECT_EQ(stats.max_particle_inside_bone_muscle, "psoas_major");
  EXPECT_EQ(stats.max_particle_inside_bone_bone, "sacrum");
  EXPECT_EQ(stats.muscle_names, (std::vector<std::string>{"iliacus", "psoas_major"}));
  EXPECT_EQ(stats.muscle_volume_error_pct, (std::vector<double>{-0.4, 0.2}));
  EXPECT_EQ(stats.muscle_skinned_volume_error_pct, (std::vector<double>{-3.5, 1.25}));
  EXPECT_EQ(stats.muscle_max_surface_inside_bone_m, (std::vector<double>{0.0005, 0.0}));
  EXPECT_EQ(stats.muscle_max_particle_inside_bone_m, (std::vector<double>{0.0003, 0.0012}));
  EXPECT_EQ(stats.muscle_skinned_max_surface_inside_bone_m, (std::vector<double>{0.009, 0.0}));
  EXPECT_EQ(stats.muscle_projection_offset_mean_m, (std::vector<double>{0.0002, 0.0}));
  EXPECT_EQ(stats.muscle_projection_offset_max_m, (std::vector<double>{0.0011, 0.0}));

  // Without the volume constraint the skinned surface is the one shown: the same volume error.
  frame.volume_corrections.clear();
  const muscle_deformation::DeformationStats uncorrected = node::statsToMessage(frame, std_msgs::Header());
  EXPECT_EQ(uncorrected.muscle_skinned_volume_error_pct, uncorrected.muscle_volume_error_pct);
  EXPECT_EQ(uncorrected.muscle_projection_offset_max_m, (std::vector<double>{0.0, 0.0})) << "nothing was moved";
  frame.bone_corrections.clear();
  const muscle_deformation::DeformationStats uncontacted = node::statsToMessage(frame, std_msgs::Header());
  EXPECT_EQ(uncontacted.muscle_skinned_max_surface_inside_bone_m, uncontacted.muscle_max_surface_inside_bone_m);
}

TEST(Conversions, ParticleCloudRoundTripsPositionsAndAttachments) {
  Eigen::Matrix3Xd positions(3, 3);
  positions << 0, 0.1, 0.2,  //
      0.01, 0.02, 0.03,      //
      -0.5, -0.25, 0.125;
  md::MassSpringSystem system = md::systemFromParticles(positions, {{0, 1}, {1, 2}}, 1.0, 1.0);
  system.is_fixed[0] = 1;
  system.fixed_bone[0] = 2;
  std_msgs::Header header;
  header.frame_id = "pelvis";
  const std::vector<md::MuscleDescription> muscles(1);
  md::FrameResult frame;
  frame.view(system, positions, muscles, {}, nullptr);
  const sensor_msgs::PointCloud2 cloud = node::particlesToCloud(frame, header);
  ASSERT_EQ(cloud.width * cloud.height, 3u);
  EXPECT_EQ(cloud.header.frame_id, "pelvis");
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
  sensor_msgs::PointCloud2ConstIterator<std::int32_t> bone(cloud, "bone");
  for (int i = 0; i < 3; ++i, ++x, ++y, ++z, ++bone) {
    EXPECT_FLOAT_EQ(*x, static_cast<float>(positions(0, i)));
    EXPECT_FLOAT_EQ(*y, static_cast<float>(positions(1, i)));
    EXPECT_FLOAT_EQ(*z, static_cast<float>(positions(2, i)));
    EXPECT_EQ(*bone, i == 0 ? 2 : -1);
  }
}

TEST(Conversions, TheStreamsAbsentFiguresIncludeTheSurfaceMetricsWhenStatsMetricsIsFalse) {
  md::SyntheticScene scene = md::makeSyntheticThigh(1, 3);
  md::PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 6;
  settings.simulation.model.nearest_neighbours = 6;
  std::vector<md::MuscleDescription> descriptions(1);
  descriptions[0].name = scene.muscles[0].name;
  const md::DeformationPipeline stream(descriptions, scene.muscles, scene.bones, settings);
  ASSERT_NE(stream.metrics(), nullptr);
  const std::vector<md::AbsentMetric> measured = node::absentStatsFigures(stream, true);
  ASSERT_EQ(measured.size(), 1u);  // the Verlet solver's residual only
  EXPECT_EQ(measured[0].figures, "force_residual");
  const std::vector<md::AbsentMetric> without = node::absentStatsFigures(stream, false);
  ASSERT_EQ(without.size(), 2u);
  EXPECT_EQ(without[1].reason, "stats_metrics is false");
  EXPECT_EQ(without[1].remedy, "set stats_metrics: true");
  EXPECT_NE(without[1].describe().find("volume_error_*"), std::string::npos) << without[1].describe();
  EXPECT_NE(without[1].describe().find("max_particle_inside_bone_m"), std::string::npos) << without[1].describe();
}

TEST(Conversions, APipelinesFrameCarriesEverythingItsMessagesNeed) {
  md::SyntheticScene scene = md::makeSyntheticThigh(2, 3);
  md::PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 6;
  settings.simulation.model.nearest_neighbours = 6;
  std::vector<md::MuscleDescription> descriptions(2);
  for (std::size_t m = 0; m < 2; ++m) descriptions[m].name = scene.muscles[m].name;
  md::DeformationPipeline pipeline(descriptions, scene.muscles, scene.bones, settings);
  const md::FrameResult& frame =
      pipeline.solve(md::boneTransformsOf(pipeline.bones(), md::syntheticThighPose(0.3, 0.2)), md::StartMode::cold,
                     md::FrameStopping::of(md::StoppingSettings::afterIterations(5)), true, false);
  ASSERT_TRUE(frame.has_surfaces);
  std_msgs::Header header;
  header.frame_id = "pelvis";

  const sensor_msgs::PointCloud2 cloud = node::particlesToCloud(frame, header);
  EXPECT_EQ(cloud.width * cloud.height, static_cast<std::uint32_t>(frame.positions().cols()));
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x");
  for (Eigen::Index i = 0; i < frame.positions().cols(); ++i, ++x)
    ASSERT_FLOAT_EQ(*x, static_cast<float>(frame.positions()(0, i))) << "particle " << i;

  const visualization_msgs::MarkerArray fibres = node::fibresToMarkers(frame, header, false);
  ASSERT_EQ(fibres.markers.size(), 2u);
  EXPECT_FALSE(fibres.markers[0].points.empty());

  const muscle_deformation::MuscleSurfaces surfaces = node::surfacesToMessage(frame, header);
  ASSERT_EQ(surfaces.muscles.size(), 2u);
  for (std::size_t m = 0; m < 2; ++m) {
    EXPECT_EQ(surfaces.muscles[m].name, scene.muscles[m].name);
    EXPECT_EQ(surfaces.muscles[m].mesh.vertices.size(), static_cast<std::size_t>(frame.surfaces[m].cols()));
    EXPECT_EQ(surfaces.muscles[m].mesh.triangles.size(), static_cast<std::size_t>(frame.surfaceTriangles(m).cols()));
  }
  const visualization_msgs::MarkerArray markers = node::surfacesToMarkers(frame, header, 0.5f);
  ASSERT_EQ(markers.markers.size(), 2u);
  EXPECT_EQ(markers.markers[1].points.size(), 3 * static_cast<std::size_t>(frame.surfaceTriangles(1).cols()));
}

TEST(Conversions, AFrameWithoutSurfacesGivesNone) {
  md::FrameResult frame;  // has_surfaces false
  EXPECT_TRUE(node::surfacesToMessage(frame, std_msgs::Header()).muscles.empty());
  EXPECT_TRUE(node::surfacesToMarkers(frame, std_msgs::Header(), 1.0f).markers.empty());
}

// Bones are drawn in the bone colour whatever the URDF's materials say, each in its own link's frame so that rviz moves
// it with tf: the marker's points are the rest surface seen from the link.
TEST(Conversions, BonesAreMarkersInTheBoneColourInTheirLinksFramesThatFollowTf) {
  md::Bone femur{0, "femur_r", md::makeBoxMesh({-0.02, -0.02, -0.4}, {0.02, 0.02, 0.0})};
  md::Bone unlinked{1, "not_a_link", md::makeBoxMesh({0, 0, 0}, {0.01, 0.01, 0.01})};
  Eigen::Isometry3d femur_rest = Eigen::Isometry3d::Identity();
  femur_rest.translate(Eigen::Vector3d(-0.07, -0.1, -0.06)).rotate(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
  const visualization_msgs::MarkerArray markers =
      node::bonesToMarkers({femur, unlinked}, {{"femur_r", femur_rest}, {"pelvis", Eigen::Isometry3d::Identity()}});
  ASSERT_EQ(markers.markers.size(), 1u);  // a bone that is no link has no frame to follow
  const visualization_msgs::Marker& marker = markers.markers[0];
  EXPECT_EQ(marker.header.frame_id, "femur_r");
  EXPECT_TRUE(marker.header.stamp.isZero());
  EXPECT_TRUE(marker.frame_locked);
  EXPECT_EQ(marker.type, visualization_msgs::Marker::TRIANGLE_LIST);
  EXPECT_FLOAT_EQ(marker.color.r, node::kBoneColour[0]);
  EXPECT_FLOAT_EQ(marker.color.g, node::kBoneColour[1]);
  EXPECT_FLOAT_EQ(marker.color.b, node::kBoneColour[2]);
  ASSERT_EQ(marker.points.size(), 3 * static_cast<std::size_t>(femur.surface.triangleCount()));
  const Eigen::Vector3d first = femur.surface.vertices.col(femur.surface.triangles(0, 0));
  const Eigen::Vector3d seen(marker.points[0].x, marker.points[0].y, marker.points[0].z);
  EXPECT_LT((femur_rest * seen - first).norm(), 1e-12);
}
