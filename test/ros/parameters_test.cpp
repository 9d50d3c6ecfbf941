// The node's parameter reader on a plain parameter map (no roscore): types, ranges, messages, and the documented
// config/muscle_deformation.yaml agreeing with the defaults the code holds.
#include "muscle_deformation/node/parameters.hpp"

#include "muscle_deformation/core/pipeline/settings_table.hpp"

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <variant>

namespace md = muscle_deformation;
namespace node = muscle_deformation::node;

namespace {

const std::string kPackageRoot = MD_PACKAGE_DIR;

// rosparam's typing of a YAML scalar: booleans, integers, floating-point numbers, else strings.
XmlRpc::XmlRpcValue toXmlRpc(const YAML::Node& yaml) {
  if (yaml.IsSequence()) {
    XmlRpc::XmlRpcValue array;
    array.setSize(static_cast<int>(yaml.size()));
    for (std::size_t i = 0; i < yaml.size(); ++i) array[static_cast<int>(i)] = toXmlRpc(yaml[i]);
    return array;
  }
  return std::visit([](const auto& value) { return XmlRpc::XmlRpcValue(value); },
                    md::settingValueOfYamlScalar(yaml.as<std::string>()));
}

std::map<std::string, XmlRpc::XmlRpcValue> documentedParameters() {
  std::map<std::string, XmlRpc::XmlRpcValue> values;
  for (const auto& entry : YAML::LoadFile(kPackageRoot + "/config/muscle_deformation.yaml"))
    values[entry.first.as<std::string>()] = toXmlRpc(entry.second);
  return values;
}

XmlRpc::XmlRpcValue names(std::initializer_list<const char*> list) {
  XmlRpc::XmlRpcValue array;
  array.setSize(static_cast<int>(list.size()));
  int i = 0;
  for (const char* name : list) array[i++] = std::string(name);
  return array;
}

std::string errorOf(std::map<std::string, XmlRpc::XmlRpcValue> values) {
  try {
    node::readNodeSettings(node::MapParameters(std::move(values), "/muscle_deformation"), kPackageRoot);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Parameters, TheDocumentedFileHoldsTheDefaultsAndNamesEveryParameterTheNodeReads) {
  const auto documented = documentedParameters();
  node::MapParameters parameters(documented);
  const node::NodeSettings from_file = node::readNodeSettings(parameters, kPackageRoot);
  const node::NodeSettings defaults = node::readNodeSettings(node::MapParameters({}), kPackageRoot);

  for (const auto& [name, value] : documented)
    EXPECT_TRUE(parameters.asked().count(name)) << name << " is documented but the node never reads it";
  for (const std::string& name : parameters.asked()) {
    const bool explained_elsewhere = name == "scene"                                         // a launch argument
                                     || name == "reset_translation_m" || name == "reset_rotation_rad";  // replaced
    if (!explained_elsewhere) {
      EXPECT_TRUE(documented.count(name)) << name << " is read but not documented";
    }
  }

  // "Every value below is the node's default": the file changes nothing. The core's settings through their table
  // (pipeline, solvers, collision, surfaces, stream policy), the node's own ones by name.
  const md::CoreSettings& core_from_file = from_file.core;
  const md::CoreSettings& core_defaults = defaults.core;
  for (const md::SettingSpec& spec : md::coreSettingSpecs()) {
    EXPECT_TRUE(spec.get(core_from_file) == spec.get(core_defaults)) << spec.name;
    EXPECT_TRUE(documented.count(spec.name)) << spec.name << " is in the settings table but not documented";
    EXPECT_FALSE(spec.meaning.empty()) << spec.name;
  }
  EXPECT_TRUE(md::coreSettingSpecs().size() >= 30u);
  // The node's own settings (service, publishing, tf) through their table, as the core's.
  for (const node::NodeSettingSpec& spec : node::nodeSettingSpecs()) {
    EXPECT_TRUE(spec.get(from_file) == spec.get(defaults)) << spec.name;
    EXPECT_TRUE(documented.count(spec.name)) << spec.name << " is in the node's settings table but not documented";
    EXPECT_FALSE(spec.meaning.empty()) << spec.name;
    EXPECT_EQ(md::findSetting(spec.name), nullptr) << spec.name << " is declared in both tables";
  }
  EXPECT_EQ(node::nodeSettingSpecs().size(), 13u);
  // Every documented key is declared in one of the tables, but the two the node reads on its own.
  for (const auto& [name, value] : documented) {
    (void)value;
    const bool in_a_table =
        md::findSetting(name) != nullptr ||
        std::any_of(node::nodeSettingSpecs().begin(), node::nodeSettingSpecs().end(),
                    [&](const node::NodeSettingSpec& spec) { return spec.name == name; });
    EXPECT_TRUE(in_a_table || name == "muscles") << name << " is documented but declared in no settings table";
  }
#define EXPECT_SAME(field) EXPECT_EQ(from_file.field, defaults.field) << #field
  EXPECT_SAME(scene_path);
  EXPECT_SAME(muscles);
  EXPECT_SAME(service.single_pose.rule);   // derived from the stream's stopping parameters
  EXPECT_SAME(service.single_pose.residual_tolerance);
#undef EXPECT_SAME
}

TEST(Parameters, TheBenchmarksReadTheDocumentedFileAsTheNodeDoes) {
  md::CoreSettings from_yaml = md::nodeDefaultSettings();
  md::readSettingsYaml(kPackageRoot + "/config/muscle_deformation.yaml", from_yaml);
  const node::NodeSettings node_settings =
      node::readNodeSettings(node::MapParameters(documentedParameters()), kPackageRoot);
  const md::CoreSettings& from_node = node_settings.core;
  for (const md::SettingSpec& spec : md::coreSettingSpecs())
    EXPECT_TRUE(spec.get(from_yaml) == spec.get(from_node)) << spec.name;
}

TEST(Parameters, ValuesOfEveryKindAreReadIntoTheSettings) {
  const node::NodeSettings settings = node::readNodeSettings(
      node::MapParameters({{"particles_per_fibre", XmlRpc::XmlRpcValue(12)},
                           {"max_iterations", XmlRpc::XmlRpcValue(40.0)},  // a float with no fraction is an integer
                           {"attachment_distance_m", XmlRpc::XmlRpcValue(0)},  // an integer where a number is asked
                           {"fix_fibre_ends", XmlRpc::XmlRpcValue(false)},
                           {"solver", XmlRpc::XmlRpcValue(std::string("local_global"))},
                           {"stopping_rule", XmlRpc::XmlRpcValue(std::string("displacement"))},
                           {"muscles", names({"thigh13", "iliacus"})},
                           {"surface_alpha", XmlRpc::XmlRpcValue(0.25)}}),
      kPackageRoot);
  EXPECT_EQ(settings.core.pipeline.simulation.model.particles_per_fibre, 12);
  EXPECT_EQ(settings.core.stream.stopping.sweeps.max_iterations, 40);
  EXPECT_EQ(settings.core.pipeline.simulation.model.attachment_distance_m, 0.0);
  EXPECT_FALSE(settings.core.pipeline.simulation.model.fix_fibre_ends);
  EXPECT_EQ(settings.core.pipeline.simulation.solver_kind, md::SolverKind::local_global);
  EXPECT_EQ(settings.muscles, (std::vector<std::string>{"thigh13", "iliacus"}));
  EXPECT_FLOAT_EQ(settings.stream.surface_alpha, 0.25f);
  // One stopping rule per frame, whichever solver runs.
  EXPECT_EQ(settings.core.stream.stopping.sweeps.rule, md::StoppingRule::displacement);

  const node::NodeSettings single =
      node::readNodeSettings(node::MapParameters({{"muscles", XmlRpc::XmlRpcValue(std::string("thigh13"))}}), kPackageRoot);
  EXPECT_EQ(single.muscles, std::vector<std::string>{"thigh13"});
  const node::NodeSettings none =
      node::readNodeSettings(node::MapParameters({{"muscles", XmlRpc::XmlRpcValue(std::string(""))}}), kPackageRoot);
  EXPECT_TRUE(none.muscles.empty());
}

TEST(Parameters, EveryBadValueIsRefusedNamingTheParameterAndTheProblem) {
  const std::string prefix = "parameter /muscle_deformation/";
  EXPECT_EQ(errorOf({{"particles_per_fibre", XmlRpc::XmlRpcValue(20.5)}}),
            prefix + "particles_per_fibre is 20.500000, must be an integer");
  EXPECT_EQ(errorOf({{"particles_per_fibre", XmlRpc::XmlRpcValue(1)}}),
            prefix + "particles_per_fibre is 1, must be in [2, 10000]");
  EXPECT_EQ(errorOf({{"particles_per_fibre", XmlRpc::XmlRpcValue(std::string("many"))}}),
            prefix + "particles_per_fibre must be an integer");
  EXPECT_EQ(errorOf({{"surface_alpha", XmlRpc::XmlRpcValue(1.5)}}),
            prefix + "surface_alpha is 1.500000, must be in [0.000000, 1.000000]");
  EXPECT_EQ(errorOf({{"dt_s", XmlRpc::XmlRpcValue(true)}}), prefix + "dt_s must be a number");
  EXPECT_EQ(errorOf({{"collisions", XmlRpc::XmlRpcValue(1)}}), prefix + "collisions has the wrong type");
  EXPECT_EQ(errorOf({{"fixed_frame", XmlRpc::XmlRpcValue(std::string(""))}}), prefix + "fixed_frame must not be empty");
  EXPECT_EQ(errorOf({{"muscles", XmlRpc::XmlRpcValue(3)}}), prefix + "muscles must be a list of muscle names or tags");
  XmlRpc::XmlRpcValue mixed = names({"thigh13", "x"});
  mixed[1] = 4;
  EXPECT_EQ(errorOf({{"muscles", mixed}}), prefix + "muscles must be a list of muscle names or tags");

  const std::string unknown_rule = errorOf({{"stopping_rule", XmlRpc::XmlRpcValue(std::string("forever"))}});
  EXPECT_EQ(unknown_rule,
            prefix + "stopping_rule 'forever' is not one of: iterations, displacement, time_budget, force_residual");
  EXPECT_EQ(errorOf({{"solver", XmlRpc::XmlRpcValue(std::string("verlet"))},
                     {"stopping_rule", XmlRpc::XmlRpcValue(std::string("force_residual"))}}),
            prefix + "stopping_rule force_residual is measured by the block_descent and newton_krylov solvers only (solver is verlet)");
  EXPECT_EQ(errorOf({{"solver", XmlRpc::XmlRpcValue(std::string("block_descent"))},
                     {"stopping_rule", XmlRpc::XmlRpcValue(std::string("force_residual"))}}),
            "");
  EXPECT_EQ(errorOf({{"auto_resolution", XmlRpc::XmlRpcValue(true)},
                     {"stopping_rule", XmlRpc::XmlRpcValue(std::string("iterations"))}}),
            prefix + "auto_resolution fits the model to time_budget_ms: it needs stopping_rule time_budget");
  EXPECT_EQ(errorOf({{"auto_resolution", XmlRpc::XmlRpcValue(true)}}), "");  // the default rule is time_budget
  EXPECT_EQ(errorOf({{"auto_resolution", XmlRpc::XmlRpcValue(std::string("yes"))}}),
            prefix + "auto_resolution has the wrong type");
  EXPECT_EQ(errorOf({{"across_fibre_tie", XmlRpc::XmlRpcValue(0.03)}, {"tissue_relaxation_s", XmlRpc::XmlRpcValue(0.0)}}),
            prefix + "across_fibre_tie needs the tissue drag (tissue_relaxation_s > 0): the tie shares its frame anchor");
  EXPECT_EQ(errorOf({{"across_fibre_tie", XmlRpc::XmlRpcValue(0.03)}, {"tissue_relaxation_s", XmlRpc::XmlRpcValue(0.001)}}),
            "");
  EXPECT_EQ(errorOf({{"across_fibre_tie", XmlRpc::XmlRpcValue(0.0)}, {"tissue_relaxation_s", XmlRpc::XmlRpcValue(0.0)}}),
            "");
  EXPECT_EQ(errorOf({{"drag_along_fibre", XmlRpc::XmlRpcValue(0.0)}}),
            prefix + "balance_rest_shape needs drag_along_fibre > 0: the balance along the fibre rides on the drag there");
  EXPECT_EQ(errorOf({{"drag_along_fibre", XmlRpc::XmlRpcValue(0.0)}, {"balance_rest_shape", XmlRpc::XmlRpcValue(false)}}),
            "");
  const std::string replaced = errorOf({{"reset_translation_m", XmlRpc::XmlRpcValue(0.1)}});
  EXPECT_EQ(replaced.rfind(prefix + "reset_translation_m no longer exists", 0), 0u) << replaced;
  EXPECT_NE(replaced.find("max_bone_speed_m_per_s"), std::string::npos) << replaced;

  // The local/global settings are checked only for a solver that uses them, naming the parameter to change.
  const std::string stream_problem = errorOf({{"solver", XmlRpc::XmlRpcValue(std::string("local_global"))},
                                              {"lbfgs_history", XmlRpc::XmlRpcValue(8)},
                                              {"chebyshev_rho", XmlRpc::XmlRpcValue(0.5)}});
  EXPECT_EQ(stream_problem.rfind(prefix + "lbfgs_history ", 0), 0u) << stream_problem;
  EXPECT_EQ(errorOf({{"solver", XmlRpc::XmlRpcValue(std::string("verlet"))},
                     {"service_solver", XmlRpc::XmlRpcValue(std::string("verlet"))},
                     {"chebyshev_rho", XmlRpc::XmlRpcValue(0.5)}}),
            "");
  const std::string service_problem = errorOf({{"service_solver", XmlRpc::XmlRpcValue(std::string("local_global"))},
                                               {"chebyshev_rho", XmlRpc::XmlRpcValue(0.5)}});
  EXPECT_EQ(service_problem.rfind(prefix + "service_lbfgs_history ", 0), 0u) << service_problem;
}
