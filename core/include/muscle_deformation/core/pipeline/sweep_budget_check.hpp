// Whether the machine fits a frame of one sweep between two poses of the stream. Under a time budget a frame always
// takes at least one sweep, so on a machine too slow for it every frame overruns the pose period and the stream drops the poses that
// arrive meanwhile (the newest is solved next). The user should hear that once, with the measured figures and what to
// change, not find it in a rate diagnostic. The lighter setting it names was measured on the bundled 26 muscles, the
// 1-cycle gait at one sweep a frame, 2026-11-26, Release, a shared 2-core AMD EPYC VM: particles_per_fibre 10 builds 19,802 particles and 179,847 springs
// against 36,443 and 350,043 at 20, and takes 10.6-10.7 ms per sweep against 19.5-20.4 ms (two runs each). What it
// costs in shape is in the report's "Speed against error" (the 13 thigh muscles, 2026-11-27: converged, 7.3 mm RMS
// from the finest model's surface against 4.2 mm at 20 per fibre).
#pragma once

#include "muscle_deformation/core/pipeline/simulation_settings.hpp"

#include <string>
#include <vector>

namespace muscle_deformation {

class SweepBudgetCheck {
 public:
  // `pose_period_ms`: the time between two poses of the stream (0 or less: no expected rate, nothing is judged).
  // `resolution_fitted`: auto_resolution already chose the stream's model (StreamSession::resolutionFit()), so the
  // message does not offer it again.
  explicit SweepBudgetCheck(double pose_period_ms, bool resolution_fitted = false)
      : pose_period_ms_(pose_period_ms), resolution_fitted_(resolution_fitted) {}

  // One solved frame. Warm frames only count (a cold start runs its fixed sweeps once). After kFramesJudged of them,
  // returns the message once when their median time with one sweep (the frame's whole solve, FrameStats::solve_ms,
  // less the solver's time for its sweeps past the first) exceeds the pose period; an empty string otherwise and ever
  // after.
  std::string add(const FrameStats& stats, bool warm);
  bool judged() const { return judged_; }
  double medianSweepMilliseconds() const { return median_sweep_ms_; }  // once judged

  static constexpr int kFramesJudged = 10;

 private:
  double pose_period_ms_;
  bool resolution_fitted_;
  std::vector<double> sweep_ms_;
  bool judged_ = false;
  double median_sweep_ms_ = 0;
};

}  // namespace muscle_deformation
