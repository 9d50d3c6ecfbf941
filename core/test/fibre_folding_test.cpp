// Specifications of the fibre folding measure: whether the fibres keep their line as the belly deforms.
#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace muscle_deformation;

namespace {

// One muscle of two fibres of five particles along x, 1 cm apart, the second fibre 1 cm above the first.
MassSpringSystem twoStraightFibres() {
  MassSpringSystem system;
  system.rest_position.resize(3, 10);
  for (int f = 0; f < 2; ++f)
    for (int k = 0; k < 5; ++k) {
      system.rest_position.col(5 * f + k) = Eigen::Vector3d(0.01 * k, 0, 0.01 * f);
      system.fibre_of.push_back(f);
      system.muscle_of.push_back(0);
      system.sample_of.push_back(k);
    }
  system.muscle_name = {"belly"};
  system.muscle_begin = {0, 10};
  return system;
}

}  // namespace

TEST(FibreFolding, FibresAsStraightAsAtRestAreNeitherFoldedNorTortuousWhateverTheirLength) {
  const MassSpringSystem system = twoStraightFibres();
  Eigen::Matrix3Xd stretched = system.rest_position;
  stretched.row(0) *= 1.3;
  const FibreFolding folding = measureFibreFolding(system, stretched);
  EXPECT_EQ(folding.fibres, 2);
  EXPECT_EQ(folding.folded_fibres, 0);
  EXPECT_NEAR(folding.worst_tortuosity_ratio, 1.0, 1e-12);
  EXPECT_EQ(folding.most_folded_muscle, -1);
}

TEST(FibreFolding, AFibreThatTurnsBackIsFoldedAndItsArcOutgrowsItsChord) {
  const MassSpringSystem system = twoStraightFibres();
  Eigen::Matrix3Xd position = system.rest_position;
  // The second fibre's end pushed back past its middle: 0, 1, 2, 1.5, 2.5 cm along x.
  position.col(8).x() = 0.015;
  position.col(8).y() = 0.002;
  position.col(9).x() = 0.025;
  const FibreFolding folding = measureFibreFolding(system, position);
  EXPECT_EQ(folding.folded_fibres, 1);
  EXPECT_EQ(folding.most_folded_muscle, 0);
  EXPECT_EQ(folding.worst_muscle, 0);
  // Arc 1 + 1 + 0.54 + 1.02 cm over a chord of 2.5 cm, against 1 at rest.
  const double arc = 0.02 + std::hypot(0.005, 0.002) + std::hypot(0.01, 0.002);
  EXPECT_NEAR(folding.worst_tortuosity_ratio, arc / 0.025, 1e-9);
}

TEST(FibreFolding, ABendAtRestIsNoFold) {
  MassSpringSystem system = twoStraightFibres();
  // The first fibre turns back at rest already (a hooked segmentation): only a new turn counts.
  system.rest_position.col(3) = Eigen::Vector3d(0.015, 0.002, 0);
  system.rest_position.col(4) = Eigen::Vector3d(0.025, 0, 0);
  const FibreFolding folding = measureFibreFolding(system, system.rest_position);
  EXPECT_EQ(folding.folded_fibres, 0);
  EXPECT_NEAR(folding.worst_tortuosity_ratio, 1.0, 1e-12);
}

TEST(FibreFolding, PositionsOfAnotherModelAreMeasuredAsAbsent) {
  const MassSpringSystem system = twoStraightFibres();
  const FibreFolding folding = measureFibreFolding(system, Eigen::Matrix3Xd::Zero(3, 4));
  EXPECT_EQ(folding.fibres, 0);
  EXPECT_TRUE(std::isnan(folding.worst_tortuosity_ratio));
}
