// ~deform_pose of a running muscle_deformation_node (started by deform_service.test with a real roscore).
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/pipeline/settings_table.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <muscle_deformation/DeformPose.h>

#include <gtest/gtest.h>
#include <ros/package.h>
#include <ros/ros.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <vector>

namespace md = muscle_deformation;

namespace {

const char* kService = "/muscle_deformation/deform_pose";

struct Expectations {
  md::Skeleton skeleton;
  md::Scene scene;
  int particles_per_fibre = 20;
  std::size_t particles = 0;  // of the node's model: fibre particles and tendon anchors
  std::string fixed_frame;
  std::string hip_joint, knee_joint;
  double knee_flexion_sign = -1;
};

Expectations* expectations = nullptr;

md::DeformPose::Request poseRequest(double hip_flexion, double knee_flexion) {
  md::DeformPose::Request request;
  request.joint_state.name = {expectations->hip_joint, expectations->knee_joint};
  request.joint_state.position = {hip_flexion, expectations->knee_flexion_sign * knee_flexion};
  return request;
}

md::DeformPose::Response call(const md::DeformPose::Request& request) {
  md::DeformPose srv;
  srv.request = request;
  EXPECT_TRUE(ros::service::call(kService, srv)) << "the service call itself failed";
  return srv.response;
}

struct Particle {
  Eigen::Vector3d position;
  int muscle, bone;
};

std::vector<Particle> particlesOf(const sensor_msgs::PointCloud2& cloud) {
  std::vector<Particle> particles;
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
  sensor_msgs::PointCloud2ConstIterator<std::int32_t> muscle(cloud, "muscle"), bone(cloud, "bone");
  for (; x != x.end(); ++x, ++y, ++z, ++muscle, ++bone)
    particles.push_back({Eigen::Vector3d(*x, *y, *z), *muscle, *bone});
  return particles;
}

// Pose of every link in the fixed frame for the given joint values.
std::map<std::string, Eigen::Isometry3d> linksInFixedFrame(const md::JointValues& values) {
  std::map<std::string, Eigen::Isometry3d> poses = expectations->skeleton.linkPoses(values);
  const Eigen::Isometry3d fixed_inverse = poses.at(expectations->fixed_frame).inverse();
  for (auto& [name, pose] : poses) pose = fixed_inverse * pose;
  return poses;
}

void expectRefusal(const md::DeformPose::Request& request, const std::string& named_problem) {
  const md::DeformPose::Response response = call(request);
  EXPECT_FALSE(response.success);
  EXPECT_NE(response.message.find(named_problem), std::string::npos)
      << "message '" << response.message << "' does not name '" << named_problem << "'";
}

}  // namespace

TEST(DeformPoseService, ValidPoseReturnsEveryMuscleWithTheExpectedCountsAndFinitePositions) {
  const md::DeformPose::Response response = call(poseRequest(0.5, 1.0));
  ASSERT_TRUE(response.success) << response.message;
  const md::Scene& scene = expectations->scene;
  const std::size_t muscles = scene.muscles.size();
  ASSERT_EQ(response.surfaces.muscles.size(), muscles) << response.message;
  ASSERT_EQ(response.fibres.markers.size(), muscles);
  std::size_t fibre_particles = 0;
  for (std::size_t m = 0; m < muscles; ++m) {
    const md::Muscle& muscle = scene.muscles[m];
    const md::MuscleSurface& surface = response.surfaces.muscles[m];
    EXPECT_EQ(surface.name, muscle.name);
    EXPECT_EQ(surface.mesh.vertices.size(), static_cast<std::size_t>(muscle.surface.vertexCount())) << muscle.name;
    EXPECT_EQ(surface.mesh.triangles.size(), static_cast<std::size_t>(muscle.surface.triangleCount())) << muscle.name;
    for (const geometry_msgs::Point& p : surface.mesh.vertices)
      ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) << muscle.name;
    const std::size_t fibres = muscle.fibres.size();
    const auto segments = static_cast<std::size_t>(expectations->particles_per_fibre - 1);
    EXPECT_EQ(response.fibres.markers[m].points.size(), 2 * fibres * segments) << muscle.name << ": " << fibres
                                                                               << " fibres";
    for (const geometry_msgs::Point& p : response.fibres.markers[m].points)
      ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) << muscle.name;
    fibre_particles += fibres * static_cast<std::size_t>(expectations->particles_per_fibre);
  }
  const std::vector<Particle> particles = particlesOf(response.particles);
  EXPECT_EQ(particles.size(), expectations->particles);
  // Every fibre particle, and the tendon anchors (fixed to a bone) beyond them.
  EXPECT_GE(particles.size(), fibre_particles);
  std::size_t fixed = 0;
  for (const Particle& p : particles) fixed += p.bone >= 0;
  EXPECT_GE(fixed, particles.size() - fibre_particles);
  for (const Particle& p : particles) ASSERT_TRUE(p.position.allFinite());
  EXPECT_TRUE(response.stats.finite);
  EXPECT_GT(response.stats.iterations, 0);
}

