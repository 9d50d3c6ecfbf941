// Bad streams (stream_inputs.test): each reason a pose is not solved is counted and reported as itself, and rotations
// that tf2 accepts a little off unit length move the bones rigidly. The test publishes joint_states and /tf itself
// (no robot_state_publisher), so it controls which transforms exist.
#include "node_test_helpers.hpp"

#include "muscle_deformation/core/scene/scene.hpp"

#include <muscle_deformation/DeformationStats.h>

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/JointState.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/transform_broadcaster.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <vector>

namespace md = muscle_deformation;
using md::node_testing::waitFor;

namespace {

const char* kPosesStatus = "Poses (tf failures";

struct Fixture {
  std::unique_ptr<ros::NodeHandle> node;
  std::unique_ptr<md::node_testing::DiagnosticsWatcher> diagnostics;
  ros::Publisher joint_states;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf;
  ros::Subscriber particles_subscriber, rosout_subscriber, stats_subscriber;
  std::mutex mutex;
  std::vector<sensor_msgs::PointCloud2> clouds;
  std::vector<muscle_deformation::DeformationStats> stats;
  std::vector<std::string> node_log;
  md::Skeleton skeleton;
  std::vector<std::string> bone_links;  // links with collision meshes, in URDF order (the node's bone indices)
  std::map<std::string, Eigen::Isometry3d> rest_in_pelvis;
};
Fixture* fixture = nullptr;

void publishJointState(const ros::Time& stamp, double hip_flexion) {
  sensor_msgs::JointState message;
  message.header.stamp = stamp;
  message.name = {"hip_flexion_r"};
  message.position = {hip_flexion};
  fixture->joint_states.publish(message);
}

// Publishes `count` joint states at 30 Hz with stamps from `stamp_of`.
void publishAt30Hz(int count, const std::function<ros::Time()>& stamp_of, double hip_flexion = 0.1) {
  for (int i = 0; i < count; ++i) {
    publishJointState(stamp_of(), hip_flexion);
    ros::WallDuration(1.0 / 30.0).sleep();
  }
}

// The bones' links in the pelvis frame, for joint values (URDF forward kinematics), as a robot_state_publisher would
// give them, but straight from the pelvis to each bone.
std::map<std::string, Eigen::Isometry3d> bonesInPelvis(const md::JointValues& joints) {
  const std::map<std::string, Eigen::Isometry3d> root = fixture->skeleton.linkPoses(joints);
  std::map<std::string, Eigen::Isometry3d> bones;
  for (const std::string& link : fixture->bone_links) bones[link] = root.at("pelvis").inverse() * root.at(link);
  return bones;
}

void sendTransform(const ros::Time& stamp, const std::string& parent, const std::string& child,
                   const Eigen::Isometry3d& pose) {
  geometry_msgs::TransformStamped transform = tf2::eigenToTransform(pose);
  transform.header.stamp = stamp;
  transform.header.frame_id = parent;
  transform.child_frame_id = child;
  fixture->tf->sendTransform(transform);
}

// One pose of the stream: every bone's transform at `stamp` for this hip flexion, then its joint state.
void publishPose(const ros::Time& stamp, double hip_flexion) {
  for (const auto& [link, pose] : bonesInPelvis({{"hip_flexion_r", hip_flexion}}))
    if (link != "pelvis") sendTransform(stamp, "pelvis", link, pose);
  ros::WallDuration(0.01).sleep();
  publishJointState(stamp, hip_flexion);
}

// The particles of the frame that solved the pose at `stamp`, among the clouds after the first `before` (refined frames
// of an earlier pose may arrive in between: they carry that pose's stamp); an empty cloud if none came within 10 s.
sensor_msgs::PointCloud2 cloudAt(const ros::Time& stamp, std::size_t before) {
  sensor_msgs::PointCloud2 found;
  const bool arrived = waitFor(
      [&] {
        std::lock_guard<std::mutex> lock(fixture->mutex);
        for (std::size_t i = before; i < fixture->clouds.size(); ++i)
          if (fixture->clouds[i].header.stamp == stamp) {
            found = fixture->clouds[i];
            return true;
          }
        return false;
      },
      10.0);
  EXPECT_TRUE(arrived) << "no particles for the pose at " << stamp;
  return found;
}

// The stats of the frame that solved the pose at `stamp` (not a refinement), after the first `before`.
muscle_deformation::DeformationStats statsAt(const ros::Time& stamp, std::size_t before) {
  muscle_deformation::DeformationStats found;
  const bool arrived = waitFor(
      [&] {
        std::lock_guard<std::mutex> lock(fixture->mutex);
        for (std::size_t i = before; i < fixture->stats.size(); ++i)
          if (fixture->stats[i].header.stamp == stamp && !fixture->stats[i].refined) {
            found = fixture->stats[i];
            return true;
          }
        return false;
      },
      10.0);
  EXPECT_TRUE(arrived) << "no ~stats for the pose at " << stamp;
  return found;
}

std::size_t statsCount() {
  std::lock_guard<std::mutex> lock(fixture->mutex);
  return fixture->stats.size();
}

// Waits for the node's next diagnostics update after the causes of the last poses have been counted.
void settle() {
  ros::WallDuration(0.5).sleep();  // the last pose waits tf_wait_s (0.2 s) for its transforms
  const int seen = fixture->diagnostics->messages();
  ASSERT_TRUE(waitFor([&] { return fixture->diagnostics->messages() > seen; }, 5.0)) << "no /diagnostics update";
}

double total(const std::string& key) { return fixture->diagnostics->number(key); }

}  // namespace

