// Every setting of the pipeline and of the pose stream, declared once: the name the node's parameters and
// config/muscle_deformation.yaml use, its kind, unit, range or choices, one sentence, and where it lives. The node's
// parameter reader, the benchmarks' reading of the node defaults and the test of the documented YAML go through it.
// The node declares its own settings (service, publishing, tf) with the same entry type in its own table.
#pragma once

#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/stream_session.hpp"

#include <functional>
#include <type_traits>
#include <string>
#include <variant>
#include <vector>

namespace muscle_deformation {

struct CoreSettings {
  PipelineSettings pipeline;
  StreamSessionSettings stream;  // the stream's protocol and how its frames stop
};

using SettingValue = std::variant<bool, int, double, std::string>;

enum class SettingKind { boolean, integer, number, choice, text };

// One setting of the struct `Settings` holds it in (the core's CoreSettings here, the node's settings in its own
// table): its name, kind, unit, range or choices, one sentence, and how to read and write its field.
template <typename Settings>
struct SettingEntry {
  using Kind = SettingKind;
  std::string name;
  Kind kind = Kind::number;
  std::string unit;                  // SI unit, "count", or empty (dimensionless, boolean, choice, text)
  double min = 0, max = 0;           // integer and number: the closed range accepted
  std::vector<std::string> choices;  // choice: the names accepted
  std::string meaning;               // one sentence
  std::function<SettingValue(const Settings&)> get;
  std::function<void(Settings&, const SettingValue&)> set;  // for a value checkSetting accepted
};

using SettingSpec = SettingEntry<CoreSettings>;

// In the order config/muscle_deformation.yaml documents them.
const std::vector<SettingSpec>& coreSettingSpecs();
const SettingSpec* findSetting(const std::string& name);  // nullptr when no such setting

// Empty when `value` suits a setting of this kind and range or choices; otherwise what is wrong, worded to follow the
// setting's name, e.g. "is 1, must be in [2, 10000]". An integer is accepted where a number is asked, and a
// floating-point value with no fractional part where an integer is.
std::string checkSettingValue(SettingKind kind, double min, double max, const std::vector<std::string>& choices,
                              const SettingValue& value);
template <typename Settings>
std::string checkSetting(const SettingEntry<Settings>& entry, const SettingValue& value) {
  return checkSettingValue(entry.kind, entry.min, entry.max, entry.choices, value);
}

// Builders of table entries: `access` takes the settings struct and returns a reference to the setting's field.
namespace setting_entries {

inline double asNumber(const SettingValue& value) {
  if (const int* i = std::get_if<int>(&value)) return *i;
  return std::get<double>(value);
}

template <typename Settings, typename Access>
SettingEntry<Settings> describe(std::string name, SettingKind kind, std::string unit, double min, double max,
                                std::vector<std::string> choices, std::string meaning, Access access) {
  SettingEntry<Settings> entry;
  entry.name = std::move(name);
  entry.kind = kind;
  entry.unit = std::move(unit);
  entry.min = min;
  entry.max = max;
  entry.choices = std::move(choices);
  entry.meaning = std::move(meaning);
  // The table reads a field through the same accessor that writes it.
  entry.get = [access](const Settings& s) { return SettingValue(access(const_cast<Settings&>(s))); };
  return entry;
}

template <typename Settings, typename Access>
SettingEntry<Settings> boolean(std::string name, std::string meaning, Access access) {
  SettingEntry<Settings> entry =
      describe<Settings>(std::move(name), SettingKind::boolean, "", 0, 0, {}, std::move(meaning), access);
  entry.set = [access](Settings& s, const SettingValue& v) { access(s) = std::get<bool>(v); };
  return entry;
}

template <typename Settings, typename Access>
SettingEntry<Settings> integer(std::string name, std::string unit, int min, int max, std::string meaning,
                               Access access) {
  SettingEntry<Settings> entry = describe<Settings>(std::move(name), SettingKind::integer, std::move(unit), min, max,
                                                    {}, std::move(meaning), access);
  entry.set = [access](Settings& s, const SettingValue& v) { access(s) = static_cast<int>(asNumber(v)); };
  return entry;
}

template <typename Settings, typename Access>
SettingEntry<Settings> number(std::string name, std::string unit, double min, double max, std::string meaning,
                              Access access) {
  SettingEntry<Settings> entry = describe<Settings>(std::move(name), SettingKind::number, std::move(unit), min, max,
                                                    {}, std::move(meaning), access);
  // A float field (an opacity) is read as a double and stored back as a float.
  entry.get = [access](const Settings& s) {
    return SettingValue(static_cast<double>(access(const_cast<Settings&>(s))));
  };
  entry.set = [access](Settings& s, const SettingValue& v) {
    using Field = std::remove_reference_t<decltype(access(s))>;
    access(s) = static_cast<Field>(asNumber(v));
  };
  return entry;
}

// `names[i]` is the name of `values[i]`.
template <typename Settings, typename Enum, typename Access>
SettingEntry<Settings> choice(std::string name, std::vector<std::string> names, std::vector<Enum> values,
                              std::string meaning, Access access) {
  SettingEntry<Settings> entry;
  entry.name = std::move(name);
  entry.kind = SettingKind::choice;
  entry.choices = names;
  entry.meaning = std::move(meaning);
  entry.get = [access, names, values](const Settings& s) {
    const Enum current = access(const_cast<Settings&>(s));
    for (std::size_t i = 0; i < values.size(); ++i)
      if (values[i] == current) return SettingValue(names[i]);
    return SettingValue(std::string("?"));
  };
  entry.set = [access, names, values](Settings& s, const SettingValue& v) {
    const std::string& text = std::get<std::string>(v);
    for (std::size_t i = 0; i < names.size(); ++i)
      if (names[i] == text) access(s) = values[i];
  };
  return entry;
}

template <typename Settings, typename Access>
SettingEntry<Settings> text(std::string name, std::string meaning, Access access) {
  SettingEntry<Settings> entry =
      describe<Settings>(std::move(name), SettingKind::text, "", 0, 0, {}, std::move(meaning), access);
  entry.set = [access](Settings& s, const SettingValue& v) { access(s) = std::get<std::string>(v); };
  return entry;
}

}  // namespace setting_entries

// The settings the node starts from: the core's defaults, except where the node's own measurement chose otherwise
// (docs/BENCHMARKS.md, real-time section): block descent sweeping within a 12 ms budget per frame (at most 30 sweeps).
CoreSettings nodeDefaultSettings();

// A YAML scalar typed as rosparam types the same file: true/false, an integer, a floating-point number, else the text.
SettingValue settingValueOfYamlScalar(const std::string& text);

// Reads every setting of the table that the YAML map at `path` holds (other keys are left to their owners) into
// `settings`. Throws std::invalid_argument naming the file, the key and the problem.
void readSettingsYaml(const std::string& path, CoreSettings& settings);

}  // namespace muscle_deformation
