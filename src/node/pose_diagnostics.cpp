#include "muscle_deformation/node/pose_diagnostics.hpp"

#include <algorithm>

namespace muscle_deformation::node {
namespace {

double median(std::vector<double> values) {
  if (values.empty()) return 0;
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace

void PoseDiagnostics::received(bool replaced) {
  std::lock_guard<std::mutex> lock(mutex_);
  ++totals_.received;
  ++window_received_;
  if (replaced) {
    ++totals_.dropped;
    ++window_dropped_;
  }
}

void PoseDiagnostics::skipped(SkippedPose cause, const std::string& detail) {
  std::lock_guard<std::mutex> lock(mutex_);
  switch (cause) {
    case SkippedPose::tf_failure: ++totals_.tf_failures; break;
    case SkippedPose::non_finite_joint: ++totals_.non_finite_joints; break;
    case SkippedPose::duplicate_joint: ++totals_.duplicate_joints; break;
    case SkippedPose::future_stamp: ++totals_.future_stamps; break;
  }
  ++window_skipped_[static_cast<int>(cause)];
  last_detail_[static_cast<int>(cause)] = detail;
}

void PoseDiagnostics::stepped(const StreamCounters& stream, double solve_ms) {
  std::lock_guard<std::mutex> lock(mutex_);
  totals_.stream = stream;
  if (solve_ms < 0) return;
  ++window_solved_;
  window_solve_ms_.push_back(solve_ms);
}

PoseTotals PoseDiagnostics::totals() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return totals_;
}

void PoseDiagnostics::addTasks(diagnostic_updater::Updater& updater) {
  updater.add("Output rate", this, &PoseDiagnostics::outputRate);
  updater.add("Solve time", this, &PoseDiagnostics::solveTime);
  updater.add("Poses (tf failures, bad joint states, dropped)", this, &PoseDiagnostics::poses);
}

void PoseDiagnostics::outputRate(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(mutex_);
  const double seconds = std::max(1e-3, (ros::WallTime::now() - window_start_).toSec());
  const double solved_hz = window_solved_ / seconds;
  const double received_hz = window_received_ / seconds;
  if (window_received_ == 0)
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "idle: no poses received");
  else if (expected_rate_hz_ > 0 && solved_hz < 0.8 * std::min(expected_rate_hz_, received_hz))
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "solving %.1f Hz of %.1f Hz received", solved_hz,
                    received_hz);
  else
    status.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "solving %.1f Hz", solved_hz);
  status.add("Poses received (Hz)", received_hz);
  status.add("Frames solved (Hz)", solved_hz);
  status.add("Expected rate (Hz)", expected_rate_hz_);
}

void PoseDiagnostics::solveTime(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(mutex_);
  const double budget_ms = expected_rate_hz_ > 0 ? 1000.0 / expected_rate_hz_ : 0;
  const double median_ms = median(window_solve_ms_);
  const double max_ms =
      window_solve_ms_.empty() ? 0 : *std::max_element(window_solve_ms_.begin(), window_solve_ms_.end());
  if (window_solve_ms_.empty())
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "no frame solved since the last update");
  else if (budget_ms > 0 && median_ms > budget_ms)
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "median solve %.1f ms exceeds %.1f ms", median_ms,
                    budget_ms);
  else
    status.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "median solve %.1f ms", median_ms);
  status.add("Median solve (ms)", median_ms);
  status.add("Max solve (ms)", max_ms);
  status.add("Frame budget (ms)", budget_ms);
  status.add("Non-finite frames (total)", totals_.stream.non_finite);
  status.add("Divergence recoveries (total)", totals_.stream.divergence_recoveries);
  status.add("Diverged frames (total)", totals_.stream.diverged);
}

void PoseDiagnostics::poses(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(mutex_);
  // Each cause on its own: a missing transform, a broken joint state or a clock problem is not a slow solver.
  const auto count = [&](SkippedPose cause) { return window_skipped_[static_cast<int>(cause)]; };
  const auto detail = [&](SkippedPose cause) { return last_detail_[static_cast<int>(cause)]; };
  std::vector<std::string> problems;
  if (count(SkippedPose::tf_failure) > 0)
    problems.push_back(std::to_string(count(SkippedPose::tf_failure)) + " poses without transforms: " +
                       detail(SkippedPose::tf_failure));
  if (count(SkippedPose::non_finite_joint) > 0)
    problems.push_back(std::to_string(count(SkippedPose::non_finite_joint)) +
                       " joint states with non-finite positions (" + detail(SkippedPose::non_finite_joint) + ")");
  if (count(SkippedPose::duplicate_joint) > 0)
    problems.push_back(std::to_string(count(SkippedPose::duplicate_joint)) + " joint states naming a joint twice (" +
                       detail(SkippedPose::duplicate_joint) + ")");
  if (count(SkippedPose::future_stamp) > 0)
    problems.push_back(std::to_string(count(SkippedPose::future_stamp)) + " poses stamped ahead of the clock");
  if (window_dropped_ > 0)
    problems.push_back(std::to_string(window_dropped_) + " poses dropped (solver slower than the input)");
  if (problems.empty()) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "every pose handled");
  } else {
    std::string summary;
    for (const std::string& problem : problems) summary += (summary.empty() ? "" : "; ") + problem;
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, summary);
  }
  status.add("Poses received (total)", totals_.received);
  status.add("Frames solved (total)", totals_.stream.solved);
  status.add("Frames refined (total)", totals_.stream.refined);
  status.add("Poses dropped (total)", totals_.dropped);
  status.add("Poses unchanged (total)", totals_.stream.unchanged);
  status.add("tf failures (total)", totals_.tf_failures);
  status.add("Non-finite joint states (total)", totals_.non_finite_joints);
  status.add("Duplicate joints (total)", totals_.duplicate_joints);
  status.add("Future stamps (total)", totals_.future_stamps);
  status.add("Cold restarts (total)", totals_.stream.resets);
  // This task runs last: start the next window.
  window_solve_ms_.clear();
  window_solved_ = window_received_ = window_dropped_ = 0;
  std::fill(std::begin(window_skipped_), std::end(window_skipped_), 0u);
  window_start_ = ros::WallTime::now();
}

}  // namespace muscle_deformation::node