TEST(StreamInputs, MissingTransformsAreCountedAsTfFailuresNotAsDrops) {
  settle();
  const double tf_before = total("tf failures (total)"), dropped_before = total("Poses dropped (total)");
  // Poses 33 ms apart, shorter than tf_wait_s, and no transforms at all.
  publishAt30Hz(30, [] { return ros::Time::now(); });
  settle();
  EXPECT_GE(total("tf failures (total)") - tf_before, 25) << fixture->diagnostics->summary();
  EXPECT_EQ(total("Poses dropped (total)") - dropped_before, 0) << "nothing was solved, so the solver dropped nothing";
}

TEST(StreamInputs, NonFiniteJointStatesAreCountedAsSuchAndNamed) {
  settle();
  const double non_finite_before = total("Non-finite joint states (total)"), tf_before = total("tf failures (total)");
  publishAt30Hz(10, [] { return ros::Time::now(); }, std::numeric_limits<double>::quiet_NaN());
  ros::WallDuration(0.5).sleep();
  const int seen = fixture->diagnostics->messages();
  ASSERT_TRUE(waitFor([&] { return fixture->diagnostics->messages() > seen; }, 5.0));
  EXPECT_EQ(total("Non-finite joint states (total)") - non_finite_before, 10);
  EXPECT_EQ(total("tf failures (total)") - tf_before, 0);
  std::lock_guard<std::mutex> lock(fixture->mutex);
  bool named = false;
  for (const std::string& line : fixture->node_log) named = named || line.find("'hip_flexion_r' is nan") != std::string::npos;
  EXPECT_TRUE(named) << "a log line names the joint and its value";
}

TEST(StreamInputs, StampsAheadOfTheClockAreCountedAsSuch) {
  settle();
  const double future_before = total("Future stamps (total)"), tf_before = total("tf failures (total)");
  publishAt30Hz(10, [] { return ros::Time::now() + ros::Duration(100.0); });
  settle();
  EXPECT_GE(total("Future stamps (total)") - future_before, 9) << fixture->diagnostics->summary();
  EXPECT_EQ(total("tf failures (total)") - tf_before, 0);
}

