// The skeleton half of scene loading: URDF parsing (urdfdom) and forward kinematics.
#include "muscle_deformation/core/scene/skeleton.hpp"

#include <urdf_parser/urdf_parser.h>

#include <cctype>
#include <cmath>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>
#include <utility>

namespace muscle_deformation {

namespace {

Eigen::Isometry3d toIsometry(const urdf::Pose& pose) {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.translation() = Eigen::Vector3d(pose.position.x, pose.position.y, pose.position.z);
  const Eigen::Quaterniond q(pose.rotation.w, pose.rotation.x, pose.rotation.y, pose.rotation.z);
  out.linear() = q.normalized().toRotationMatrix();
  return out;
}

const char* typeName(int type) {
  switch (type) {
    case urdf::Joint::REVOLUTE: return "revolute";
    case urdf::Joint::CONTINUOUS: return "continuous";
    case urdf::Joint::PRISMATIC: return "prismatic";
    case urdf::Joint::FLOATING: return "floating";
    case urdf::Joint::PLANAR: return "planar";
    case urdf::Joint::FIXED: return "fixed";
    default: return "unknown";
  }
}

// The `name` attributes of every <tag ...> element, in document order, comments removed. urdfdom keeps links and joints
// in name-sorted maps, but users (and the gait bags) expect the order they wrote, e.g. for JointState names.
std::vector<std::string> elementNamesInOrder(const std::string& xml, const std::string& tag) {
  std::string text;
  text.reserve(xml.size());
  for (std::size_t at = 0; at < xml.size();) {
    const std::size_t open = xml.find("<!--", at);
    if (open == std::string::npos) {
      text.append(xml, at, std::string::npos);
      break;
    }
    text.append(xml, at, open - at);
    const std::size_t close = xml.find("-->", open + 4);
    if (close == std::string::npos) break;
    at = close + 3;
  }
  std::vector<std::string> names;
  std::set<std::string> seen;
  const std::string opening = "<" + tag;
  for (std::size_t at = text.find(opening); at != std::string::npos; at = text.find(opening, at + 1)) {
    const std::size_t after = at + opening.size();
    if (after >= text.size() || !std::isspace(static_cast<unsigned char>(text[after]))) continue;  // e.g. <linkage
    const std::size_t end = text.find('>', after);
    if (end == std::string::npos) break;
    const std::string element = text.substr(after, end - after);
    // Find name="..." or name='...' as a whole attribute (not e.g. "filename=").
    for (std::size_t n = element.find("name"); n != std::string::npos; n = element.find("name", n + 1)) {
      if (n > 0 && !std::isspace(static_cast<unsigned char>(element[n - 1]))) continue;
      std::size_t eq = n + 4;
      while (eq < element.size() && std::isspace(static_cast<unsigned char>(element[eq]))) ++eq;
      if (eq >= element.size() || element[eq] != '=') continue;
      std::size_t quote = eq + 1;
      while (quote < element.size() && std::isspace(static_cast<unsigned char>(element[quote]))) ++quote;
      if (quote >= element.size() || (element[quote] != '"' && element[quote] != '\'')) continue;
      const std::size_t close = element.find(element[quote], quote + 1);
      if (close == std::string::npos) break;
      const std::string name = element.substr(quote + 1, close - quote - 1);
      if (seen.insert(name).second) names.push_back(name);
      break;
    }
  }
  return names;
}

}  // namespace

Skeleton Skeleton::fromUrdfString(const std::string& xml, const std::string& source_name) {
  urdf::ModelInterfaceSharedPtr model;
  try {
    model = urdf::parseURDF(xml);
  } catch (const std::exception& e) {
    throw SceneError(source_name + ": not a valid URDF: " + e.what());
  }
  if (!model || !model->getRoot()) {
    throw SceneError(source_name +
                     ": not a valid URDF (urdfdom could not parse it; its console output above says why)");
  }

  Skeleton skeleton;
  skeleton.source_ = source_name;
  skeleton.root_ = model->getRoot()->name;

  // Document order first, then anything urdfdom knows that the text scan missed (it cannot miss a real element,
  // but stay correct if it does).
  std::vector<std::string> link_order = elementNamesInOrder(xml, "link");
  std::vector<std::string> joint_order = elementNamesInOrder(xml, "joint");
  std::vector<urdf::LinkSharedPtr> all_links;
  model->getLinks(all_links);
  std::set<std::string> listed(link_order.begin(), link_order.end());
  for (const auto& link : all_links)
    if (!listed.count(link->name)) link_order.push_back(link->name);
  listed = std::set<std::string>(joint_order.begin(), joint_order.end());
  for (const auto& entry : model->joints_)
    if (!listed.count(entry.first)) joint_order.push_back(entry.first);

  for (const std::string& name : link_order) {
    const urdf::LinkConstSharedPtr link = model->getLink(name);
    if (!link) continue;  // a <link name=...> inside something else (e.g. a transmission): not a link
    SkeletonLink out;
    out.name = name;
    if (link->parent_joint) {
      out.parent_joint = link->parent_joint->name;
      out.parent_link = link->parent_joint->parent_link_name;
    }
    std::vector<urdf::CollisionSharedPtr> collisions = link->collision_array;
    if (collisions.empty() && link->collision) collisions.push_back(link->collision);
    for (const auto& collision : collisions) {
      if (!collision || !collision->geometry || collision->geometry->type != urdf::Geometry::MESH) continue;
      const auto* mesh = dynamic_cast<const urdf::Mesh*>(collision->geometry.get());
      if (!mesh) continue;
      CollisionMeshRef ref;
      ref.uri = mesh->filename;
      ref.scale = Eigen::Vector3d(mesh->scale.x, mesh->scale.y, mesh->scale.z);
      ref.origin = toIsometry(collision->origin);
      if (!ref.scale.allFinite() || (ref.scale.array() == 0.0).any()) {
        throw SceneError(source_name + ": link '" + name + "' mesh '" + ref.uri + "' has a zero or invalid scale");
      }
      out.collision_meshes.push_back(ref);
    }
    skeleton.links_.push_back(std::move(out));
  }

  for (const std::string& name : joint_order) {
    const urdf::JointConstSharedPtr joint = model->getJoint(name);
    if (!joint) continue;
    SkeletonJoint out;
    out.name = name;
    out.type = typeName(joint->type);
    if (out.type == std::string("unknown")) throw SceneError(source_name + ": joint '" + name + "' has an unknown type");
    out.parent_link = joint->parent_link_name;
    out.child_link = joint->child_link_name;
    out.origin = toIsometry(joint->parent_to_joint_origin_transform);
    const Eigen::Vector3d axis(joint->axis.x, joint->axis.y, joint->axis.z);
    const bool needs_axis = out.type == "revolute" || out.type == "continuous" || out.type == "prismatic";
    if (needs_axis && !(axis.norm() > 1e-12)) {
      throw SceneError(source_name + ": joint '" + name + "' has a zero axis");
    }
    if (axis.norm() > 1e-12) out.axis = axis.normalized();
    if (joint->limits && out.type != "continuous") {
      out.lower = joint->limits->lower;
      out.upper = joint->limits->upper;
    }
    if (joint->mimic) {
      out.mimic_joint = joint->mimic->joint_name;
      out.mimic_multiplier = joint->mimic->multiplier;
      out.mimic_offset = joint->mimic->offset;
      if (!model->getJoint(out.mimic_joint)) {
        throw SceneError(source_name + ": joint '" + name + "' mimics unknown joint '" + out.mimic_joint + "'");
      }
    }
    skeleton.joints_.push_back(std::move(out));
  }

  // Mimic chains must end: a cycle would make every joint of it undefined.
  for (const SkeletonJoint& joint : skeleton.joints_) {
    std::set<std::string> visited{joint.name};
    for (const SkeletonJoint* j = &joint; !j->mimic_joint.empty();) {
      j = skeleton.joint(j->mimic_joint);
      if (!visited.insert(j->name).second) {
        throw SceneError(source_name + ": joint '" + joint.name + "' is part of a mimic cycle");
      }
    }
  }
  return skeleton;
}

Skeleton Skeleton::fromUrdfFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw SceneError(path + ": cannot open the URDF file");
  std::stringstream text;
  text << in.rdbuf();
  return fromUrdfString(text.str(), path);
}

