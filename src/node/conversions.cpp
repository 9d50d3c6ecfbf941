#include "muscle_deformation/node/conversions.hpp"

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/register_point_struct.h>
#include <pcl_conversions/pcl_conversions.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>

// A particle as a PCL point: position plus the fields rviz can colour by.
namespace muscle_deformation::node {
struct EIGEN_ALIGN16 ParticlePoint {
  PCL_ADD_POINT4D;
  float radius;
  float strain;
  std::int32_t muscle;
  std::int32_t bone;
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};
}  // namespace muscle_deformation::node

POINT_CLOUD_REGISTER_POINT_STRUCT(muscle_deformation::node::ParticlePoint,
                                  (float, x, x)(float, y, y)(float, z, z)(float, radius, radius)(float, strain, strain)
                                  (std::int32_t, muscle, muscle)(std::int32_t, bone, bone))

namespace muscle_deformation::node {
namespace {

std_msgs::ColorRGBA colourOf(const MuscleDescription& muscle, float alpha) {
  std_msgs::ColorRGBA colour;
  colour.r = muscle.colour[0];
  colour.g = muscle.colour[1];
  colour.b = muscle.colour[2];
  colour.a = alpha < 0 ? muscle.colour[3] : alpha;
  return colour;
}

// Blue (-20 % and below) -> white (0) -> red (+20 % and above).
std_msgs::ColorRGBA strainColour(double strain) {
  const float t = static_cast<float>(std::clamp(strain / 0.2, -1.0, 1.0));
  std_msgs::ColorRGBA colour;
  colour.a = 1.0f;
  colour.r = t >= 0 ? 1.0f : 1.0f + t;
  colour.g = 1.0f - std::abs(t);
  colour.b = t <= 0 ? 1.0f : 1.0f - t;
  return colour;
}

geometry_msgs::Point pointOf(const Eigen::Vector3d& p) {
  geometry_msgs::Point point;
  point.x = p.x();
  point.y = p.y();
  point.z = p.z();
  return point;
}

visualization_msgs::Marker baseMarker(const std_msgs::Header& header, const std::string& ns, int id, int type) {
  visualization_msgs::Marker marker;
  marker.header = header;
  marker.ns = ns;
  marker.id = id;
  marker.type = type;
  marker.action = visualization_msgs::Marker::ADD;
  marker.pose.orientation.w = 1.0;
  marker.scale.x = marker.scale.y = marker.scale.z = 1.0;
  return marker;
}

}  // namespace

JointValues jointValuesFromMessage(const sensor_msgs::JointState& joint_state) {
  if (joint_state.position.size() != joint_state.name.size()) {
    throw std::invalid_argument("joint_state has " + std::to_string(joint_state.name.size()) + " names but " +
                                std::to_string(joint_state.position.size()) + " positions");
  }
  JointValues values;
  for (std::size_t i = 0; i < joint_state.name.size(); ++i) {
    const std::string& name = joint_state.name[i];
    if (name.empty()) throw std::invalid_argument("joint_state.name[" + std::to_string(i) + "] is empty");
    if (!std::isfinite(joint_state.position[i])) {
      throw std::invalid_argument("joint '" + name + "' has a non-finite position (" +
                                  std::to_string(joint_state.position[i]) + ")");
    }
    if (!values.emplace(name, joint_state.position[i]).second)
      throw std::invalid_argument("joint '" + name + "' is given twice");
  }
  return values;
}

std::string jointStateProblem(const sensor_msgs::JointState& joint_state, bool& duplicate) {
  duplicate = false;
  for (std::size_t j = 0; j < joint_state.position.size(); ++j) {
    if (std::isfinite(joint_state.position[j])) continue;
    const std::string joint = j < joint_state.name.size() ? joint_state.name[j] : "#" + std::to_string(j);
    return "joint '" + joint + "' is " + std::to_string(joint_state.position[j]);
  }
  std::set<std::string> seen;
  for (const std::string& name : joint_state.name) {
    if (seen.insert(name).second) continue;
    duplicate = true;
    return "joint '" + name + "' is given twice";
  }
  return {};
}

std::string jointLimitWarnings(const Skeleton& skeleton, const sensor_msgs::JointState& joint_state) {
  JointValues values;
  for (std::size_t j = 0; j < joint_state.name.size() && j < joint_state.position.size(); ++j)
    if (skeleton.joint(joint_state.name[j])) values[joint_state.name[j]] = joint_state.position[j];
  std::vector<std::string> warnings;
  try {
    skeleton.linkPoses(values, &warnings);
  } catch (const std::exception&) {
    return {};  // nothing to say about limits; the pose itself comes through tf
  }
  std::string text;
  for (const std::string& warning : warnings) text += (text.empty() ? "" : "; ") + warning;
  return text;
}

SinglePoseRequest singlePoseRequestFromMessage(const muscle_deformation::DeformPose::Request& request,
                                               const Skeleton& skeleton, const std::string& fixed_frame,
                                               std::string& frame_id) {
  SinglePoseRequest single;
  single.muscles = request.muscles;
  single.warm_start = request.warm_start;
  single.max_iterations = request.max_iterations;
  single.displacement_tolerance_m = request.displacement_tolerance_m;
  single.time_budget_ms = request.time_budget_ms;
  if (!request.joint_state.name.empty()) {
    const JointValues values = jointValuesFromMessage(request.joint_state);
    for (const auto& [name, value] : values) {
      (void)value;
      if (!skeleton.joint(name)) throw std::invalid_argument("joint '" + name + "' is not a joint of the URDF");
    }
    single.link_poses = skeleton.linkPoses(values, &single.warnings);
    // Express the links in the fixed frame when it is a link of the skeleton (as tf would), else in the root.
    const auto fixed = single.link_poses.find(fixed_frame);
    frame_id = fixed == single.link_poses.end() ? skeleton.rootLink() : fixed_frame;
    if (fixed != single.link_poses.end()) {
      const Eigen::Isometry3d root_to_fixed = fixed->second.inverse();
      for (auto& [name, pose] : single.link_poses) pose = root_to_fixed * pose;
    }
    return single;
  }
  if (request.bone_poses.empty())
    throw std::invalid_argument(
        "the request has no pose: give joint_state (names and positions) or bone_poses (link poses)");
  frame_id = fixed_frame;
  for (std::size_t i = 0; i < request.bone_poses.size(); ++i) {
    const geometry_msgs::TransformStamped& bone = request.bone_poses[i];
    const std::string what = "bone_poses[" + std::to_string(i) + "] ('" + bone.child_frame_id + "')";
    if (!bone.header.frame_id.empty() && bone.header.frame_id != fixed_frame)
      throw std::invalid_argument(what + " is given in frame '" + bone.header.frame_id +
                                  "'; give bone poses in the node's fixed frame '" + fixed_frame + "'");
    if (!skeleton.link(bone.child_frame_id))
      throw std::invalid_argument(what + ": child_frame_id is not a link of the URDF");
    double quaternion_length = 1;
    if (!single.link_poses.emplace(bone.child_frame_id, isometryFromMessage(bone.transform, what, &quaternion_length))
             .second)
      throw std::invalid_argument(what + " is given twice");
    if (std::abs(quaternion_length - 1.0) > kUnitQuaternionTolerance)
      single.warnings.push_back(what + ": rotation quaternion of length " + std::to_string(quaternion_length) +
                                " normalised");
  }
  return single;
}

Eigen::Isometry3d rigidTransformFromMessage(const geometry_msgs::Transform& transform, double& quaternion_length) {
  const Eigen::Quaterniond rotation(transform.rotation.w, transform.rotation.x, transform.rotation.y,
                                    transform.rotation.z);
  quaternion_length = rotation.norm();
  Eigen::Isometry3d result = Eigen::Isometry3d::Identity();
  // A zero quaternion gives NaN here, which the solve refuses with a message (no rotation can be guessed).
  result.linear() = Eigen::Quaterniond(rotation.coeffs() / quaternion_length).toRotationMatrix();
  result.translation() = Eigen::Vector3d(transform.translation.x, transform.translation.y, transform.translation.z);
  return result;
}

Eigen::Isometry3d isometryFromMessage(const geometry_msgs::Transform& transform, const std::string& what,
                                      double* quaternion_length) {
  const Eigen::Vector3d translation(transform.translation.x, transform.translation.y, transform.translation.z);
  const Eigen::Quaterniond rotation(transform.rotation.w, transform.rotation.x, transform.rotation.y,
                                    transform.rotation.z);
  if (!translation.allFinite() || !rotation.coeffs().allFinite())
    throw std::invalid_argument(what + " has a non-finite value");
  const double norm = rotation.norm();
  if (norm < 0.9 || norm > 1.1) {
    throw std::invalid_argument(what + " has a rotation quaternion of length " + std::to_string(norm) +
                                " (expected a unit quaternion)");
  }
  double length = 1;
  const Eigen::Isometry3d result = rigidTransformFromMessage(transform, length);
  if (quaternion_length) *quaternion_length = length;
  return result;
}

Eigen::VectorXf particleStrains(const MassSpringSystem& system, const Eigen::Matrix3Xd& positions) {
  const Eigen::Index n = system.particleCount();
  Eigen::VectorXd sum = Eigen::VectorXd::Zero(n);
  Eigen::VectorXi count = Eigen::VectorXi::Zero(n);
  const SpringSet& springs = system.springs;
  for (std::size_t s = 0; s < springs.size(); ++s) {
    const std::int32_t a = springs.first[s], b = springs.second[s];
    const double rest = springs.rest_length[static_cast<Eigen::Index>(s)];
    const double strain = rest > 0 ? std::abs((positions.col(a) - positions.col(b)).norm() - rest) / rest : 0.0;
    sum[a] += strain;
    sum[b] += strain;
    ++count[a];
    ++count[b];
  }
  Eigen::VectorXf strain(n);
  for (Eigen::Index i = 0; i < n; ++i) strain[i] = count[i] ? static_cast<float>(sum[i] / count[i]) : 0.0f;
  return strain;
}

visualization_msgs::MarkerArray fibresToMarkers(const FrameResult& frame, const std_msgs::Header& header,
                                                bool colour_by_strain) {
  const MassSpringSystem& system = frame.particles();
  const Eigen::Matrix3Xd& positions = frame.positions();
  const std::vector<MuscleDescription>& muscles = frame.muscles();
  visualization_msgs::MarkerArray array;
  const int muscle_count = system.muscleCount();
  array.markers.reserve(static_cast<std::size_t>(muscle_count));
  for (int m = 0; m < muscle_count; ++m) {
    visualization_msgs::Marker marker = baseMarker(header, "fibres", m, visualization_msgs::Marker::LINE_LIST);
    marker.scale.x = 0.0015;  // line width, m
    marker.color = colourOf(muscles[static_cast<std::size_t>(m)], -1);
    const std::int32_t begin = system.muscle_begin[static_cast<std::size_t>(m)];
    const std::int32_t end = system.muscle_begin[static_cast<std::size_t>(m) + 1];
    for (std::int32_t i = begin; i + 1 < end; ++i) {
      const auto next = static_cast<std::size_t>(i) + 1;
      if (system.fibre_of[next] != system.fibre_of[static_cast<std::size_t>(i)]) continue;  // next fibre starts
      if (system.fibre_of[next] == kTendonAnchor) continue;  // tendons' bone ends: no fibre joins them
      marker.points.push_back(pointOf(positions.col(i)));
      marker.points.push_back(pointOf(positions.col(i + 1)));
      if (colour_by_strain) {
        const double rest = (system.rest_position.col(i + 1) - system.rest_position.col(i)).norm();
        const double now = (positions.col(i + 1) - positions.col(i)).norm();
        const std_msgs::ColorRGBA colour = strainColour(rest > 0 ? now / rest - 1.0 : 0.0);
        marker.colors.push_back(colour);
        marker.colors.push_back(colour);
      }
    }
    array.markers.push_back(std::move(marker));
  }
  return array;
}

sensor_msgs::PointCloud2 particlesToCloud(const FrameResult& frame, const std_msgs::Header& header) {
  const MassSpringSystem& system = frame.particles();
  const Eigen::Matrix3Xd& positions = frame.positions();
  const Eigen::VectorXf strain = particleStrains(system, positions);
  pcl::PointCloud<ParticlePoint> cloud;
  cloud.resize(static_cast<std::size_t>(system.particleCount()));
  for (Eigen::Index i = 0; i < system.particleCount(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    ParticlePoint& point = cloud[k];
    point.x = static_cast<float>(positions(0, i));
    point.y = static_cast<float>(positions(1, i));
    point.z = static_cast<float>(positions(2, i));
    point.radius = static_cast<float>(system.radius[i]);
    point.strain = strain[i];
    point.muscle = system.muscle_of[k];
    point.bone = system.is_fixed[k] ? system.fixed_bone[k] : -1;
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  cloud.height = 1;
  cloud.is_dense = positions.allFinite();
  sensor_msgs::PointCloud2 message;
  pcl::toROSMsg(cloud, message);
  message.header = header;
  return message;
}

muscle_deformation::MuscleSurfaces surfacesToMessage(const FrameResult& frame, const std_msgs::Header& header) {
  muscle_deformation::MuscleSurfaces message;
  message.header = header;
  if (!frame.has_surfaces) return message;
  const std::vector<Vertices>& surfaces = frame.surfaces;
  const std::vector<MuscleDescription>& muscles = frame.muscles();
  message.muscles.resize(surfaces.size());
  for (std::size_t m = 0; m < surfaces.size(); ++m) {
    muscle_deformation::MuscleSurface& out = message.muscles[m];
    out.name = muscles[m].name;
    out.color = colourOf(muscles[m], -1);
    const Vertices& vertices = surfaces[m];
    out.mesh.vertices.resize(static_cast<std::size_t>(vertices.cols()));
    for (Eigen::Index v = 0; v < vertices.cols(); ++v)
      out.mesh.vertices[static_cast<std::size_t>(v)] = pointOf(vertices.col(v));
    const Triangles& triangles = frame.surfaceTriangles(m);
    out.mesh.triangles.resize(static_cast<std::size_t>(triangles.cols()));
    for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
      for (int c = 0; c < 3; ++c)
        out.mesh.triangles[static_cast<std::size_t>(t)].vertex_indices[static_cast<std::size_t>(c)] =
            static_cast<std::uint32_t>(triangles(c, t));
    }
  }
  return message;
}

visualization_msgs::MarkerArray surfacesToMarkers(const FrameResult& frame, const std_msgs::Header& header,
                                                  float alpha) {
  visualization_msgs::MarkerArray array;
  if (!frame.has_surfaces) return array;
  const std::vector<Vertices>& surfaces = frame.surfaces;
  const std::vector<MuscleDescription>& muscles = frame.muscles();
  for (std::size_t m = 0; m < surfaces.size(); ++m) {
    visualization_msgs::Marker marker =
        baseMarker(header, "surfaces", static_cast<int>(m), visualization_msgs::Marker::TRIANGLE_LIST);
    marker.color = colourOf(muscles[m], alpha);
    const Triangles& triangles = frame.surfaceTriangles(m);
    marker.points.reserve(static_cast<std::size_t>(triangles.size()));
    for (Eigen::Index t = 0; t < triangles.cols(); ++t)
      for (int c = 0; c < 3; ++c) marker.points.push_back(pointOf(surfaces[m].col(triangles(c, t))));
    array.markers.push_back(std::move(marker));
  }
  return array;
}

visualization_msgs::MarkerArray bonesToMarkers(const std::vector<Bone>& bones,
                                               const std::map<std::string, Eigen::Isometry3d>& rest_link_poses) {
  visualization_msgs::MarkerArray array;
  for (std::size_t b = 0; b < bones.size(); ++b) {
    const auto rest = rest_link_poses.find(bones[b].name);
    if (rest == rest_link_poses.end()) continue;  // not a link: nothing to hang it on
    std_msgs::Header header;
    header.frame_id = bones[b].name;
    visualization_msgs::Marker marker =
        baseMarker(header, "bones", static_cast<int>(b), visualization_msgs::Marker::TRIANGLE_LIST);
    marker.frame_locked = true;
    marker.color.r = kBoneColour[0];
    marker.color.g = kBoneColour[1];
    marker.color.b = kBoneColour[2];
    marker.color.a = kBoneColour[3];
    const Eigen::Isometry3d to_link = rest->second.inverse();
    const TriangleMesh& surface = bones[b].surface;
    marker.points.reserve(static_cast<std::size_t>(surface.triangles.size()));
    for (Eigen::Index t = 0; t < surface.triangleCount(); ++t)
      for (int c = 0; c < 3; ++c) marker.points.push_back(pointOf(to_link * surface.vertices.col(surface.triangles(c, t))));
    array.markers.push_back(std::move(marker));
  }
  return array;
}

muscle_deformation::DeformationStats statsToMessage(const FrameResult& frame, const std_msgs::Header& header) {
  muscle_deformation::DeformationStats stats;
  stats.header = header;
  const SolveStats& solve = frame.stats.solver;
  stats.iterations = solve.iterations;
  stats.converged = solve.converged;
  constexpr double kAbsent = std::numeric_limits<double>::quiet_NaN();
  stats.has_residual = solve.residual >= 0;
  stats.force_residual = stats.has_residual ? solve.residual : kAbsent;
  if (!stats.has_residual)
    stats.residual_absent_reason = frame.residual_absent_reason.empty() ? "not measured" : frame.residual_absent_reason;
  stats.time_limit_reached = solve.time_limit_reached;
  stats.warm_started = frame.stats.warm_started;
  stats.finite = frame.stats.finite;
  stats.divergence_recoveries = static_cast<std::uint32_t>(solve.divergence_recoveries);
  stats.diverged = solve.diverged;
  stats.time_step_s = solve.time_step_s;
  stats.mss_ms = solve.mss_ms;
  stats.collision_ms = solve.collision_ms;
  stats.skinning_ms = frame.skinning_ms;
  stats.metrics_ms = frame.metrics_ms;
  stats.solve_ms = frame.stats.solve_ms;
  stats.preparation_ms = frame.stats.preparation_ms;
  stats.solver_ms = solve.total_ms;
  stats.total_ms = frame.stats.solve_ms + frame.skinning_ms + frame.metrics_ms;
  stats.spring_deviation_ratio = solve.spring_deviation_ratio;
  stats.mean_strain = solve.mean_strain;
  stats.max_strain = solve.max_strain;
  stats.strain_p99 = solve.strain_p99;
  const CollisionStats& collision = frame.stats.collision;
  stats.has_collision_metrics = frame.stats.has_collision;
  if (stats.has_collision_metrics) {
    stats.contacts = collision.contacts;
    stats.max_penetration_sphere_bone_m = collision.max_penetration_muscle_bone_m;
    stats.max_penetration_sphere_muscle_m = collision.max_penetration_muscle_muscle_m;
  } else {
    stats.collision_absent_reason =
        frame.collision_absent_reason.empty() ? "not measured" : frame.collision_absent_reason;
    stats.contacts = -1;
    stats.max_penetration_sphere_bone_m = stats.max_penetration_sphere_muscle_m = kAbsent;
  }
  stats.has_surface_metrics = frame.has_metrics;
  if (frame.has_metrics) {
    const SceneMetrics& metrics = frame.metrics;
    stats.volume_error_mean_pct = metrics.volume_error_mean_pct;
    stats.volume_error_max_pct = metrics.volume_error_max_pct;
    double worst = -1;
    for (const MuscleMetrics& m : metrics.muscles) {
      if (std::abs(m.volume_error_pct) > worst) {
        worst = std::abs(m.volume_error_pct);
        stats.volume_error_max_muscle = m.name;
      }
    }
    stats.surface_vertices_inside_bone = metrics.vertices_inside_bone;
    stats.max_surface_inside_bone_m = metrics.max_inside_bone_depth_m;
    double deepest = 0;
    for (const MuscleMetrics& m : metrics.muscles) {
      if (m.vertices_inside_bone > 0 && m.max_inside_bone_depth_m >= deepest) {
        deepest = m.max_inside_bone_depth_m;
        stats.max_surface_inside_bone_muscle = m.name;
        stats.max_surface_inside_bone_bone = m.deepest_bone;
      }
    }
    stats.particles_inside_bone = metrics.particles_inside_bone;
    stats.max_particle_inside_bone_m = metrics.max_particle_inside_bone_depth_m;
    double deepest_particle = 0;
    for (const MuscleMetrics& m : metrics.muscles) {
      if (m.particles_inside_bone > 0 && m.max_particle_inside_bone_depth_m >= deepest_particle) {
        deepest_particle = m.max_particle_inside_bone_depth_m;
        stats.max_particle_inside_bone_muscle = m.name;
        stats.max_particle_inside_bone_bone = m.deepest_particle_bone;
      }
    }
    const bool corrected = frame.volume_corrections.size() == metrics.muscles.size();
    const bool contacted = frame.bone_corrections.size() == metrics.muscles.size();
    for (std::size_t m = 0; m < metrics.muscles.size(); ++m) {
      const MuscleMetrics& muscle = metrics.muscles[m];
      stats.muscle_names.push_back(muscle.name);
      stats.muscle_volume_error_pct.push_back(muscle.volume_error_pct);
      stats.muscle_skinned_volume_error_pct.push_back(
          corrected ? frame.volume_corrections[m].volume_error_before_pct : muscle.volume_error_pct);
      stats.muscle_max_surface_inside_bone_m.push_back(muscle.max_inside_bone_depth_m);
      stats.muscle_skinned_max_surface_inside_bone_m.push_back(
          contacted ? std::max(frame.bone_corrections[m].max_depth_before_m, muscle.max_inside_bone_depth_m)
                    : muscle.max_inside_bone_depth_m);
      stats.muscle_max_particle_inside_bone_m.push_back(muscle.max_particle_inside_bone_depth_m);
      stats.muscle_projection_offset_mean_m.push_back(corrected ? frame.volume_corrections[m].mean_offset_m : 0.0);
      stats.muscle_projection_offset_max_m.push_back(corrected ? frame.volume_corrections[m].max_offset_m : 0.0);
    }
  } else {
    stats.surface_metrics_absent_reason =
        frame.metrics_absent_reason.empty() ? "not measured" : frame.metrics_absent_reason;
    stats.volume_error_mean_pct = stats.volume_error_max_pct = kAbsent;
    stats.surface_vertices_inside_bone = -1;
    stats.max_surface_inside_bone_m = kAbsent;
    stats.particles_inside_bone = -1;
    stats.max_particle_inside_bone_m = kAbsent;
  }
  return stats;
}

std::vector<AbsentMetric> absentStatsFigures(const DeformationPipeline& stream, bool stats_metrics) {
  std::vector<AbsentMetric> absent = stream.absentMetrics();
  if (stream.metrics() && !stats_metrics)
    absent.push_back({kFidelityFigures,
                      "stats_metrics is false", "set stats_metrics: true", true});
  return absent;
}

}  // namespace muscle_deformation::node
