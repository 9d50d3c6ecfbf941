#include "muscle_deformation/node/parameters.hpp"

#include "muscle_deformation/core/pipeline/settings_table.hpp"

#include <cmath>
#include <filesystem>
#include <stdexcept>

namespace muscle_deformation::node {
namespace {

// Reads typed, range-checked values; types follow roscpp's getParam (an integer is accepted where a double is asked).
class ParameterReader {
 public:
  explicit ParameterReader(const ParameterSource& source) : source_(source) {}

  bool has(const std::string& name) const {
    XmlRpc::XmlRpcValue raw;
    return source_.get(name, raw);
  }
  void readString(const std::string& name, std::string& value) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(name, raw)) return;  // keep the default
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeString) fail(name, "has the wrong type");
    value = static_cast<std::string>(raw);
  }
  void readBool(const std::string& name, bool& value) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(name, raw)) return;
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeBoolean) fail(name, "has the wrong type");
    value = static_cast<bool>(raw);
  }
  void readDouble(const std::string& name, double& value, double min, double max) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(name, raw)) return;
    double read_value = 0;
    if (raw.getType() == XmlRpc::XmlRpcValue::TypeDouble)
      read_value = static_cast<double>(raw);
    else if (raw.getType() == XmlRpc::XmlRpcValue::TypeInt)
      read_value = static_cast<int>(raw);
    else
      fail(name, "must be a number");
    if (!(read_value >= min && read_value <= max))
      fail(name, "is " + std::to_string(read_value) + ", must be in [" + std::to_string(min) + ", " +
                     std::to_string(max) + "]");
    value = read_value;
  }
  // roscpp's getParam(int) rounds a floating-point value silently: accept only integers (a float with no fractional
  // part, e.g. 30.0, counts as one).
  void readInt(const std::string& name, int& value, int min, int max) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(name, raw)) return;
    double number = 0;
    if (raw.getType() == XmlRpc::XmlRpcValue::TypeInt) {
      number = static_cast<int>(raw);
    } else if (raw.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
      number = static_cast<double>(raw);
      if (!std::isfinite(number) || number != std::floor(number))
        fail(name, "is " + std::to_string(number) + ", must be an integer");
    } else {
      fail(name, "must be an integer");
    }
    if (number < min || number > max)
      fail(name, "is " + std::to_string(static_cast<long long>(number)) + ", must be in [" + std::to_string(min) +
                     ", " + std::to_string(max) + "]");
    value = static_cast<int>(number);
  }
  template <typename Enum, typename Parse>
  void readEnum(const std::string& name, Enum& value, Parse parse) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(name, raw)) return;
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeString) fail(name, "must be a string");
    try {
      value = parse(static_cast<std::string>(raw));
    } catch (const std::invalid_argument& e) {
      fail(name, e.what());
    }
  }
  // A single name or tag, or a list of them; an empty string means none.
  void readNames(const std::string& name, std::vector<std::string>& value) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(name, raw)) return;
    if (raw.getType() == XmlRpc::XmlRpcValue::TypeString) {
      const std::string single = static_cast<std::string>(raw);
      value.clear();
      if (!single.empty()) value.push_back(single);
      return;
    }
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeArray) fail(name, "must be a list of muscle names or tags");
    std::vector<std::string> names;
    for (int i = 0; i < raw.size(); ++i) {
      if (raw[i].getType() != XmlRpc::XmlRpcValue::TypeString) fail(name, "must be a list of muscle names or tags");
      names.push_back(static_cast<std::string>(raw[i]));
    }
    value = std::move(names);
  }
  [[noreturn]] void fail(const std::string& name, const std::string& problem) const {
    throw std::invalid_argument("parameter " + source_.fullName(name) + " " + problem);
  }

 private:
  const ParameterSource& source_;
};

}  // namespace

void shareStoppingRule(SimulationSettings& simulation) {
  simulation.local_global.stopping_rule = simulation.solver.stopping_rule;
  simulation.local_global.max_iterations = simulation.solver.max_iterations;
  simulation.local_global.displacement_tolerance_m = simulation.solver.displacement_tolerance_m;
  simulation.local_global.time_budget_ms = simulation.solver.time_budget_ms;
}

bool NodeHandleParameters::get(const std::string& name, XmlRpc::XmlRpcValue& value) const {
  return node_.hasParam(name) && node_.getParam(name, value);
}

bool MapParameters::get(const std::string& name, XmlRpc::XmlRpcValue& value) const {
  asked_.insert(name);
  const auto found = values_.find(name);
  if (found == values_.end()) return false;
  value = found->second;
  return true;
}

