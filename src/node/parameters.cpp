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
  // One setting of a table (the core's or the node's) into `settings`; every parameter words its problems alike
  // (checkSetting): e.g. roscpp's getParam(int) would round 30.5 silently, here it is refused.
  template <typename Settings>
  void readSetting(const SettingEntry<Settings>& entry, Settings& settings) const {
    XmlRpc::XmlRpcValue raw;
    if (!source_.get(entry.name, raw)) return;  // keep the default
    const SettingValue value = valueOf(entry.kind, raw);
    if (const std::string problem = checkSetting(entry, value); !problem.empty()) fail(entry.name, problem);
    entry.set(settings, value);
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
  static SettingValue valueOf(SettingKind kind, XmlRpc::XmlRpcValue& raw) {
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
        return kind == SettingKind::boolean ? SettingValue(0) : SettingValue(false);
    }
  }

  const ParameterSource& source_;
};

std::vector<NodeSettingSpec> buildNodeTable() {
  namespace entries = setting_entries;
  const auto service = [](NodeSettings& s) -> ServiceSettings& { return s.service; };
  const auto stream = [](NodeSettings& s) -> StreamSettings& { return s.stream; };
  return {
      entries::text<NodeSettings>("fixed_frame", "tf frame the bones are looked up in and every output is expressed in",
                                  [](NodeSettings& s) -> std::string& { return s.fixed_frame; }),
      // ~deform_pose service
      entries::choice<NodeSettings, SolverKind>(
          "service_solver", {"verlet", "local_global", "block_descent", "newton_krylov"},
          {SolverKind::verlet, SolverKind::local_global, SolverKind::block_descent, SolverKind::newton_krylov},
          "the service's solver (the streaming one is `solver`)",
          [service](NodeSettings& s) -> SolverKind& { return service(s).single_pose.solver_kind; }),
      entries::integer<NodeSettings>("service_lbfgs_history", "count", 0, 1000,
                                     "local_global: the service's quasi-Newton curvature pairs (0 = plain iterations)",
                                     [service](NodeSettings& s) -> int& { return service(s).single_pose.lbfgs_history; }),
      entries::integer<NodeSettings>("service_max_iterations", "count", 1, 1000000,
                                     "iterations per call (a request's max_iterations overrides it)",
                                     [service](NodeSettings& s) -> int& { return service(s).single_pose.max_iterations; }),
      entries::integer<NodeSettings>("service_max_queued", "count", 0, 100,
                                     "calls that may wait while one solves; further calls are refused at once",
                                     [service](NodeSettings& s) -> int& { return service(s).max_queued; }),
      entries::number<NodeSettings>(
          "service_warm_max_translation_m", "m", 0.0, 1e6,
          "a warm start continues the client's previous answer only if no bone moved further since",
          [service](NodeSettings& s) -> double& { return service(s).single_pose.warm_max_translation_m; }),
      entries::number<NodeSettings>(
          "service_warm_max_rotation_rad", "rad", 0.0, 7.0,
          "a warm start continues the client's previous answer only if no bone turned more since",
          [service](NodeSettings& s) -> double& { return service(s).single_pose.warm_max_rotation_rad; }),
      entries::number<NodeSettings>("max_solve_time_s", "s", 1e-3, 3600.0,
                                    "wall-time ceiling of any solve, stream or service call",
                                    [](NodeSettings& s) -> double& { return s.max_solve_time_s; }),
      // Streaming and publishing
      entries::number<NodeSettings>("tf_wait_s", "s", 0.0, 60.0,
                                    "wall time to wait for a pose's transforms before counting a tf failure",
                                    [stream](NodeSettings& s) -> double& { return stream(s).tf_wait_s; }),
      entries::boolean<NodeSettings>("stats_metrics", "measure surface fidelity for ~stats while it has subscribers",
                                     [stream](NodeSettings& s) -> bool& { return stream(s).stats_metrics; }),
      entries::boolean<NodeSettings>("colour_fibres_by_strain",
                                     "~fibres: colour segments by their strain instead of by muscle",
                                     [stream](NodeSettings& s) -> bool& { return stream(s).colour_fibres_by_strain; }),
      entries::number<NodeSettings>("surface_alpha", "", 0.0, 1.0, "opacity of ~surface_markers",
                                    [stream](NodeSettings& s) -> float& { return stream(s).surface_alpha; }),
      entries::number<NodeSettings>("expected_rate_hz", "Hz", 0.0, 1e6,
                                    "diagnostics: pose rate the solver should keep up with (0 = no expectation)",
                                    [stream](NodeSettings& s) -> double& { return stream(s).expected_rate_hz; }),
  };
}

}  // namespace

