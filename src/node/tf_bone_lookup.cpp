#include "muscle_deformation/node/tf_bone_lookup.hpp"

#include "muscle_deformation/node/conversions.hpp"

#include <ros/ros.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace muscle_deformation::node {

TfBoneLookup::TfBoneLookup(tf2_ros::Buffer& buffer, const Skeleton& skeleton, std::vector<std::string> bone_links,
                           std::string fixed_frame)
    : buffer_(buffer), fixed_frame_(std::move(fixed_frame)), bone_links_(std::move(bone_links)) {
  fixed_is_link_ = skeleton.link(fixed_frame_) != nullptr;
  std::map<std::string, std::size_t> edge_of_child;
  // The links from the root down to `link`, as edge indices.
  const auto chainTo = [&](const std::string& link) {
    std::vector<std::string> path;
    for (const SkeletonLink* l = skeleton.link(link); l && !l->parent_link.empty(); l = skeleton.link(l->parent_link))
      path.push_back(l->name);
    std::reverse(path.begin(), path.end());
    std::vector<std::size_t> chain;
    for (const std::string& child : path) {
      auto found = edge_of_child.find(child);
      if (found == edge_of_child.end()) {
        edges_.push_back({skeleton.link(child)->parent_link, child});
        found = edge_of_child.emplace(child, edges_.size() - 1).first;
      }
      chain.push_back(found->second);
    }
    return chain;
  };
  if (fixed_is_link_) fixed_chain_ = chainTo(fixed_frame_);
  for (const std::string& link : bone_links_) chains_[link] = chainTo(link);
  // A skeleton without the fixed frame among its links: its root is looked up in the fixed frame, then the chains.
  if (!fixed_is_link_) edges_.push_back({fixed_frame_, skeleton.rootLink()});
}

namespace {
// `transform` as a rigid transform; a quaternion off unit length is normalised and noted in `warnings`.
Eigen::Isometry3d normalised(const geometry_msgs::TransformStamped& transform, std::vector<std::string>& warnings) {
  double quaternion_length = 1;
  const Eigen::Isometry3d rigid = rigidTransformFromMessage(transform.transform, quaternion_length);
  if (std::abs(quaternion_length - 1.0) > kUnitQuaternionTolerance) {
    std::ostringstream warning;
    warning << "the transform of '" << transform.child_frame_id << "' in '" << transform.header.frame_id << "' at "
            << transform.header.stamp << " has a rotation quaternion of length " << quaternion_length
            << "; normalised";
    warnings.push_back(warning.str());
  }
  return rigid;
}
}  // namespace

bool TfBoneLookup::tryDirectLookup(const ros::Time& stamp, Result& result, std::string& error) const {
  for (const std::string& link : bone_links_) {
    std::string why;
    if (!buffer_.canTransform(fixed_frame_, link, stamp, &why)) {
      error = "no transform from '" + link + "' to '" + fixed_frame_ + "': " + why;
      return false;
    }
    try {
      result.link_poses[link] = normalised(buffer_.lookupTransform(fixed_frame_, link, stamp), result.warnings);
    } catch (const tf2::TransformException& e) {
      error = e.what();
      return false;
    }
  }
  return true;
}

bool TfBoneLookup::tryLookup(const ros::Time& stamp, Result& result, std::string& error) const {
  std::vector<Eigen::Isometry3d> edge_transforms(edges_.size());
  for (std::size_t e = 0; e < edges_.size(); ++e) {
    const Edge& edge = edges_[e];
    std::string why;
    if (!buffer_.canTransform(edge.parent, edge.child, stamp, &why)) {
      error = "no transform from '" + edge.child + "' to '" + edge.parent + "': " + why;
      return false;
    }
    try {
      edge_transforms[e] = normalised(buffer_.lookupTransform(edge.parent, edge.child, stamp), result.warnings);
    } catch (const tf2::TransformException& e) {
      error = e.what();
      return false;
    }
  }
  const auto compose = [&](const std::vector<std::size_t>& chain) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    for (const std::size_t e : chain) pose = pose * edge_transforms[e];
    return pose;
  };
  // Root in the fixed frame: the inverse of the fixed frame's chain, or the edge looked up directly.
  const Eigen::Isometry3d root_in_fixed =
      fixed_is_link_ ? Eigen::Isometry3d(compose(fixed_chain_).inverse()) : edge_transforms.back();
  for (const std::string& link : bone_links_) result.link_poses[link] = root_in_fixed * compose(chains_.at(link));
  return true;
}

bool TfBoneLookup::clearDataAheadOf(const ros::Time& stamp, double tolerance_s) {
  ros::Time newest;
  for (const std::string& link : bone_links_) {
    try {
      newest = std::max(newest, buffer_.lookupTransform(fixed_frame_, link, ros::Time(0)).header.stamp);
    } catch (const tf2::TransformException&) {
      // no transform of this bone at all: nothing newer either
    }
  }
  if (newest <= stamp + ros::Duration(tolerance_s)) return false;
  buffer_.clear();
  return true;
}

bool TfBoneLookup::lookup(const ros::Time& stamp, double wait_s, const std::function<bool()>& give_up,
                          Result& result) const {
  result = Result();
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(wait_s);
  while (true) {
    std::string error, direct_error;
    if (tryLookup(stamp, result, error)) return true;
    result.warnings.clear();
    // A tf tree without the URDF's joints as frames (transforms published straight from the fixed frame to the bones):
    // each bone as tf composes it, its own rotation normalised.
    if (tryDirectLookup(stamp, result, direct_error)) return true;
    result.warnings.clear();
    if (give_up && give_up()) {
      result.error = "transforms not available before a newer pose arrived (" + error + ")";
      return false;
    }
    if (ros::WallTime::now() > deadline) {
      result.error = "transforms not available within tf_wait_s = " + std::to_string(wait_s) + " s (" + error + ")";
      return false;
    }
    ros::WallDuration(0.001).sleep();
  }
}

}  // namespace muscle_deformation::node