TEST(DeformPoseService, FixedParticlesSitExactlyWhereTheirBonesMovedThem) {
  const md::DeformPose::Response rest = call(poseRequest(0.0, 0.0));
  ASSERT_TRUE(rest.success) << rest.message;
  const md::DeformPose::Response posed = call(poseRequest(0.5, 1.0));
  ASSERT_TRUE(posed.success) << posed.message;
  ASSERT_EQ(rest.bone_names, posed.bone_names);
  const std::vector<Particle> at_rest = particlesOf(rest.particles), moved = particlesOf(posed.particles);
  ASSERT_EQ(at_rest.size(), moved.size());

  md::JointValues zero, pose;
  pose[expectations->hip_joint] = 0.5;
  pose[expectations->knee_joint] = expectations->knee_flexion_sign * 1.0;
  const auto links_zero = linksInFixedFrame(zero), links_pose = linksInFixedFrame(pose);
  int fixed = 0;
  for (std::size_t i = 0; i < moved.size(); ++i) {
    if (moved[i].bone < 0) continue;
    ++fixed;
    ASSERT_EQ(moved[i].bone, at_rest[i].bone);
    const std::string& bone = posed.bone_names.at(static_cast<std::size_t>(moved[i].bone));
    const Eigen::Isometry3d motion = links_pose.at(bone) * links_zero.at(bone).inverse();
    // The cloud carries float32 coordinates: 1e-5 m is their resolution at a metre, not a modelling tolerance.
    EXPECT_LT((moved[i].position - motion * at_rest[i].position).norm(), 1e-5)
        << "particle " << i << " fixed to " << bone;
  }
  EXPECT_GT(fixed, 0) << "every muscle has attached fibre ends";
}

TEST(DeformPoseService, RefusesAnUnknownJointNamingIt) {
  md::DeformPose::Request request = poseRequest(0.5, 1.0);
  request.joint_state.name.push_back("no_such_joint");
  request.joint_state.position.push_back(0.1);
  expectRefusal(request, "no_such_joint");
}

TEST(DeformPoseService, RefusesANaNJointPositionNamingTheJoint) {
  md::DeformPose::Request request = poseRequest(0.5, 1.0);
  request.joint_state.position[0] = std::numeric_limits<double>::quiet_NaN();
  expectRefusal(request, expectations->hip_joint);
  expectRefusal(request, "non-finite");
}

TEST(DeformPoseService, AJointOutsideItsLimitsIsSolvedAndTheAnswerWarnsNamingIt) {
  md::DeformPose::Request request = poseRequest(3.0, 1.0);  // hip flexion beyond the URDF's limit
  request.max_iterations = 2;                              // the warning is the point, not the shape
  const md::DeformPose::Response response = call(request);
  ASSERT_TRUE(response.success) << response.message;
  EXPECT_NE(response.message.find("warning: joint '" + expectations->hip_joint + "' = 3 is outside its limits"),
            std::string::npos)
      << response.message;
}

