// Shared by the node's rostest gtests: waiting on a condition in wall time, and reading the node's diagnostics.
#pragma once

#include <diagnostic_msgs/DiagnosticArray.h>
#include <ros/ros.h>

#include <functional>
#include <map>
#include <mutex>
#include <string>

namespace muscle_deformation::node_testing {

// Polls `done` every 10 ms (callbacks run on the test's AsyncSpinner) until it holds or `seconds` of wall time pass.
inline bool waitFor(const std::function<bool()>& done, double seconds) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::ok() && ros::WallTime::now() < deadline) {
    if (done()) return true;
    ros::WallDuration(0.01).sleep();
  }
  return done();
}

// The newest /diagnostics status of the node whose name contains `status_name`, as key -> value, plus its summary.
class DiagnosticsWatcher {
 public:
  DiagnosticsWatcher(ros::NodeHandle& node, std::string status_name)
      : status_name_(std::move(status_name)),
        subscriber_(node.subscribe("/diagnostics", 100, &DiagnosticsWatcher::onDiagnostics, this)) {}

  std::map<std::string, std::string> values() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return values_;
  }
  std::string summary() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return summary_;
  }
  int messages() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  // The value of `key` as a number (-1 if absent).
  double number(const std::string& key) const {
    const auto all = values();
    const auto found = all.find(key);
    return found == all.end() ? -1.0 : std::stod(found->second);
  }

 private:
  void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& message) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const diagnostic_msgs::DiagnosticStatus& status : message->status) {
      if (status.name.find(status_name_) == std::string::npos) continue;
      ++messages_;
      summary_ = status.message;
      values_.clear();
      for (const diagnostic_msgs::KeyValue& value : status.values) values_[value.key] = value.value;
    }
  }

  std::string status_name_;
  mutable std::mutex mutex_;
  std::map<std::string, std::string> values_;
  std::string summary_;
  int messages_ = 0;
  ros::Subscriber subscriber_;
};

}  // namespace muscle_deformation::node_testing
