#include "muscle_deformation/core/pipeline/sweep_budget_check.hpp"

#include "muscle_deformation/core/base/median.hpp"

#include <algorithm>
#include <cstdio>
#include <string>

namespace muscle_deformation {

std::string SweepBudgetCheck::add(const FrameStats& stats, bool warm) {
  if (judged_ || !(pose_period_ms_ > 0) || !warm || stats.solver.iterations < 1 || stats.solver.diverged) return {};
  // The frame as if it had run its one sweep: its whole solve (the pose's preparation, the contact figures) less the
  // solver's time for the sweeps past the first.
  const double solver_sweep_ms = stats.solver.total_ms / stats.solver.iterations;
  sweep_ms_.push_back(std::max(solver_sweep_ms, stats.solve_ms - (stats.solver.iterations - 1) * solver_sweep_ms));
  if (static_cast<int>(sweep_ms_.size()) < kFramesJudged) return {};
  judged_ = true;
  median_sweep_ms_ = upperMedian(sweep_ms_);
  if (median_sweep_ms_ <= pose_period_ms_) return {};
  char text[768];
  std::snprintf(text, sizeof text,
                "a frame's solve with one sweep takes %.1f ms on this machine (median of the first %d frames, the pose's "
                "preparation included), longer than the %.1f ms "
                "between poses: every frame overruns, and the poses that arrive while it is solved are dropped (the "
                "newest is solved next). ",
                median_sweep_ms_, kFramesJudged, pose_period_ms_);
  const std::string lighter =
      resolution_fitted_
          ? "auto_resolution chose this model already (its startup message): fewer muscles in the scene would be "
            "lighter still."
          : "A lighter model: particles_per_fibre 10 instead of 20 (on the bundled scene 0.54 of the particles and "
            "0.52-0.55 of the time per sweep; auto_resolution: true chooses the resolution at startup from a timed "
            "solve), or fewer muscles in the scene.";
  return text + lighter;

}

}  // namespace muscle_deformation
