// The gait bag through robot_state_publisher and muscle_deformation_node under sim time (gait_bag.test): every pose
// is solved (or counted as skipped), nothing is NaN, spheres stay out of bone, outputs follow the bag's rate.
#include <muscle_deformation/DeformationStats.h>
#include <muscle_deformation/MuscleSurfaces.h>

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/SetBool.h>
#include <visualization_msgs/MarkerArray.h>

#include <boost/function.hpp>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <vector>

namespace {

struct Recorder {
  std::mutex mutex;
  std::vector<muscle_deformation::DeformationStats> stats;
  std::vector<ros::Time> fibre_stamps, particle_stamps, surface_stamps, surface_marker_stamps;
};

Recorder recorder;
int expected_poses = 73;
double bag_rate_hz = 60.0;
double max_sphere_penetration_m = 0.002;

std::vector<muscle_deformation::DeformationStats> statsCopy() {
  std::lock_guard<std::mutex> lock(recorder.mutex);
  return recorder.stats;
}

// Frames per second of sim time spanned by the stamps, each pose once (a refined frame repeats the stamp of the pose it
// refines).
double rateOf(std::vector<ros::Time> stamps) {
  stamps.erase(std::unique(stamps.begin(), stamps.end()), stamps.end());
  if (stamps.size() < 2) return 0;
  return static_cast<double>(stamps.size() - 1) / (stamps.back() - stamps.front()).toSec();
}

// The frames that solved a new pose (not the refinements of an unfinished one while the bag paused between poses).
std::vector<muscle_deformation::DeformationStats> newPoses(const std::vector<muscle_deformation::DeformationStats>& all) {
  std::vector<muscle_deformation::DeformationStats> frames;
  for (const auto& frame : all)
    if (!frame.refined) frames.push_back(frame);
  return frames;
}

}  // namespace

TEST(GaitBag, EveryPoseIsSolvedOrCountedAsSkipped) {
  const auto stats = statsCopy();
  ASSERT_FALSE(stats.empty()) << "no ~stats message arrived";
  const auto& last = stats.back();
  EXPECT_EQ(last.poses_received, static_cast<std::uint32_t>(expected_poses));
  EXPECT_EQ(last.poses_solved + last.poses_dropped + last.poses_unchanged + last.tf_failures + last.poses_non_finite +
                last.poses_future_stamp,
            last.poses_received)
      << "solved " << last.poses_solved << ", dropped " << last.poses_dropped << ", unchanged "
      << last.poses_unchanged << ", tf failures " << last.tf_failures << ", non-finite " << last.poses_non_finite
      << ", future stamps " << last.poses_future_stamp;
  EXPECT_EQ(last.poses_non_finite, 0u);
  EXPECT_EQ(last.poses_future_stamp, 0u);
  EXPECT_EQ(last.tf_failures, 0u) << "robot_state_publisher publishes every pose's transforms";
  // At the test's playback rate the solver keeps up: nothing is dropped.
  EXPECT_EQ(last.poses_dropped, 0u);
  EXPECT_EQ(newPoses(stats).size(), last.poses_solved) << "one ~stats message per solved pose";
  // Between the bag's poses (played slowly) the node refines each unfinished frame and publishes some of the
  // refinements: they are counted apart, never as poses.
  EXPECT_LE(stats.size() - last.poses_solved, last.poses_refined);
}

TEST(GaitBag, NoFrameHasNonFinitePositions) {
  for (const auto& frame : statsCopy()) {
    EXPECT_TRUE(frame.finite) << "frame at " << frame.header.stamp;
    EXPECT_TRUE(std::isfinite(frame.spring_deviation_ratio)) << "frame at " << frame.header.stamp;
  }
}

TEST(GaitBag, NoGaitFrameTriggersTheDivergenceCheck) {
  // Gait frames are all legitimate solves: a recovery here would be a false alarm.
  for (const auto& frame : statsCopy()) {
    EXPECT_EQ(frame.divergence_recoveries, 0u) << "frame at " << frame.header.stamp;
    EXPECT_FALSE(frame.diverged) << "frame at " << frame.header.stamp;
    EXPECT_GE(frame.time_step_s, 0.0) << "frame at " << frame.header.stamp;  // 0: the default solver has no step
  }
}

TEST(GaitBag, EveryFrameSaysHowFinishedItIs) {
  // The default solver (block descent) measures its force residual: every frame carries it, finite and not negative.
  for (const auto& frame : statsCopy()) {
    EXPECT_TRUE(frame.has_residual) << "frame at " << frame.header.stamp;
    EXPECT_TRUE(std::isfinite(frame.force_residual)) << "frame at " << frame.header.stamp;
    EXPECT_GE(frame.force_residual, 0.0) << "frame at " << frame.header.stamp;
    EXPECT_GE(frame.iterations, 1) << "frame at " << frame.header.stamp;  // a budget always allows one sweep
  }
}

TEST(GaitBag, SpheresStayOutOfBone) {
  double deepest = 0;
  for (const auto& frame : statsCopy()) {
    EXPECT_TRUE(frame.has_collision_metrics) << "frame at " << frame.header.stamp << ": " << frame.collision_absent_reason;
    deepest = std::max(deepest, frame.max_penetration_sphere_bone_m);
  }
  EXPECT_LT(deepest, max_sphere_penetration_m);
  RecordProperty("max_penetration_sphere_bone_m", std::to_string(deepest));
}

