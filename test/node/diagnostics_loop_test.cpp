// A looping bag under sim time (diagnostics_loop.test): /diagnostics keeps publishing after the clock jumps back at
// every wrap of the bag.
#include "node_test_helpers.hpp"

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Clock.h>
#include <std_srvs/SetBool.h>

#include <atomic>
#include <mutex>
#include <vector>

namespace md = muscle_deformation;
using md::node_testing::waitFor;

namespace {

std::mutex mutex;
ros::Time last_clock;
std::vector<ros::WallTime> wraps;  // wall times at which the clock went back

void onClock(const rosgraph_msgs::Clock::ConstPtr& clock) {
  std::lock_guard<std::mutex> lock(mutex);
  if (!last_clock.isZero() && clock->clock < last_clock) wraps.push_back(ros::WallTime::now());
  last_clock = clock->clock;
}

std::size_t wrapCount() {
  std::lock_guard<std::mutex> lock(mutex);
  return wraps.size();
}

}  // namespace

TEST(DiagnosticsLoop, KeepPublishingThroughEveryWrapOfTheBag) {
  ros::NodeHandle node;
  md::node_testing::DiagnosticsWatcher diagnostics(node, "Output rate");
  // Resume the paused player once the node listens.
  ros::ServiceClient pause = node.serviceClient<std_srvs::SetBool>("/player/pause_playback");
  ASSERT_TRUE(pause.waitForExistence(ros::Duration(60)));
  // The node may still be building the scene (bone distance fields, skinning) when the player is up: the bag is to wrap
  // under a running node, so wait for its first diagnostics before playing.
  ASSERT_TRUE(waitFor([&] { return diagnostics.messages() > 0; }, 60.0)) << "the node never published diagnostics";
  std_srvs::SetBool resume;
  resume.request.data = false;
  ASSERT_TRUE(pause.call(resume));

  // The 1.2 s bag wraps about every 1.2 s: wait for three wraps, then count diagnostics over the next 4 s.
  ASSERT_TRUE(waitFor([] { return wrapCount() >= 3; }, 30.0)) << "the bag did not loop (" << wrapCount() << " wraps)";
  const int before = diagnostics.messages();
  ros::WallDuration(4.0).sleep();
  const int during = diagnostics.messages() - before;
  EXPECT_GE(wrapCount(), 5u) << "the clock jumped back again while diagnostics were counted";
  EXPECT_GE(during, 3) << "diagnostics are published once a second of wall time, whatever the sim clock does";
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "diagnostics_loop_test");
  ros::NodeHandle node;
  ros::Subscriber clock = node.subscribe("/clock", 1000, onClock);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  return result;
}