TEST(StreamInputs, NonUnitQuaternionsMoveTheBonesRigidlyAndJointsOutsideTheirLimitsAreWarnedAbout) {
  // Every bone's transform at `stamp`: at rest, except the femur turned about z by `angle`, its quaternion scaled by
  // `length` (tf2 accepts |q|^2 within 1 +- 0.01).
  const auto publishBones = [](const ros::Time& stamp, double angle, double length) {
    for (const std::string& link : fixture->bone_links) {
      Eigen::Isometry3d pose = fixture->rest_in_pelvis.at(link);
      if (link == "femur_r") pose.linear() = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()) * pose.linear();
      geometry_msgs::TransformStamped transform = tf2::eigenToTransform(pose);
      transform.header.stamp = stamp;
      transform.header.frame_id = "pelvis";
      transform.child_frame_id = link;
      if (link == "femur_r") {
        transform.transform.rotation.x *= length;
        transform.transform.rotation.y *= length;
        transform.transform.rotation.z *= length;
        transform.transform.rotation.w *= length;
      }
      if (link != "pelvis") fixture->tf->sendTransform(transform);
    }
  };
  const auto solvedCloud = [&](double angle, double length, double hip_flexion) {
    const std::size_t before = [] {
      std::lock_guard<std::mutex> lock(fixture->mutex);
      return fixture->clouds.size();
    }();
    const ros::Time stamp = ros::Time::now();
    publishBones(stamp, angle, length);
    ros::WallDuration(0.05).sleep();
    publishJointState(stamp, hip_flexion);
    return cloudAt(stamp, before);
  };
  const auto femurParticles = [](const sensor_msgs::PointCloud2& cloud) {
    const int femur = static_cast<int>(std::find(fixture->bone_links.begin(), fixture->bone_links.end(), "femur_r") -
                                       fixture->bone_links.begin());
    std::vector<Eigen::Vector3d> points;
    sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
    sensor_msgs::PointCloud2ConstIterator<std::int32_t> bone(cloud, "bone");
    for (; x != x.end(); ++x, ++y, ++z, ++bone)
      if (*bone == femur) points.emplace_back(*x, *y, *z);
    return points;
  };
  const std::vector<Eigen::Vector3d> rest = femurParticles(solvedCloud(0.0, 1.0, 0.0));
  // 0.5 rad in about 0.15 s: an ordinary motion; |q| = 1.0045 (|q|^2 = 1.009, inside tf2's tolerance).
  ros::WallDuration(0.1).sleep();
  const std::vector<Eigen::Vector3d> turned = femurParticles(solvedCloud(0.5, 1.0045, 3.0));
  ASSERT_EQ(rest.size(), turned.size());
  ASSERT_GE(rest.size(), 2u) << "the muscle has particles fixed to the femur";
  // The femur turned by 0.5 rad about the pelvis z axis through its link origin: where its fixed particles must be.
  const Eigen::Vector3d hip = fixture->rest_in_pelvis.at("femur_r").translation();
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  double worst = 0;
  for (std::size_t i = 0; i < rest.size(); ++i)
    worst = std::max(worst, (turned[i] - (hip + turn * (rest[i] - hip))).norm());
  // float32 coordinates resolve about 1e-7 m; the quaternion used unnormalised would put them ~1e-3 m off.
  EXPECT_LT(worst, 1e-5) << "the particles fixed to the femur did not move rigidly with it";

  // hip_flexion_r = 3.0 rad is outside its URDF limits [-2.0944, 2.0944].
  EXPECT_TRUE(waitFor(
      [] {
        std::lock_guard<std::mutex> lock(fixture->mutex);
        for (const std::string& line : fixture->node_log)
          if (line.find("hip_flexion_r") != std::string::npos && line.find("outside its limits") != std::string::npos)
            return true;
        return false;
      },
      5.0))
      << "the node warns about a joint value outside its limits";
}

TEST(StreamInputs, AJointNamedTwiceIsDroppedCountedAndNamedAndTheStreamGoesOn) {
  settle();
  const double duplicates_before = total("Duplicate joints (total)");
  for (int i = 0; i < 5; ++i) {
    sensor_msgs::JointState message;
    message.header.stamp = ros::Time::now();
    message.name = {"hip_flexion_r", "knee_angle_r", "hip_flexion_r"};
    message.position = {0.1, -0.2, 0.3};
    fixture->joint_states.publish(message);
    ros::WallDuration(1.0 / 30.0).sleep();
  }
  settle();
  EXPECT_EQ(total("Duplicate joints (total)") - duplicates_before, 5) << fixture->diagnostics->summary();
  {
    std::lock_guard<std::mutex> lock(fixture->mutex);
    bool named = false;
    for (const std::string& line : fixture->node_log)
      named = named || line.find("'hip_flexion_r' is given twice") != std::string::npos;
    EXPECT_TRUE(named) << "a log line names the joint given twice";
  }
  // The stream goes on with the next good pose.
  const std::size_t before = statsCount();
  const ros::Time good = ros::Time::now();
  publishPose(good, 0.05);
  EXPECT_EQ(statsAt(good, before).header.stamp, good) << "the next good pose was not solved";
}

