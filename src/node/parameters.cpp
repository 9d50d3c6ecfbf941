#include "muscle_deformation/node/parameters.hpp"

#include "muscle_deformation/core/pipeline/settings_table.hpp"

#include <filesystem>
#include <optional>
#include <stdexcept>
#include <variant>

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
  // Booleans, integers and numbers are checked like the core's settings (checkSetting), so every parameter words
  // its problems alike: e.g. roscpp's getParam(int) would round 30.5 silently, here it is refused.
  void readBool(const std::string& name, bool& value) const {
    if (const auto read = readChecked(specOf(name, SettingSpec::Kind::boolean, 0, 0))) value = std::get<bool>(*read);
  }
  void readDouble(const std::string& name, double& value, double min, double max) const {
    if (const auto read = readChecked(specOf(name, SettingSpec::Kind::number, min, max)))
      value = std::holds_alternative<int>(*read) ? std::get<int>(*read) : std::get<double>(*read);
  }
  void readInt(const std::string& name, int& value, int min, int max) const {
    if (const auto read = readChecked(specOf(name, SettingSpec::Kind::integer, min, max)))
      value = std::holds_alternative<int>(*read) ? std::get<int>(*read) : static_cast<int>(std::get<double>(*read));
  }
  // One setting of the core's table into `settings`.
  void readSetting(const SettingSpec& spec, CoreSettings& settings) const {
    if (const auto read = readChecked(spec)) spec.set(settings, *read);
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
  // The parameter's value, or nothing when it is not set; refuses (fail) a value checkSetting does not accept.
  std::optional<SettingValue> readChecked(const SettingSpec& spec) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(spec.name, raw)) return std::nullopt;  // keep the default
    const SettingValue value = valueOf(spec.kind, raw);
    if (const std::string problem = checkSetting(spec, value); !problem.empty()) fail(spec.name, problem);
    return value;
  }
  // A node-only parameter described like a setting of the core's table, for checkSetting.
  static SettingSpec specOf(const std::string& name, SettingSpec::Kind kind, double min, double max) {
    SettingSpec spec;
    spec.name = name;
    spec.kind = kind;
    spec.min = min;
    spec.max = max;
    return spec;
  }
  static SettingValue valueOf(SettingSpec::Kind kind, XmlRpc::XmlRpcValue& raw) {
    switch (raw.getType()) {
      case XmlRpc::XmlRpcValue::TypeBoolean:
        return static_cast<bool>(raw);
      case XmlRpc::XmlRpcValue::TypeInt:
        return static_cast<int>(raw);
      case XmlRpc::XmlRpcValue::TypeDouble:
        return static_cast<double>(raw);
      case XmlRpc::XmlRpcValue::TypeString:
        return static_cast<std::string>(raw);
      default:  // a list or map: a value of a type the kind never accepts, so checkSetting names the type expected
        return kind == SettingSpec::Kind::boolean ? SettingValue(0) : SettingValue(false);
    }
  }

  const ParameterSource& source_;
};

}  // namespace

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

  for (const SettingSpec& spec : coreSettingSpecs()) p.readSetting(spec, core);
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
  if (simulation.stopping.rule == StoppingRule::force_residual && simulation.solver_kind != SolverKind::block_descent)
    p.fail("stopping_rule", "force_residual is measured by the block_descent solver only (solver is " +
                                toString(simulation.solver_kind) + ")");
  // The local/global settings are checked where a solver will use them: the stream's, then the service's (which
  // shares every local/global parameter but the L-BFGS history).
  if (simulation.solver_kind == SolverKind::local_global)
    if (const std::string problem = validate(simulation.local_global); !problem.empty()) p.fail("lbfgs_history", problem);
  LocalGlobalSettings service_local_global = simulation.local_global;
  service_local_global.lbfgs_history = service.lbfgs_history;
  if (service_local_global.stopping_rule == StoppingRule::force_residual)
    service_local_global.stopping_rule = StoppingRule::iterations;  // as the service runs it (node's handler)
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