TEST(DeformPoseService, RefusesAnUnknownMuscleNamingIt) {
  md::DeformPose::Request request = poseRequest(0.5, 1.0);
  request.muscles = {"no_such_muscle"};
  expectRefusal(request, "no_such_muscle");
}

TEST(DeformPoseService, RefusesNegativeLimitsNamingTheField) {
  md::DeformPose::Request request = poseRequest(0.5, 1.0);
  request.max_iterations = -1;
  expectRefusal(request, "max_iterations");
  request = poseRequest(0.5, 1.0);
  request.displacement_tolerance_m = -1e-3;
  expectRefusal(request, "displacement_tolerance_m");
  request = poseRequest(0.5, 1.0);
  request.time_budget_ms = -5;
  expectRefusal(request, "time_budget_ms");
}

TEST(DeformPoseService, RefusesARequestWithoutJointStateOrBonePoses) {
  expectRefusal(md::DeformPose::Request(), "no pose");
}

TEST(DeformPoseService, AnswersAValidCallAfterBadOnes) {
  md::DeformPose::Request bad = poseRequest(0.5, 1.0);
  bad.muscles = {"no_such_muscle"};
  expectRefusal(bad, "no_such_muscle");
  expectRefusal(md::DeformPose::Request(), "no pose");
  const md::DeformPose::Response response = call(poseRequest(0.2, 0.3));
  EXPECT_TRUE(response.success) << response.message;
  EXPECT_EQ(response.surfaces.muscles.size(), expectations->scene.muscles.size());
}

TEST(DeformPoseService, SolvesAMuscleSubsetWithOverriddenIterations) {
  md::DeformPose::Request request = poseRequest(0.5, 1.0);
  const std::string muscle = expectations->scene.muscles.front().name;
  request.muscles = {muscle};
  request.max_iterations = 7;
  const md::DeformPose::Response response = call(request);
  ASSERT_TRUE(response.success) << response.message;
  ASSERT_EQ(response.fibres.markers.size(), 1u);
  EXPECT_EQ(response.stats.iterations, 7);
  if (!response.surfaces.muscles.empty()) {
    EXPECT_EQ(response.surfaces.muscles.front().name, muscle);
  }
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "deform_service_test");
  ros::NodeHandle node, private_node("~");
  Expectations loaded;
  private_node.param<std::string>("hip_joint", loaded.hip_joint, "hip_flexion_r");
  private_node.param<std::string>("knee_joint", loaded.knee_joint, "knee_angle_r");
  private_node.param("knee_flexion_sign", loaded.knee_flexion_sign, -1.0);
  node.param("/muscle_deformation/particles_per_fibre", loaded.particles_per_fibre, 20);
  node.param<std::string>("/muscle_deformation/fixed_frame", loaded.fixed_frame, "pelvis");
  std::string urdf, scene_path;
  if (!node.getParam("/robot_description", urdf) || !node.getParam("/muscle_deformation/scene", scene_path)) {
    ADD_FAILURE() << "robot_description or /muscle_deformation/scene is not set";
    return 1;
  }
  const std::string package_root = ros::package::getPath("muscle_deformation");
  loaded.skeleton = md::Skeleton::fromUrdfString(urdf, "robot_description");
  const md::SceneDescription description = md::loadSceneDescription(scene_path);
  loaded.scene = md::loadScene(description, loaded.skeleton,
                               md::makeUriResolver({{"muscle_deformation", package_root}}, package_root));
  // The node's model at its defaults (the launch file loads the documented ones) and this particles_per_fibre.
  md::ModelSettings model = md::nodeDefaultSettings().pipeline.simulation.model;
  model.particles_per_fibre = loaded.particles_per_fibre;
  loaded.particles =
      static_cast<std::size_t>(md::buildMassSpringSystem(loaded.scene.muscles, loaded.scene.bones, model).particleCount());
  expectations = &loaded;
  if (!ros::service::waitForService(kService, ros::Duration(300))) {
    ADD_FAILURE() << kService << " did not appear within 300 s";
    return 1;
  }
  return RUN_ALL_TESTS();
}