TEST(StreamInputs, AfterStampsAheadOfTheClockPosesStampedOnTimeAreSolvedAgain) {
  settle();
  const double future_before = total("Future stamps (total)");
  // A publisher 100 s ahead, with its transforms (as robot_state_publisher sends them for every joint state): tf's
  // buffer then holds data 100 s newer than anything on time, and would drop every on-time transform after it.
  for (int i = 0; i < 5; ++i) {
    publishPose(ros::Time::now() + ros::Duration(100.0), 0.1);
    ros::WallDuration(1.0 / 30.0).sleep();
  }
  settle();
  EXPECT_EQ(total("Future stamps (total)") - future_before, 5) << fixture->diagnostics->summary();
  const double tf_before = total("tf failures (total)"), dropped_before = total("Poses dropped (total)");
  const std::size_t stats_before = statsCount();
  std::vector<ros::Time> on_time;
  // Each pose waits for the frame before it (at most 2 s): on a loaded machine a slow solve would otherwise make the
  // node drop the poses that arrive meanwhile (the newest wins), which is not what this test is about.
  const auto solvedAt = [](const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(fixture->mutex);
    return std::any_of(fixture->stats.begin(), fixture->stats.end(), [&](const auto& stats) {
      return stats.header.stamp == stamp && !stats.refined;
    });
  };
  for (int i = 0; i < 15; ++i) {
    on_time.push_back(ros::Time::now());
    publishPose(on_time.back(), 0.1 + 0.01 * i);
    waitFor([&] { return solvedAt(on_time.back()); }, 2.0);
    ros::WallDuration(1.0 / 15.0).sleep();
  }
  settle();
  int solved = 0;
  {
    std::lock_guard<std::mutex> lock(fixture->mutex);
    for (std::size_t i = stats_before; i < fixture->stats.size(); ++i)
      solved += !fixture->stats[i].refined &&
                std::find(on_time.begin(), on_time.end(), fixture->stats[i].header.stamp) != on_time.end();
  }
  EXPECT_GE(solved, 13) << "poses stamped on time were not solved again; dropped while solving: "
                        << total("Poses dropped (total)") - dropped_before << "; " << fixture->diagnostics->summary();
  // The first on-time pose finds no transforms (tf dropped them) and the buffer is cleared; none after it may fail.
  EXPECT_LE(total("tf failures (total)") - tf_before, 1) << fixture->diagnostics->summary();
}

TEST(StreamInputs, ARotationOffUnitLengthIsNormalisedBeforeTheSkeletonsChainIsComposed) {
  // The URDF's chain as robot_state_publisher sends it (every joint's parent -> child transform), with the femur's
  // joint turned by 0.4 rad about z and its quaternion scaled to |q|^2 = 1.009. tf2 composes the chain with the
  // quaternion as it is, which stretches every translation below the femur by |q|^2: the node must normalise each
  // joint before composing, so that the tibia's particles move rigidly with the femur.
  const auto publishChain = [](const ros::Time& stamp, double angle, double length) {
    const std::map<std::string, Eigen::Isometry3d> root = fixture->skeleton.linkPoses({});
    for (const md::SkeletonJoint& joint : fixture->skeleton.joints()) {
      Eigen::Isometry3d edge = root.at(joint.parent_link).inverse() * root.at(joint.child_link);
      geometry_msgs::TransformStamped transform;
      if (joint.child_link == "femur_r") edge.linear() = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()) * edge.linear();
      transform = tf2::eigenToTransform(edge);
      if (joint.child_link == "femur_r") {
        transform.transform.rotation.x *= length;
        transform.transform.rotation.y *= length;
        transform.transform.rotation.z *= length;
        transform.transform.rotation.w *= length;
      }
      transform.header.stamp = stamp;
      transform.header.frame_id = joint.parent_link;
      transform.child_frame_id = joint.child_link;
      fixture->tf->sendTransform(transform);
    }
  };
  const auto solvedCloud = [&](double angle, double length) {
    const std::size_t before = [] {
      std::lock_guard<std::mutex> lock(fixture->mutex);
      return fixture->clouds.size();
    }();
    const ros::Time stamp = ros::Time::now();
    publishChain(stamp, angle, length);
    ros::WallDuration(0.05).sleep();
    publishJointState(stamp, 0.0);
    return cloudAt(stamp, before);
  };
  const auto tibiaParticles = [](const sensor_msgs::PointCloud2& cloud) {
    const int tibia = static_cast<int>(std::find(fixture->bone_links.begin(), fixture->bone_links.end(), "tibia_r") -
                                       fixture->bone_links.begin());
    std::vector<Eigen::Vector3d> points;
    sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
    sensor_msgs::PointCloud2ConstIterator<std::int32_t> bone(cloud, "bone");
    for (; x != x.end(); ++x, ++y, ++z, ++bone)
      if (*bone == tibia) points.emplace_back(*x, *y, *z);
    return points;
  };
  ros::WallDuration(0.2).sleep();
  const std::vector<Eigen::Vector3d> rest = tibiaParticles(solvedCloud(0.0, 1.0));
  ros::WallDuration(0.1).sleep();
  const std::vector<Eigen::Vector3d> turned = tibiaParticles(solvedCloud(0.4, 1.0045));
  ASSERT_EQ(rest.size(), turned.size());
  ASSERT_GE(rest.size(), 2u) << "gracilis has particles fixed to the tibia";
  // The femur and everything below it turned by 0.4 rad about the pelvis z axis through the femur's origin.
  const Eigen::Vector3d hip = fixture->rest_in_pelvis.at("femur_r").translation();
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  double worst = 0;
  for (std::size_t i = 0; i < rest.size(); ++i)
    worst = std::max(worst, (turned[i] - (hip + turn * (rest[i] - hip))).norm());
  // Composed with the quaternion unnormalised the tibia's particles lie about 4 mm off.
  EXPECT_LT(worst, 1e-5) << "the particles fixed to the tibia did not move rigidly with the femur";
}

