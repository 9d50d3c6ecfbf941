// What became of the poses the node received, counted per cause (a missing transform, a broken joint state, a clock
// problem, a slow solver are different problems), the solve times of the current window, and the three diagnostic
// tasks built from them. Thread-safe: the subscriber, the worker and the diagnostics timer run on different threads.
#pragma once

#include "muscle_deformation/core/pipeline/stream_session.hpp"

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/time.h>

#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

namespace muscle_deformation::node {

enum class SkippedPose {
  tf_failure,         // a bone's transform was not available at the pose's stamp
  non_finite_joint,   // the joint state held a NaN or infinite position
  duplicate_joint,    // the joint state named a joint twice
  future_stamp,       // stamped ahead of the clock
};

// Counts since the node started: the input side here, the stream's decisions from its session.
struct PoseTotals {
  std::uint32_t received = 0, dropped = 0, tf_failures = 0, non_finite_joints = 0, duplicate_joints = 0,
                future_stamps = 0;
  StreamCounters stream;
};

class PoseDiagnostics {
 public:
  explicit PoseDiagnostics(double expected_rate_hz) : expected_rate_hz_(expected_rate_hz) {}

  // A pose arrived; `replaced` a pending one the worker had not taken yet (the solver is slower than the input).
  void received(bool replaced);
  void skipped(SkippedPose cause, const std::string& detail);
  // The stream's counts after a step, and the solve time of a frame it solved (< 0: none).
  void stepped(const StreamCounters& stream, double solve_ms);
  PoseTotals totals() const;

  // Registers the tasks "Output rate", "Solve time" and "Poses" (the last one starts the next window).
  void addTasks(diagnostic_updater::Updater& updater);

 private:
  void outputRate(diagnostic_updater::DiagnosticStatusWrapper& status);
  void solveTime(diagnostic_updater::DiagnosticStatusWrapper& status);
  void poses(diagnostic_updater::DiagnosticStatusWrapper& status);

  const double expected_rate_hz_;
  mutable std::mutex mutex_;
  PoseTotals totals_;
  // Since the last diagnostics update.
  std::vector<double> window_solve_ms_;
  std::uint32_t window_solved_ = 0, window_received_ = 0, window_dropped_ = 0;
  std::uint32_t window_skipped_[4] = {0, 0, 0, 0};  // by SkippedPose
  std::string last_detail_[4];
  ros::WallTime window_start_ = ros::WallTime::now();
};

}  // namespace muscle_deformation::node