const std::vector<NodeSettingSpec>& nodeSettingSpecs() {
  static const std::vector<NodeSettingSpec> table = buildNodeTable();
  return table;
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
  // The node's own settings (service, publishing, tf) from their table.
  for (const NodeSettingSpec& spec : nodeSettingSpecs()) p.readSetting(spec, settings);
  if (settings.fixed_frame.empty()) p.fail("fixed_frame", "must not be empty");
  for (const char* replaced : {"reset_translation_m", "reset_rotation_rad"}) {
    if (p.has(replaced)) {
      p.fail(replaced, "no longer exists: the stream starts cold only at a discontinuity (time going back, or a bone "
                       "faster than max_bone_speed_m_per_s / max_bone_angular_speed_rad_per_s); the service's warm "
                       "starts have service_warm_max_translation_m / service_warm_max_rotation_rad");
    }
  }

  for (const SettingSpec& spec : coreSettingSpecs()) p.readSetting(spec, core);
  const SimulationSettings& simulation = core.pipeline.simulation;
  const StoppingSettings& stopping = core.stream.stopping.sweeps;
  if (stopping.rule == StoppingRule::force_residual && !measuresForceResidual(simulation.solver_kind))
    p.fail("stopping_rule", "force_residual is measured by the block_descent and newton_krylov solvers only (solver is " +
                                toString(simulation.solver_kind) + ")");
  if (core.stream.auto_resolution && stopping.rule != StoppingRule::time_budget)
    p.fail("auto_resolution", "fits the model to time_budget_ms: it needs stopping_rule time_budget");
  // Block descent's settings that depend on one another (the across-fibre tie on the drag, the rest balance on the drag
  // along the fibre) are refused here, before the scene is built, with the core's reason; each reason begins with the
  // parameter it names.
  if (const std::string problem = validate(simulation.block_descent); !problem.empty()) {
    const std::size_t space = problem.find(' ');
    p.fail(problem.substr(0, space), space == std::string::npos ? "is invalid" : problem.substr(space + 1));
  }
  // The local/global settings are checked where a solver will use them: the stream's, then the service's (which
  // shares every local/global parameter but the L-BFGS history).
  if (simulation.solver_kind == SolverKind::local_global)
    if (const std::string problem = validate(simulation.local_global); !problem.empty()) p.fail("lbfgs_history", problem);
  SinglePoseSettings& single_pose = settings.service.single_pose;
  LocalGlobalSettings service_local_global = simulation.local_global;
  service_local_global.lbfgs_history = single_pose.lbfgs_history;
  if (single_pose.solver_kind == SolverKind::local_global)
    if (const std::string problem = validate(service_local_global); !problem.empty())
      p.fail("service_lbfgs_history", problem + " (chebyshev_rho and volume_weight apply to the service too)");
  // The service stops as the stream's rule says where it can (a residual), else by its iteration count; "converged"
  // is the same residual criterion for both.
  single_pose.rule = stopping.rule == StoppingRule::force_residual ? StoppingRule::force_residual : StoppingRule::iterations;
  single_pose.residual_tolerance = stopping.residual_tolerance;
  settings.core = core;
  return settings;
}

}  // namespace muscle_deformation::node
