// A synthetic thigh: analytic bones and spindle muscles with grid fibres, sized like the GRAPP paper's Table 1
// scene (13 muscles x 64 fibres). Used by benchmarks, the core demo and tests; real anatomy lives in data/.
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"

#include <vector>

namespace muscle_deformation {

// Closed, outward-wound primitives (metres).
TriangleMesh makeCylinderMesh(const Eigen::Vector3d& bottom_centre, const Eigen::Vector3d& top_centre, double radius,
                              int segments = 24, int rings = 8);
TriangleMesh makeSphereMesh(const Eigen::Vector3d& centre, double radius, int subdivisions = 3);  // icosphere
// Faces split into square-ish cells no longer than max_edge_m (0: two triangles per face).
TriangleMesh makeBoxMesh(const Eigen::Vector3d& min_corner, const Eigen::Vector3d& max_corner, double max_edge_m = 0);

// A spindle muscle along the segment bottom..top: radius profile peak_radius * (0.35 + 0.65 sin(pi t)), elliptic
// cross-section (aspect = minor/major), and fibres_per_side^2 straight-in-cross-section fibres on a grid that
// follow the same profile, each sampled at `fibre_points` points from bottom (origin) to top (insertion).
Muscle makeSpindleMuscle(const std::string& name, const Eigen::Vector3d& bottom, const Eigen::Vector3d& top,
                         double peak_radius, double aspect = 1.0, int fibres_per_side = 8, int fibre_points = 50,
                         int segments = 32, int rings = 40);

struct SyntheticScene {
  std::vector<Bone> bones;      // pelvis (box), femur (cylinder), tibia (cylinder)
  std::vector<Muscle> muscles;  // around the femur, pelvis to tibia
};

// `muscle_count` spindles (default 13, as the paper's thigh) with 64 fibres each.
SyntheticScene makeSyntheticThigh(int muscle_count = 13, int fibres_per_side = 8);

// Hip flexion rotates femur and tibia about the hip centre (+y axis), knee flexion the tibia about the knee.
Pose syntheticThighPose(double hip_flexion_rad, double knee_flexion_rad);

}  // namespace muscle_deformation
