// Every setting of the pipeline and of the pose stream, declared once: the name the node's parameters and
// config/muscle_deformation.yaml use, its kind, unit, range or choices, one sentence, and where it lives. The node's
// parameter reader, the benchmarks' reading of the node defaults and the test of the documented YAML go through it.
#pragma once

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/pose_stream.hpp"

#include <functional>
#include <string>
#include <variant>
#include <vector>

namespace muscle_deformation {

struct CoreSettings {
  PipelineSettings pipeline;
  PoseStreamSettings stream;
};

using SettingValue = std::variant<bool, int, double, std::string>;

struct SettingSpec {
  enum class Kind { boolean, integer, number, choice };
  std::string name;
  Kind kind = Kind::number;
  std::string unit;                  // SI unit, "count", or empty (dimensionless, boolean, choice)
  double min = 0, max = 0;           // integer and number: the closed range accepted
  std::vector<std::string> choices;  // choice: the names accepted
  std::string meaning;               // one sentence
  std::function<SettingValue(const CoreSettings&)> get;
  std::function<void(CoreSettings&, const SettingValue&)> set;  // for a value checkSetting accepted
};

// In the order config/muscle_deformation.yaml documents them.
const std::vector<SettingSpec>& coreSettingSpecs();
const SettingSpec* findSetting(const std::string& name);  // nullptr when no such setting

// Empty when `value` suits `spec` (kind, range, choice); otherwise what is wrong, worded to follow the setting's
// name, e.g. "is 1, must be in [2, 10000]". An integer is accepted where a number is asked, and a floating-point
// value with no fractional part where an integer is.
std::string checkSetting(const SettingSpec& spec, const SettingValue& value);

// The settings the node starts from: the core's defaults, except where the node's own measurement chose otherwise
// (docs/BENCHMARKS.md, real-time section): block descent sweeping within a 12 ms budget per frame (at most 30 sweeps).
CoreSettings nodeDefaultSettings();

// A YAML scalar typed as rosparam types the same file: true/false, an integer, a floating-point number, else the text.
SettingValue settingValueOfYamlScalar(const std::string& text);

// The table holds one set of stopping parameters (stopping_rule, max_iterations, tolerances, time budget) in
// SimulationSettings::stopping; shareStoppingRule (pipeline/simulation.hpp) makes them drive whichever solver runs.

// Reads every setting of the table that the YAML map at `path` holds (other keys are left to their owners) into
// `settings`. Throws std::invalid_argument naming the file, the key and the problem.
void readSettingsYaml(const std::string& path, CoreSettings& settings);

}  // namespace muscle_deformation
