// The one place where core types meet ROS messages (as grid_map's GridMapRosConverter): free functions, no state.
#pragma once

#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/core/surfaces/surface_skinning.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/single_pose_session.hpp"

#include <muscle_deformation/DeformPose.h>
#include <muscle_deformation/DeformationStats.h>
#include <muscle_deformation/MuscleSurfaces.h>

#include <geometry_msgs/Transform.h>
#include <sensor_msgs/JointState.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>
#include <visualization_msgs/MarkerArray.h>

#include <Eigen/Geometry>

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation::node {

// ----- messages -> core (throw std::invalid_argument with a message naming the bad field) -----

// Joint names -> positions. Rejects mismatched name/position counts, empty or repeated names and non-finite values.
JointValues jointValuesFromMessage(const sensor_msgs::JointState& joint_state);

// A quaternion whose length differs from 1 by more than this is worth a warning when it is normalised.
constexpr double kUnitQuaternionTolerance = 1e-6;

// A rigid transform whatever the message holds: the rotation quaternion is normalised (tf2 accepts quaternions a
// little off unit length, and using one as it is scales and shears the bone). `quaternion_length` receives the length
// it had. Non-finite values give a non-finite result; callers check.
Eigen::Isometry3d rigidTransformFromMessage(const geometry_msgs::Transform& transform, double& quaternion_length);

// A rigid transform; rejects non-finite values and quaternions far from unit length (|q| outside [0.9, 1.1]), and
// normalises the others (their length before in `quaternion_length`, if given). `what` names the field in the error.
Eigen::Isometry3d isometryFromMessage(const geometry_msgs::Transform& transform, const std::string& what,
                                      double* quaternion_length = nullptr);

// Why a /joint_states message cannot be a pose of the stream, by the service's rule (a non-finite position, a joint
// named twice): empty when it can. `duplicate` tells which of the two it is.
std::string jointStateProblem(const sensor_msgs::JointState& joint_state, bool& duplicate);

// The joints of `joint_state` outside their URDF limits, as one line (empty: none, or nothing to say).
std::string jointLimitWarnings(const Skeleton& skeleton, const sensor_msgs::JointState& joint_state);

// A ~deform_pose request as the single-pose session takes it: the pose (joint_state through the skeleton's forward
// kinematics, expressed in `fixed_frame` when it is a link of the skeleton, else in the root; or bone_poses, which
// must be given in `fixed_frame`), the muscles, limits and warm start. `frame_id` receives the frame the answer is
// in. Throws std::invalid_argument naming the field of a bad request (unknown joint or link, no pose, a link given
// twice, a non-finite or far from unit transform).
SinglePoseRequest singlePoseRequestFromMessage(const muscle_deformation::DeformPose::Request& request,
                                               const Skeleton& skeleton, const std::string& fixed_frame,
                                               std::string& frame_id);

// ----- core -> messages -----

// Per particle: mean |l - l0| / l0 over its springs (0 for a particle without springs).
Eigen::VectorXf particleStrains(const MassSpringSystem& system, const Eigen::Matrix3Xd& positions);

// Per muscle one LINE_LIST marker (namespace "fibres", id = muscle index) joining consecutive particles of each
// fibre. Colour: the muscle's scene colour, or, with `colour_by_strain`, each segment from blue (shortened by 20 %
// or more) through white (rest length) to red (stretched by 20 % or more).
visualization_msgs::MarkerArray fibresToMarkers(const FrameResult& frame, const std_msgs::Header& header,
                                                bool colour_by_strain);

// PointCloud2 built with PCL, one point per particle: x y z (float32, m), radius (float32, m, collision sphere, 0 for
// interior particles), strain (float32, see particleStrains), muscle (int32, muscle index), bone (int32: the bone a
// fixed particle is attached to, -1 for free particles).
sensor_msgs::PointCloud2 particlesToCloud(const FrameResult& frame, const std_msgs::Header& header);

// Deformed surfaces (the frame's, when it has_surfaces; none otherwise), per muscle its name, colour and
// shape_msgs/Mesh.
muscle_deformation::MuscleSurfaces surfacesToMessage(const FrameResult& frame, const std_msgs::Header& header);

// The same surfaces as TRIANGLE_LIST markers (namespace "surfaces", id = muscle index) for rviz.
visualization_msgs::MarkerArray surfacesToMarkers(const FrameResult& frame, const std_msgs::Header& header,
                                                  float alpha);

// The colour bones are drawn in (ivory): apart from the muscles' colours, whatever the URDF's materials say.
constexpr float kBoneColour[4] = {0.92f, 0.88f, 0.78f, 1.0f};

// The bones as TRIANGLE_LIST markers (namespace "bones", id = bone index) in kBoneColour, each in its own link's frame
// (`rest_link_poses`: the links at rest in the scene frame the bone surfaces are given in) and frame_locked with stamp
// 0, so that rviz moves them with the newest tf: published once, they follow the skeleton.
visualization_msgs::MarkerArray bonesToMarkers(const std::vector<Bone>& bones,
                                               const std::map<std::string, Eigen::Isometry3d>& rest_link_poses);

// Per-frame statistics (the running counters are left at 0 for the caller to fill). `converged` is true only when a
// convergence criterion was met (SolveStats::converged), never for running out of iterations or time. A figure the
// frame does not have (residual, collision, surface metrics) is NaN (a count -1) with its has_* flag false and the
// frame's reason, never 0.
muscle_deformation::DeformationStats statsToMessage(const FrameResult& frame, const std_msgs::Header& header);

// The ~stats figures the node's stream never measures, as set up: the pipeline's (DeformationPipeline::absentMetrics)
// and the surface metrics when ~stats_metrics is false; each with the reason and how to turn it on.
std::vector<AbsentMetric> absentStatsFigures(const DeformationPipeline& stream, bool stats_metrics);

}  // namespace muscle_deformation::node