TEST(StreamInputs, AJumpAfterAHoldStartsColdAndAHeldUnfinishedFrameIsRefined) {
  settle();
  const auto lastStats = [] {
    std::lock_guard<std::mutex> lock(fixture->mutex);
    return fixture->stats.empty() ? muscle_deformation::DeformationStats() : fixture->stats.back();
  };
  // Flexed and held for half a second (the node skips the held poses as unchanged, refining the last frame).
  ros::Time stamp = ros::Time::now();
  for (int i = 0; i < 30; ++i) {
    publishPose(stamp, 1.2);
    ros::WallDuration(1.0 / 60.0).sleep();
    stamp += ros::Duration(1.0 / 60.0);
  }
  ros::WallDuration(1.0).sleep();
  const muscle_deformation::DeformationStats held = lastStats();
  EXPECT_GT(held.poses_refined, 0u) << "the held pose's unfinished frame was not refined";
  // Then 1.5 rad in one frame: 90 rad/s, a jump, although 1.5 rad over the half second of the hold would be 3 rad/s.
  const std::size_t before = statsCount();
  publishPose(stamp, -0.3);
  const muscle_deformation::DeformationStats jump = statsAt(stamp, before);
  ASSERT_EQ(jump.header.stamp, stamp);
  EXPECT_FALSE(jump.warm_started) << "the jump after the hold was solved warm";
  EXPECT_EQ(jump.resets, held.resets + 1) << "the jump after the hold was not counted as a cold restart";
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "stream_inputs_test");
  Fixture loaded;
  loaded.node = std::make_unique<ros::NodeHandle>();
  ros::NodeHandle& node = *loaded.node;
  std::string urdf;
  if (!node.getParam("/robot_description", urdf)) {
    ADD_FAILURE() << "robot_description is not set";
    return 1;
  }
  loaded.skeleton = md::Skeleton::fromUrdfString(urdf, "robot_description");
  std::map<std::string, Eigen::Isometry3d> root = loaded.skeleton.linkPoses({});
  const Eigen::Isometry3d pelvis_inverse = root.at("pelvis").inverse();
  for (const md::SkeletonLink& link : loaded.skeleton.links()) {
    if (link.collision_meshes.empty()) continue;
    loaded.bone_links.push_back(link.name);
    loaded.rest_in_pelvis[link.name] = pelvis_inverse * root.at(link.name);
  }
  loaded.diagnostics = std::make_unique<md::node_testing::DiagnosticsWatcher>(node, kPosesStatus);
  loaded.joint_states = node.advertise<sensor_msgs::JointState>("/joint_states", 100);
  loaded.tf = std::make_unique<tf2_ros::TransformBroadcaster>();
  loaded.particles_subscriber = node.subscribe<sensor_msgs::PointCloud2>(
      "/muscle_deformation/particles", 10, [&loaded](const sensor_msgs::PointCloud2::ConstPtr& cloud) {
        std::lock_guard<std::mutex> lock(loaded.mutex);
        loaded.clouds.push_back(*cloud);
      });
  loaded.stats_subscriber = node.subscribe<muscle_deformation::DeformationStats>(
      "/muscle_deformation/stats", 1000, [&loaded](const muscle_deformation::DeformationStats::ConstPtr& stats) {
        std::lock_guard<std::mutex> lock(loaded.mutex);
        loaded.stats.push_back(*stats);
      });
  loaded.rosout_subscriber = node.subscribe<rosgraph_msgs::Log>(
      "/rosout", 1000, [&loaded](const rosgraph_msgs::Log::ConstPtr& log) {
        if (log->name.find("muscle_deformation") == std::string::npos) return;
        std::lock_guard<std::mutex> lock(loaded.mutex);
        loaded.node_log.push_back(log->msg);
      });
  fixture = &loaded;
  ros::AsyncSpinner spinner(2);
  spinner.start();
  // The node is up once it subscribes to joint_states and has published diagnostics.
  if (!waitFor([&] { return loaded.joint_states.getNumSubscribers() > 0 && loaded.diagnostics->messages() > 0; },
               120.0)) {
    ADD_FAILURE() << "muscle_deformation did not subscribe to /joint_states or publish diagnostics within 120 s";
    return 1;
  }
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  return result;
}
