// The once-only notice that one sweep does not fit between two poses.
#include "muscle_deformation/core/pipeline/sweep_budget_check.hpp"

#include <gtest/gtest.h>

using namespace muscle_deformation;

namespace {
FrameStats frameOf(double total_ms, int sweeps) {
  FrameStats stats;
  stats.solver.total_ms = total_ms;
  stats.solver.iterations = sweeps;
  return stats;
}
}  // namespace

TEST(SweepBudgetCheck, ASlowMachineIsToldOnceWithTheMeasuredSweepAndThePosePeriod) {
  SweepBudgetCheck check(1000.0 / 60);  // 16.7 ms between poses
  EXPECT_EQ(check.add(frameOf(400, 10), false), "");  // a cold start's ten sweeps do not count
  for (int k = 1; k < SweepBudgetCheck::kFramesJudged; ++k) EXPECT_EQ(check.add(frameOf(40, 2), true), "");
  EXPECT_FALSE(check.judged());
  const std::string notice = check.add(frameOf(22, 1), true);
  EXPECT_TRUE(check.judged());
  EXPECT_DOUBLE_EQ(check.medianSweepMilliseconds(), 20.0);
  EXPECT_NE(notice.find("one sweep takes 20.0 ms"), std::string::npos) << notice;
  EXPECT_NE(notice.find("16.7 ms between poses"), std::string::npos) << notice;
  EXPECT_NE(notice.find("particles_per_fibre"), std::string::npos) << notice;
  EXPECT_EQ(check.add(frameOf(40, 1), true), "");  // once
}

TEST(SweepBudgetCheck, AMachineThatFitsASweepHearsNothingAndNoRateMeansNoJudgement) {
  SweepBudgetCheck fits(1000.0 / 60);
  for (int k = 0; k < 2 * SweepBudgetCheck::kFramesJudged; ++k) EXPECT_EQ(fits.add(frameOf(12, 1), true), "");
  EXPECT_TRUE(fits.judged());
  SweepBudgetCheck no_rate(0);
  for (int k = 0; k < 2 * SweepBudgetCheck::kFramesJudged; ++k) EXPECT_EQ(no_rate.add(frameOf(50, 1), true), "");
  EXPECT_FALSE(no_rate.judged());
}

TEST(SweepBudgetCheck, AModelAutoResolutionChoseIsNotOfferedItAgain) {
  SweepBudgetCheck check(1000.0 / 60, /*resolution_fitted=*/true);
  std::string notice;
  for (int k = 0; k < SweepBudgetCheck::kFramesJudged; ++k) notice = check.add(frameOf(30, 1), true);
  EXPECT_NE(notice.find("one sweep takes 30.0 ms"), std::string::npos) << notice;
  EXPECT_NE(notice.find("auto_resolution chose this model already"), std::string::npos) << notice;
  EXPECT_EQ(notice.find("particles_per_fibre 10"), std::string::npos) << notice;
  SweepBudgetCheck unfitted(1000.0 / 60);
  for (int k = 0; k < SweepBudgetCheck::kFramesJudged; ++k) notice = unfitted.add(frameOf(30, 1), true);
  EXPECT_NE(notice.find("auto_resolution: true"), std::string::npos) << notice;
}
