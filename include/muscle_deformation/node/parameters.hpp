// The node's private parameters (documented with units in config/muscle_deformation.yaml) read into plain settings:
// the core's settings through the core's table, the node's own ones (service, publishing, tf) through nodeSettingSpecs,
// a table of the same entry type.
#pragma once

#include "muscle_deformation/core/pipeline/settings_table.hpp"
#include "muscle_deformation/core/pipeline/single_pose_session.hpp"

#include <ros/node_handle.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include <map>
#include <set>
#include <string>
#include <vector>

namespace muscle_deformation::node {

// How the node takes poses in and publishes frames (the stream's protocol is the core's StreamSessionSettings).
struct StreamSettings {
  double tf_wait_s = 0.2;                 // wall time to wait for a pose's transforms before counting a tf failure
  bool colour_fibres_by_strain = false;
  float surface_alpha = 0.8f;             // opacity of ~surface_markers
  bool stats_metrics = true;              // measure surface fidelity for ~stats (costs a few ms per frame)
  double expected_rate_hz = 60.0;         // diagnostics: expected output rate
};

// The ~deform_pose service: the core's single-pose session (~service_solver, ~service_lbfgs_history,
// ~service_max_iterations, ~service_warm_max_*) and how many calls may wait.
struct ServiceSettings {
  SinglePoseSettings single_pose;
  int max_queued = 4;  // ~service_max_queued: calls that may wait while one solves; more are refused
};

struct NodeSettings {
  std::string package_root;              // of muscle_deformation
  std::string scene_path;                // ~scene
  std::vector<std::string> muscles;      // ~muscles: names or tags, empty = all
  std::string fixed_frame = "pelvis";    // ~fixed_frame
  double max_solve_time_s = 10.0;        // ~max_solve_time_s: wall-time ceiling of any solve, stream or service
  CoreSettings core;      // the core's table: the pipeline and the stream session
  StreamSettings stream;
  ServiceSettings service;
};

// The settings only the node has, declared once as the core's are (name, kind, unit, range or choices, one sentence,
// field), in the order config/muscle_deformation.yaml documents them. Not in it: `scene` (a path whose default is
// the package's bundled scene, set by the launch file) and `muscles` (a list of names or tags).
using NodeSettingSpec = SettingEntry<NodeSettings>;
const std::vector<NodeSettingSpec>& nodeSettingSpecs();

// Where the node's parameters come from: the parameter server in the node, a plain map in tests (no roscore).
class ParameterSource {
 public:
  virtual ~ParameterSource() = default;
  // False when `name` is not set; otherwise its raw value.
  virtual bool get(const std::string& name, XmlRpc::XmlRpcValue& value) const = 0;
  // The name as the user knows it (resolved in the node's namespace), for error messages.
  virtual std::string fullName(const std::string& name) const = 0;
};

class NodeHandleParameters : public ParameterSource {
 public:
  explicit NodeHandleParameters(const ros::NodeHandle& node) : node_(node) {}
  bool get(const std::string& name, XmlRpc::XmlRpcValue& value) const override;
  std::string fullName(const std::string& name) const override { return node_.resolveName(name); }

 private:
  const ros::NodeHandle& node_;
};

// Parameters from a map; remembers every name asked for, so a test can tell documented parameters the node ignores.
class MapParameters : public ParameterSource {
 public:
  explicit MapParameters(std::map<std::string, XmlRpc::XmlRpcValue> values, std::string node_name = "/node")
      : values_(std::move(values)), node_name_(std::move(node_name)) {}
  bool get(const std::string& name, XmlRpc::XmlRpcValue& value) const override;
  std::string fullName(const std::string& name) const override { return node_name_ + "/" + name; }
  const std::set<std::string>& asked() const { return asked_; }

 private:
  std::map<std::string, XmlRpc::XmlRpcValue> values_;
  std::string node_name_;
  mutable std::set<std::string> asked_;
};

// Throws std::invalid_argument naming the parameter and what is wrong.
NodeSettings readNodeSettings(const ParameterSource& parameters, const std::string& package_root);
NodeSettings readNodeSettings(const ros::NodeHandle& private_node, const std::string& package_root);

}  // namespace muscle_deformation::node
