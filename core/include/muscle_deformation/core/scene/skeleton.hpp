// The skeleton from a URDF (urdfdom): links, joints, their collision meshes, and forward kinematics.
#pragma once

#include <Eigen/Geometry>

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// Any problem with the scene files: the message names the file (and line where known) and what is wrong.
class SceneError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CollisionMeshRef {
  std::string uri;                                               // as written in the URDF
  Eigen::Vector3d scale = Eigen::Vector3d::Ones();               // <mesh scale="...">
  Eigen::Isometry3d origin = Eigen::Isometry3d::Identity();      // <collision><origin>, in the link frame
};

struct SkeletonLink {
  std::string name;
  std::string parent_link;   // empty for the root
  std::string parent_joint;  // empty for the root
  std::vector<CollisionMeshRef> collision_meshes;
};

struct SkeletonJoint {
  std::string name;
  std::string type;  // revolute, continuous, prismatic, fixed, floating, planar
  std::string parent_link, child_link;
  Eigen::Isometry3d origin = Eigen::Isometry3d::Identity();  // parent link frame -> joint frame at zero
  Eigen::Vector3d axis = Eigen::Vector3d::UnitX();           // unit, in the joint frame
  double lower = 0, upper = 0;                               // limits (rad or m); equal = no limit given
  // <mimic>: value = multiplier * value(mimicked) + offset
  std::string mimic_joint;
  double mimic_multiplier = 1, mimic_offset = 0;
};

using JointValues = std::map<std::string, double>;  // joint name -> position (rad or m); missing joints are 0

class Skeleton {
 public:
  // Parses URDF XML (urdfdom). Throws SceneError naming `source_name` (a file path or "robot_description").
  static Skeleton fromUrdfString(const std::string& xml, const std::string& source_name);
  static Skeleton fromUrdfFile(const std::string& path);

  const std::string& source() const { return source_; }  // the source_name it was parsed from
  const std::string& rootLink() const { return root_; }
  const std::vector<SkeletonLink>& links() const { return links_; }
  const std::vector<SkeletonJoint>& joints() const { return joints_; }
  const SkeletonLink* link(const std::string& name) const;
  const SkeletonJoint* joint(const std::string& name) const;
  // Names of the joints a pose sets, in URDF order: neither fixed nor mimicking another joint (a mimic joint
  // follows the joint it mimics, as the patella's slide follows the knee, and a value given to it is ignored).
  std::vector<std::string> movableJointNames() const;

  // Forward kinematics: every link's pose in the root frame. Throws SceneError for an unknown joint name or a
  // non-finite value; a value outside the joint's limits is accepted (the skeleton has no actuators) but reported in
  // `warnings` if given.
  std::map<std::string, Eigen::Isometry3d> linkPoses(const JointValues& values,
                                                     std::vector<std::string>* warnings = nullptr) const;

 private:
  std::string source_;
  std::string root_;
  std::vector<SkeletonLink> links_;
  std::vector<SkeletonJoint> joints_;
};

// How the link names of two skeletons differ (e.g. the URDF file a scene was made for and the robot_description a
// node was given): empty when both have the same links, otherwise one sentence naming the links only one of them has
// (at most 10 of each, then a count).
std::string describeLinkDifferences(const Skeleton& a, const Skeleton& b);

}  // namespace muscle_deformation
