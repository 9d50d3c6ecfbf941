// The service beside a running stream (service_load.test): a burst of concurrent calls neither starves the stream nor
// the diagnostics, calls beyond the queue are refused with a message, every call honours its limits and the node's
// ceiling, and warm starts continue only the same caller's nearby previous answer.
#include "node_test_helpers.hpp"

#include "muscle_deformation/core/scene/scene.hpp"

#include <muscle_deformation/DeformPose.h>
#include <muscle_deformation/DeformationStats.h>

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/JointState.h>

#include <boost/function.hpp>

#include <algorithm>
#include <atomic>
#include <climits>
#include <cstdio>
#include <cmath>
#include <cstdlib>
#include <thread>
#include <vector>

namespace md = muscle_deformation;
using md::node_testing::waitFor;

namespace {

const char* kService = "/muscle_deformation/deform_pose";
// The stream must keep at least this share of its rate without service calls while a burst of calls is served.
constexpr double kMinStreamRateShare = 0.5;
double max_solve_time_s = 2.0;  // the node's ~max_solve_time_s in service_load.test
int max_queued = 2;             // the node's ~service_max_queued

std::atomic<int> stats_received{0};
std::atomic<bool> publishing{true};

md::DeformPose::Request poseRequest(double hip_flexion) {
  md::DeformPose::Request request;
  request.joint_state.name = {"hip_flexion_r"};
  request.joint_state.position = {hip_flexion};
  return request;
}

md::DeformPose::Response call(const md::DeformPose::Request& request, double* seconds = nullptr) {
  md::DeformPose srv;
  srv.request = request;
  const ros::WallTime start = ros::WallTime::now();
  EXPECT_TRUE(ros::service::call(kService, srv)) << "the service call itself failed";
  if (seconds) *seconds = (ros::WallTime::now() - start).toSec();
  return srv.response;
}

// Output rate of ~stats (Hz of wall time) over `seconds`, while `during` runs (if given) on another thread.
double statsRate(double seconds) {
  const int before = stats_received;
  ros::WallDuration(seconds).sleep();
  return (stats_received - before) / seconds;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// The node's residual_tolerance, read from the parameter server in main (config/muscle_deformation.yaml is the
// default): block descent's frame has converged below it.
double residual_tolerance = -1.0;

// "converged" is the residual criterion, whatever stopped the solve, and the reply says which side of it the frame
// ended on.
void expectConvergedByTheResidual(const md::DeformPose::Response& r) {
  ASSERT_TRUE(r.stats.has_residual) << r.message;
  EXPECT_EQ(r.stats.converged, r.stats.force_residual < residual_tolerance) << r.message;
  EXPECT_TRUE(contains(r.message, r.stats.converged ? "; converged: force residual" : "; not converged: force residual"))
      << r.message;
}

}  // namespace

TEST(ServiceLoad, ABurstOfCallsKeepsTheStreamAndDiagnosticsGoingAndRefusesCallsBeyondTheQueue) {
  ros::NodeHandle node;
  md::node_testing::DiagnosticsWatcher diagnostics(node, "Output rate");
  const double baseline_hz = statsRate(3.0);
  ASSERT_GT(baseline_hz, 5.0) << "the stream runs before the burst";

  // 8 callers at once, each asking for unlimited iterations within 1.5 s.
  constexpr int kCallers = 8;
  constexpr double kBudgetMs = 1500;
  std::vector<md::DeformPose::Response> responses(kCallers);
  std::vector<double> seconds(kCallers, 0);
  std::atomic<int> finished{0};
  const int stats_before = stats_received, diagnostics_before = diagnostics.messages();
  const ros::WallTime burst_start = ros::WallTime::now();
  std::vector<std::thread> callers;
  for (int c = 0; c < kCallers; ++c) {
    callers.emplace_back([&, c] {
      md::DeformPose::Request request = poseRequest(0.3 + 0.01 * c);
      request.max_iterations = INT_MAX;
      request.time_budget_ms = kBudgetMs;
      responses[c] = call(request, &seconds[c]);
      ++finished;
    });
  }
  // Measure the stream while the first calls are being solved.
  const double window_s = 3.0;
  ros::WallDuration(window_s).sleep();
  const double burst_hz = (stats_received - stats_before) / window_s;
  const int diagnostics_during = diagnostics.messages() - diagnostics_before;
  for (std::thread& caller : callers) caller.join();
  const double burst_s = (ros::WallTime::now() - burst_start).toSec();

  std::printf("stream %.1f Hz before the burst, %.1f Hz during it; %d diagnostics messages in %.0f s\n", baseline_hz,
              burst_hz, diagnostics_during, window_s);
  EXPECT_GE(burst_hz, kMinStreamRateShare * baseline_hz)
      << "stream at " << burst_hz << " Hz during the burst, " << baseline_hz << " Hz before";
  EXPECT_GE(diagnostics_during, 2) << "diagnostics kept publishing (1 Hz) during the burst";

  int solved = 0, refused = 0;
  for (int c = 0; c < kCallers; ++c) {
    const md::DeformPose::Response& r = responses[c];
    if (r.success) {
      ++solved;
      EXPECT_TRUE(r.stats.time_limit_reached) << r.message;
      expectConvergedByTheResidual(r);
      EXPECT_LE(r.stats.solve_ms, kBudgetMs + 250) << r.message;
      EXPECT_TRUE(contains(r.message, "time_budget_ms")) << r.message;
    } else {
      ++refused;
      EXPECT_TRUE(contains(r.message, "busy")) << r.message;
      EXPECT_LT(seconds[c], 1.0) << "a refusal comes at once, not after the queue: " << r.message;
    }
  }
  std::printf("burst of %d calls: %d solved, %d refused, %.1f s in all\n", kCallers, solved, refused, burst_s);
  EXPECT_GE(solved, 1);
  EXPECT_LE(solved, max_queued + 1) << "one solving and service_max_queued waiting";
  EXPECT_GE(refused, kCallers - (max_queued + 1) - 1) << "the rest are refused (one may slip in as a slot frees)";
  EXPECT_LT(burst_s, (solved + 1) * (kBudgetMs / 1000.0 + 1.0)) << "the accepted calls ran one after the other";
}

TEST(ServiceLoad, EveryLimitOfARequestIsHonouredAndTheNodeCeilingBoundsTheRest) {
  // Unlimited iterations and no budget: the node's max_solve_time_s ends it.
  md::DeformPose::Request unlimited = poseRequest(0.4);
  unlimited.max_iterations = INT_MAX;
  double seconds = 0;
  const md::DeformPose::Response bounded = call(unlimited, &seconds);
  ASSERT_TRUE(bounded.success) << bounded.message;
  EXPECT_TRUE(bounded.stats.time_limit_reached);
  expectConvergedByTheResidual(bounded);
  EXPECT_TRUE(contains(bounded.message, "max_solve_time_s")) << bounded.message;
  EXPECT_LT(seconds, max_solve_time_s + 3.0) << bounded.message;

  // A displacement tolerance is honoured although the node's stopping rule is `iterations`. One muscle on its own
  // settles to it well within the node's ceiling (the node's three, in contact, do not: see service_load.test).
  md::DeformPose::Request tolerant = poseRequest(0.4);
  tolerant.muscles = {"adductor_longus"};
  tolerant.max_iterations = 1000000;
  tolerant.displacement_tolerance_m = 1e-5;
  const md::DeformPose::Response settled = call(tolerant);
  std::printf("displacement tolerance 1e-5 m, one muscle: %s\n", settled.message.c_str());
  ASSERT_TRUE(settled.success) << settled.message;
  EXPECT_TRUE(contains(settled.message, "the mean step fell below 1e-05 m")) << settled.message;
  expectConvergedByTheResidual(settled);
  EXPECT_LT(settled.stats.iterations, 1000000);
  EXPECT_FALSE(settled.stats.time_limit_reached) << settled.message;

  // A plain iteration count is not convergence: five cold sweeps leave the residual far above the tolerance.
  md::DeformPose::Request counted = poseRequest(0.4);
  counted.max_iterations = 5;
  const md::DeformPose::Response five = call(counted);
  ASSERT_TRUE(five.success) << five.message;
  EXPECT_EQ(five.stats.iterations, 5);
  EXPECT_FALSE(five.stats.converged) << five.message;
  expectConvergedByTheResidual(five);
}

TEST(ServiceLoad, WarmStartsContinueOnlyTheSameCallersNearbyAnswer) {
  // Another client (the rosservice tool) calls in between: the warm request starts cold and says why.
  ASSERT_TRUE(call(poseRequest(0.2)).success);
  const int status = std::system(
      "rosservice call /muscle_deformation/deform_pose \"{joint_state: {name: [hip_flexion_r], position: [0.25]}}\" "
      "> /dev/null");
  ASSERT_EQ(status, 0) << "rosservice call failed";
  md::DeformPose::Request warm = poseRequest(0.21);
  warm.warm_start = true;
  const md::DeformPose::Response after_other = call(warm);
  ASSERT_TRUE(after_other.success) << after_other.message;
  EXPECT_FALSE(after_other.stats.warm_started);
  EXPECT_TRUE(contains(after_other.message, "another client")) << after_other.message;

  // The same caller, a nearby pose: warm.
  warm.joint_state.position = {0.22};
  const md::DeformPose::Response continued = call(warm);
  ASSERT_TRUE(continued.success) << continued.message;
  EXPECT_TRUE(continued.stats.warm_started) << continued.message;

  // The same caller after a pose with the femur 100 m away: the jump guard starts cold, and the answer is sane.
  md::DeformPose::Request far;
  geometry_msgs::TransformStamped femur;
  femur.child_frame_id = "femur_r";
  femur.transform.translation.x = 100.0;
  femur.transform.rotation.w = 1.0;
  far.bone_poses = {femur};
  call(far);  // its answer does not matter here, only what it leaves behind
  warm.joint_state.position = {0.2};
  const md::DeformPose::Response after_jump = call(warm);
  ASSERT_TRUE(after_jump.success) << after_jump.message;
  EXPECT_FALSE(after_jump.stats.warm_started);
  EXPECT_TRUE(contains(after_jump.message, "warm start refused")) << after_jump.message;
  if (after_jump.stats.has_surface_metrics) {
    EXPECT_LT(after_jump.stats.volume_error_max_pct, 50.0);
  }
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "service_load_test");
  ros::NodeHandle node, private_node("~");
  private_node.param("max_solve_time_s", max_solve_time_s, max_solve_time_s);
  private_node.param("max_queued", max_queued, max_queued);
  if (!node.getParam("/muscle_deformation/residual_tolerance", residual_tolerance) || !(residual_tolerance > 0.0)) {
    ADD_FAILURE() << "/muscle_deformation/residual_tolerance is not set to a positive number";
    return 1;
  }
  std::string urdf;
  if (!node.getParam("/robot_description", urdf)) {
    ADD_FAILURE() << "robot_description is not set";
    return 1;
  }
  ros::Publisher joint_states = node.advertise<sensor_msgs::JointState>("/joint_states", 10);
  const boost::function<void(const md::DeformationStats::ConstPtr&)> count_stats =
      [](const md::DeformationStats::ConstPtr&) { ++stats_received; };
  ros::Subscriber stats = node.subscribe<md::DeformationStats>("/muscle_deformation/stats", 100, count_stats);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  // The stream: a slow hip flexion at 30 Hz for as long as the tests run.
  std::thread stream([&] {
    const ros::WallTime start = ros::WallTime::now();
    // robot_state_publisher turns only the joints it is given into transforms: give every movable joint.
    sensor_msgs::JointState message;
    message.name = md::Skeleton::fromUrdfString(urdf, "robot_description").movableJointNames();
    message.position.assign(message.name.size(), 0.0);
    const auto hip = std::find(message.name.begin(), message.name.end(), "hip_flexion_r") - message.name.begin();
    while (publishing && ros::ok()) {
      message.header.stamp = ros::Time::now();
      message.position[static_cast<std::size_t>(hip)] = 0.3 * std::sin((ros::WallTime::now() - start).toSec());
      joint_states.publish(message);
      ros::WallDuration(1.0 / 30.0).sleep();
    }
  });
  int result = 1;
  if (!ros::service::waitForService(kService, ros::Duration(120)) ||
      !waitFor([] { return stats_received > 10; }, 60.0)) {
    ADD_FAILURE() << kService << " did not appear, or the stream did not start";
  } else {
    result = RUN_ALL_TESTS();
  }
  publishing = false;
  stream.join();
  spinner.stop();
  return result;
}
