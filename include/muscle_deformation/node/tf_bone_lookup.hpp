// The bones of a pose from tf: every simulated bone's link in the fixed frame at a stamp. Each joint of the URDF's chain
// from the fixed frame to a bone is looked up on its own and its rotation normalised before the chain is composed:
// tf2 composes quaternions as they arrive, and one a little off unit length (|q|^2 = 1.009) stretches every
// translation below it, so a tibia would sit millimetres off its femur although each bone stayed rigid. A tf tree
// without the URDF's joints as frames is read bone by bone as tf composes it.
#pragma once

#include "muscle_deformation/core/scene/skeleton.hpp"

#include <ros/time.h>
#include <tf2_ros/buffer.h>

#include <Eigen/Geometry>

#include <functional>
#include <map>
#include <string>
#include <vector>

namespace muscle_deformation::node {

class TfBoneLookup {
 public:
  // `bone_links`: the links of the simulated bones. The chain of each is taken from `skeleton` (links between the
  // fixed frame, when it is a link of the skeleton, or else its root, and the bone). `buffer` must outlive the lookup.
  TfBoneLookup(tf2_ros::Buffer& buffer, const Skeleton& skeleton, std::vector<std::string> bone_links,
               std::string fixed_frame);

  struct Result {
    std::map<std::string, Eigen::Isometry3d> link_poses;  // every bone link in the fixed frame
    std::string error;                                    // why not, when lookup() returns false
    std::vector<std::string> warnings;                    // quaternions normalised (link, length)
  };
  // Waits (wall time, up to `wait_s`, or until `give_up` says so: a newer pose arrived, shutdown) until every bone's
  // transform at `stamp` is available. False, with `error` naming the missing transform, if they did not all arrive.
  bool lookup(const ros::Time& stamp, double wait_s, const std::function<bool()>& give_up, Result& result) const;
  // Clears tf's buffer when it holds transforms of the bones more than `tolerance_s` newer than `stamp` (a buffer
  // that does has dropped that pose's transforms as old, and drops every later one stamped on time); true if it did.
  bool clearDataAheadOf(const ros::Time& stamp, double tolerance_s);

 private:
  // One edge of a chain: the transform from `parent` to `child` (a URDF joint), or from the fixed frame to the root.
  struct Edge {
    std::string parent, child;
  };
  // False with `error` when an edge is not available (yet).
  bool tryLookup(const ros::Time& stamp, Result& result, std::string& error) const;
  // Each bone straight from the fixed frame (for a tf tree that lacks the URDF's intermediate frames).
  bool tryDirectLookup(const ros::Time& stamp, Result& result, std::string& error) const;

  tf2_ros::Buffer& buffer_;
  std::string fixed_frame_;
  std::vector<std::string> bone_links_;
  std::vector<Edge> edges_;  // every edge below the fixed frame's common root once, parents before children
  // Per bone link: the indices into edges_ from the root down to it.
  std::map<std::string, std::vector<std::size_t>> chains_;
  // The fixed frame's own chain from the root (empty when it is the root or not a link of the skeleton: then the root
  // is looked up in the fixed frame directly).
  std::vector<std::size_t> fixed_chain_;
  bool fixed_is_link_ = false;
};

}  // namespace muscle_deformation::node