const SkeletonLink* Skeleton::link(const std::string& name) const {
  for (const auto& l : links_)
    if (l.name == name) return &l;
  return nullptr;
}

const SkeletonJoint* Skeleton::joint(const std::string& name) const {
  for (const auto& j : joints_)
    if (j.name == name) return &j;
  return nullptr;
}

std::vector<std::string> Skeleton::movableJointNames() const {
  std::vector<std::string> names;
  for (const auto& j : joints_)
    if (j.type != "fixed" && j.mimic_joint.empty()) names.push_back(j.name);
  return names;
}

std::map<std::string, Eigen::Isometry3d> Skeleton::linkPoses(const JointValues& values,
                                                             std::vector<std::string>* warnings) const {
  auto warn = [&](const std::string& text) {
    if (warnings) warnings->push_back(text);
  };
  for (const auto& [name, value] : values) {
    const SkeletonJoint* j = joint(name);
    if (!j) throw SceneError("joint values: unknown joint '" + name + "'");
    if (!std::isfinite(value)) {
      std::ostringstream msg;
      msg << "joint values: joint '" << name << "' has a non-finite value (" << value << ")";
      throw SceneError(msg.str());
    }
    if (j->type == "fixed" || j->type == "floating" || j->type == "planar") {
      if (value != 0.0) warn("joint '" + name + "' is " + j->type + ": its value is ignored (held at zero)");
    } else if (!j->mimic_joint.empty()) {
      warn("joint '" + name + "' mimics '" + j->mimic_joint + "': its own value is ignored");
    }
  }

  // Effective value of each joint: its own, or the mimicked joint's (chains were checked acyclic at parse time).
  std::function<double(const SkeletonJoint&)> valueOf = [&](const SkeletonJoint& j) -> double {
    if (!j.mimic_joint.empty()) return j.mimic_multiplier * valueOf(*joint(j.mimic_joint)) + j.mimic_offset;
    const auto it = values.find(j.name);
    return it == values.end() ? 0.0 : it->second;
  };

  std::map<std::string, Eigen::Isometry3d> poses;
  poses[root_] = Eigen::Isometry3d::Identity();
  // Joints may be listed in any order: sweep until every reachable child is placed (depth <= joint count).
  std::vector<const SkeletonJoint*> pending;
  for (const auto& j : joints_) pending.push_back(&j);
  while (!pending.empty()) {
    std::vector<const SkeletonJoint*> next;
    for (const SkeletonJoint* j : pending) {
      const auto parent = poses.find(j->parent_link);
      if (parent == poses.end()) {
        next.push_back(j);
        continue;
      }
      Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
      const bool moves = j->type == "revolute" || j->type == "continuous" || j->type == "prismatic";
      if (moves) {
        const double q = valueOf(*j);
        if (!std::isfinite(q)) throw SceneError("joint values: joint '" + j->name + "' evaluates to a non-finite value");
        if ((j->type == "revolute" || j->type == "prismatic") && j->lower < j->upper && (q < j->lower || q > j->upper)) {
          std::ostringstream msg;
          msg << "joint '" << j->name << "' = " << q << " is outside its limits [" << j->lower << ", " << j->upper << "]";
          warn(msg.str());
        }
        if (j->type == "prismatic") {
          motion.translation() = q * j->axis;
        } else {
          motion.linear() = Eigen::AngleAxisd(q, j->axis).toRotationMatrix();
        }
      }
      poses[j->child_link] = parent->second * j->origin * motion;
    }
    if (next.size() == pending.size()) break;  // the rest hang off links not connected to the root
    pending.swap(next);
  }
  return poses;
}

std::string describeLinkDifferences(const Skeleton& a, const Skeleton& b) {
  const auto namesOf = [](const Skeleton& skeleton) {
    std::set<std::string> names;
    for (const SkeletonLink& link : skeleton.links()) names.insert(link.name);
    return names;
  };
  const std::set<std::string> in_a = namesOf(a), in_b = namesOf(b);
  const auto onlyIn = [](const std::set<std::string>& these, const std::set<std::string>& others) {
    constexpr std::size_t kListed = 10;
    std::string list;
    std::size_t count = 0;
    for (const std::string& name : these) {
      if (others.count(name)) continue;
      if (++count <= kListed) list += (list.empty() ? "'" : ", '") + name + "'";
    }
    if (count > kListed) list += " and " + std::to_string(count - kListed) + " more";
    return list;
  };
  const std::string only_a = onlyIn(in_a, in_b), only_b = onlyIn(in_b, in_a);
  if (only_a.empty() && only_b.empty()) return {};
  std::string text;
  if (!only_a.empty()) text += "only " + a.source() + " has " + only_a;
  if (!only_b.empty()) text += std::string(text.empty() ? "" : "; ") + "only " + b.source() + " has " + only_b;
  return text;
}

}  // namespace muscle_deformation
