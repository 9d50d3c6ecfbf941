// Fixtures and checks shared by the core tests.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/pipeline/simulation_settings.hpp"
#include "muscle_deformation/core/solvers/block_descent_solver.hpp"

#include <gtest/gtest.h>

#include <exception>
#include <string>

namespace muscle_deformation::testing {

// Unit cube [0,1]^3, two triangles per face, counter-clockwise seen from outside; vertex i has coordinates
// (x, y, z) with x, y from the bottom face's corners 0..3 counter-clockwise and z = i / 4.
inline TriangleMesh unitCube() {
  TriangleMesh mesh;
  mesh.vertices.resize(3, 8);
  mesh.vertices << 0, 1, 1, 0, 0, 1, 1, 0,  //
      0, 0, 1, 1, 0, 0, 1, 1,               //
      0, 0, 0, 0, 1, 1, 1, 1;
  const int quads[6][4] = {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4}, {2, 3, 7, 6}, {0, 4, 7, 3}, {1, 2, 6, 5}};
  mesh.triangles.resize(3, 12);
  for (int f = 0; f < 6; ++f) {
    mesh.triangles.col(2 * f) << quads[f][0], quads[f][1], quads[f][2];
    mesh.triangles.col(2 * f + 1) << quads[f][0], quads[f][2], quads[f][3];
  }
  return mesh;
}

// Stopping for block descent and Newton-Krylov: until the force residual falls below `tolerance`, at most
// `max_iterations` iterations.
inline StoppingSettings converging(int max_iterations, double tolerance) {
  return StoppingSettings::atResidual(tolerance, max_iterations);
}

// One pose solved by a simulation (the pipeline's MuscleSimulation, which takes bone transforms): the pose's bone
// transforms, then the solve with `stopping`.
template <typename Simulation>
FrameStats solvePose(Simulation& simulation, const Pose& pose, StartMode start, const FrameStopping& stopping,
                     double frame_interval_s = kNominalFrameIntervalS) {
  return simulation.solve(boneTransformsOf(simulation.bones(), pose), start, stopping, frame_interval_s);
}

// A state at `positions` with zero velocity.
inline ParticleState stateAt(const Eigen::Matrix3Xd& positions) {
  ParticleState state;
  state.position = positions;
  state.previous_position = positions;
  return state;
}

// The message of the `Error` that `call` throws, or a test failure (and "") if it throws nothing or something else.
template <typename Error, typename Call>
std::string errorMessageOf(Call&& call) {
  try {
    call();
  } catch (const Error& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "threw something other than the expected error: " << e.what();
    return "";
  }
  ADD_FAILURE() << "did not throw";
  return "";
}

}  // namespace muscle_deformation::testing

// The text contains the part (error messages must name what is wrong).
#define EXPECT_CONTAINS(text, part) \
  EXPECT_NE(std::string(text).find(part), std::string::npos) << "message: " << (text) << "\nexpected to contain: " << (part)