NodeSettings readNodeSettings(const ros::NodeHandle& private_node, const std::string& package_root) {
  return readNodeSettings(NodeHandleParameters(private_node), package_root);
}

NodeSettings readNodeSettings(const ParameterSource& parameters, const std::string& package_root) {
  NodeSettings settings;
  // The core's settings (model, solver, collision, surfaces, stream policy) from their one table, starting from the
  // node's defaults, which config/muscle_deformation.yaml documents (a test checks).
  CoreSettings core = nodeDefaultSettings();
  settings.package_root = package_root;
  settings.scene_path = (std::filesystem::path(package_root) / "config/scenes/right_hip_thigh.yaml").string();
  const ParameterReader p(parameters);

  p.readString("scene", settings.scene_path);
  p.readNames("muscles", settings.muscles);
  p.readString("fixed_frame", settings.fixed_frame);
  if (settings.fixed_frame.empty()) p.fail("fixed_frame", "must not be empty");

  for (const SettingSpec& spec : coreSettingSpecs()) {
    XmlRpc::XmlRpcValue raw;
    if (!parameters.get(spec.name, raw)) continue;  // keep the default
    SettingValue value;
    switch (raw.getType()) {
      case XmlRpc::XmlRpcValue::TypeBoolean: value = static_cast<bool>(raw); break;
      case XmlRpc::XmlRpcValue::TypeInt: value = static_cast<int>(raw); break;
      case XmlRpc::XmlRpcValue::TypeDouble: value = static_cast<double>(raw); break;
      case XmlRpc::XmlRpcValue::TypeString: value = static_cast<std::string>(raw); break;
      default: p.fail(spec.name, "must be a single value");
    }
    if (const std::string problem = checkSetting(spec, value); !problem.empty()) p.fail(spec.name, problem);
    spec.set(core, value);
  }
  settings.pipeline = core.pipeline;
  settings.stream.policy = core.stream;
  SimulationSettings& simulation = settings.pipeline.simulation;
  ServiceSettings& service = settings.service;
  p.readEnum("service_solver", service.solver_kind, solverKindFromString);
  p.readInt("service_lbfgs_history", service.lbfgs_history, 0, 1000);
  p.readInt("service_max_iterations", service.max_iterations, 1, 1000000);
  p.readInt("service_max_queued", service.max_queued, 0, 100);
  p.readDouble("service_warm_max_translation_m", service.warm_max_translation_m, 0.0, 1e6);
  p.readDouble("service_warm_max_rotation_rad", service.warm_max_rotation_rad, 0.0, 7.0);
  p.readDouble("max_solve_time_s", settings.max_solve_time_s, 1e-3, 3600.0);
  shareStoppingRule(simulation);
  // The local/global settings are checked where a solver will use them: the stream's, then the service's (which
  // shares every local/global parameter but the L-BFGS history).
  if (simulation.solver_kind == SolverKind::local_global)
    if (const std::string problem = validate(simulation.local_global); !problem.empty()) p.fail("lbfgs_history", problem);
  LocalGlobalSettings service_local_global = simulation.local_global;
  service_local_global.lbfgs_history = service.lbfgs_history;
  if (service.solver_kind == SolverKind::local_global)
    if (const std::string problem = validate(service_local_global); !problem.empty())
      p.fail("service_lbfgs_history", problem + " (chebyshev_rho and volume_weight apply to the service too)");

  StreamSettings& stream = settings.stream;
  for (const char* replaced : {"reset_translation_m", "reset_rotation_rad"}) {
    if (p.has(replaced)) {
      p.fail(replaced, "no longer exists: the stream starts cold only at a discontinuity (time going back, or a bone "
                       "faster than max_bone_speed_m_per_s / max_bone_angular_speed_rad_per_s); the service's warm "
                       "starts have service_warm_max_translation_m / service_warm_max_rotation_rad");
    }
  }
  p.readDouble("tf_wait_s", stream.tf_wait_s, 0.0, 60.0);
  p.readBool("colour_fibres_by_strain", stream.colour_fibres_by_strain);
  double alpha = stream.surface_alpha;
  p.readDouble("surface_alpha", alpha, 0.0, 1.0);
  stream.surface_alpha = static_cast<float>(alpha);
  p.readBool("stats_metrics", stream.stats_metrics);
  p.readDouble("expected_rate_hz", stream.expected_rate_hz, 0.0, 1e6);
  return settings;
}

}  // namespace muscle_deformation::node