TEST(GaitBag, FramesFollowTheBagInOrderAndStartWarmAfterTheFirst) {
  const auto stats = newPoses(statsCopy());
  ASSERT_GE(stats.size(), 2u);
  EXPECT_FALSE(stats.front().warm_started);
  for (std::size_t i = 1; i < stats.size(); ++i) {
    EXPECT_GT(stats[i].header.stamp, stats[i - 1].header.stamp);
    EXPECT_TRUE(stats[i].warm_started) << "frame " << i;
  }
}

TEST(GaitBag, OutputsArriveAtTheBagRate) {
  std::lock_guard<std::mutex> lock(recorder.mutex);
  const std::size_t solved = recorder.stats.size();  // new poses and published refinements alike
  for (const auto* stamps : {&recorder.fibre_stamps, &recorder.particle_stamps, &recorder.surface_stamps,
                             &recorder.surface_marker_stamps}) {
    EXPECT_EQ(stamps->size(), solved);
    // Sim-time rate: one output per bag message, 1 / 60 s apart in the bag's clock.
    EXPECT_NEAR(rateOf(*stamps), bag_rate_hz, 0.05 * bag_rate_hz);
  }
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "gait_bag_test");
  ros::NodeHandle node, private_node("~");
  private_node.param("expected_poses", expected_poses, expected_poses);
  private_node.param("bag_rate_hz", bag_rate_hz, bag_rate_hz);
  private_node.param("max_sphere_penetration_m", max_sphere_penetration_m, max_sphere_penetration_m);

  const auto stamp_into = [](std::vector<ros::Time>& list, const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(recorder.mutex);
    list.push_back(stamp);
  };
  using StatsCallback = boost::function<void(const muscle_deformation::DeformationStats::ConstPtr&)>;
  using MarkersCallback = boost::function<void(const visualization_msgs::MarkerArray::ConstPtr&)>;
  using CloudCallback = boost::function<void(const sensor_msgs::PointCloud2::ConstPtr&)>;
  using SurfacesCallback = boost::function<void(const muscle_deformation::MuscleSurfaces::ConstPtr&)>;
  ros::Subscriber stats = node.subscribe<muscle_deformation::DeformationStats>(
      "/muscle_deformation/stats", 1000, StatsCallback([](const muscle_deformation::DeformationStats::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(recorder.mutex);
        recorder.stats.push_back(*m);
      }));
  ros::Subscriber fibres = node.subscribe<visualization_msgs::MarkerArray>(
      "/muscle_deformation/fibres", 1000, MarkersCallback([&](const visualization_msgs::MarkerArray::ConstPtr& m) {
        if (!m->markers.empty()) stamp_into(recorder.fibre_stamps, m->markers.front().header.stamp);
      }));
  ros::Subscriber particles = node.subscribe<sensor_msgs::PointCloud2>(
      "/muscle_deformation/particles", 1000, CloudCallback([&](const sensor_msgs::PointCloud2::ConstPtr& m) {
        stamp_into(recorder.particle_stamps, m->header.stamp);
      }));
  ros::Subscriber surfaces = node.subscribe<muscle_deformation::MuscleSurfaces>(
      "/muscle_deformation/surfaces", 1000, SurfacesCallback([&](const muscle_deformation::MuscleSurfaces::ConstPtr& m) {
        stamp_into(recorder.surface_stamps, m->header.stamp);
      }));
  ros::Subscriber surface_markers = node.subscribe<visualization_msgs::MarkerArray>(
      "/muscle_deformation/surface_markers", 1000,
      MarkersCallback([&](const visualization_msgs::MarkerArray::ConstPtr& m) {
        if (!m->markers.empty()) stamp_into(recorder.surface_marker_stamps, m->markers.front().header.stamp);
      }));

  ros::AsyncSpinner spinner(2);
  spinner.start();
  // The bag starts paused: resume it once the node is up (its service is advertised after the model is built).
  if (!ros::service::waitForService("/muscle_deformation/deform_pose", ros::Duration(600)) ||
      !ros::service::waitForService("/player/pause_playback", ros::Duration(60))) {
    ADD_FAILURE() << "the node or the bag player did not come up";
    return 1;
  }
  ros::WallDuration(1.0).sleep();  // let the subscriptions connect
  std_srvs::SetBool resume;
  resume.request.data = false;
  if (!ros::service::call("/player/pause_playback", resume)) {
    ADD_FAILURE() << "could not resume the bag player";
    return 1;
  }

  // Wait (wall time) until every pose of the bag is accounted for and no output arrived for a few seconds.
  const ros::WallTime give_up = ros::WallTime::now() + ros::WallDuration(800);
  ros::WallTime last_change = ros::WallTime::now();
  std::size_t last_count = 0;
  while (ros::ok() && ros::WallTime::now() < give_up) {
    ros::WallDuration(0.5).sleep();
    std::lock_guard<std::mutex> lock(recorder.mutex);
    const std::size_t count = recorder.stats.size() + recorder.fibre_stamps.size() + recorder.particle_stamps.size() +
                              recorder.surface_stamps.size() + recorder.surface_marker_stamps.size();
    if (count != last_count) {
      last_count = count;
      last_change = ros::WallTime::now();
    }
    const bool all_received = !recorder.stats.empty() &&
                              recorder.stats.back().poses_received >= static_cast<std::uint32_t>(expected_poses);
    if (all_received && ros::WallTime::now() - last_change > ros::WallDuration(5.0)) break;
  }
  spinner.stop();
  return RUN_ALL_TESTS();
}
