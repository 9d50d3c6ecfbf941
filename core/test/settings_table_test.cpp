// The one table of the core's settings: every entry reads and writes its own field, checks its kind and range with a
// message, and a YAML file goes through it.
#include "muscle_deformation/core/pipeline/settings_table.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>

namespace md = muscle_deformation;
namespace fs = std::filesystem;

namespace {

// A value of the setting's kind other than `current`, inside its range.
md::SettingValue anotherValue(const md::SettingSpec& spec, const md::SettingValue& current) {
  switch (spec.kind) {
    case md::SettingSpec::Kind::boolean:
      return !std::get<bool>(current);
    case md::SettingSpec::Kind::integer:
      return std::get<int>(current) == static_cast<int>(spec.max) ? static_cast<int>(spec.min)
                                                                  : static_cast<int>(spec.max);
    case md::SettingSpec::Kind::number:
      return std::get<double>(current) == spec.max ? spec.min : spec.max;
    case md::SettingSpec::Kind::choice:
      return spec.choices.front() == std::get<std::string>(current) ? spec.choices.back() : spec.choices.front();
    case md::SettingSpec::Kind::text:
      return std::get<std::string>(current) + "_changed";
  }
  return current;
}

}  // namespace

TEST(SettingsTable, EveryEntryIsUniqueAndChangesItsOwnFieldAndNoOther) {
  std::set<std::string> names;
  for (const md::SettingSpec& spec : md::coreSettingSpecs()) {
    EXPECT_TRUE(names.insert(spec.name).second) << spec.name << " twice";
    EXPECT_FALSE(spec.meaning.empty()) << spec.name;
    const md::CoreSettings defaults = md::nodeDefaultSettings();
    EXPECT_EQ(md::checkSetting(spec, spec.get(defaults)), "") << spec.name << ": the default is out of its own range";
    md::CoreSettings changed = defaults;
    const md::SettingValue value = anotherValue(spec, spec.get(defaults));
    ASSERT_EQ(md::checkSetting(spec, value), "") << spec.name;
    spec.set(changed, value);
    EXPECT_TRUE(spec.get(changed) == value) << spec.name << " does not read back what was written";
    for (const md::SettingSpec& other : md::coreSettingSpecs()) {
      if (other.name != spec.name) {
        EXPECT_TRUE(other.get(changed) == other.get(defaults)) << "writing " << spec.name << " changed " << other.name;
      }
    }
  }
}

TEST(SettingsTable, BadValuesAreDescribed) {
  const md::SettingSpec& particles = *md::findSetting("particles_per_fibre");
  EXPECT_EQ(md::checkSetting(particles, md::SettingValue(1)), "is 1, must be in [2, 10000]");
  EXPECT_EQ(md::checkSetting(particles, md::SettingValue(20.5)), "is 20.500000, must be an integer");
  EXPECT_EQ(md::checkSetting(particles, md::SettingValue(30.0)), "");
  EXPECT_EQ(md::checkSetting(particles, md::SettingValue(std::string("many"))), "must be an integer");
  const md::SettingSpec& rule = *md::findSetting("stopping_rule");
  EXPECT_EQ(md::checkSetting(rule, md::SettingValue(std::string("forever"))),
            "'forever' is not one of: iterations, displacement, time_budget, force_residual");
  EXPECT_EQ(md::checkSetting(*md::findSetting("collisions"), md::SettingValue(1)), "has the wrong type");
  EXPECT_EQ(md::checkSetting(*md::findSetting("dt_s"), md::SettingValue(true)), "must be a number");
  EXPECT_EQ(md::checkSetting(*md::findSetting("cold_start_sweeps"), md::SettingValue(0)), "is 0, must be in [1, 1000]");
  EXPECT_EQ(md::findSetting("no_such_setting"), nullptr);
}

TEST(SettingsTable, AYamlFileIsReadThroughTheTableAndABadValueNamesFileAndKey) {
  const fs::path path = fs::temp_directory_path() / "md_settings_table_test.yaml";
  std::ofstream(path) << "max_iterations: 45\nsolver: local_global\nfix_fibre_ends: false\ntf_wait_s: 3\n"
                         "attachment_distance_m: 0\nrefine_unfinished_frames: false\nthreads: 1\n";
  md::CoreSettings settings = md::nodeDefaultSettings();
  ASSERT_TRUE(settings.stream.refine_unfinished_frames);
  md::readSettingsYaml(path.string(), settings);
  EXPECT_EQ(settings.stream.stopping.sweeps.max_iterations, 45);
  EXPECT_FALSE(settings.stream.refine_unfinished_frames);
  EXPECT_EQ(settings.pipeline.threads, 1);
  EXPECT_EQ(settings.pipeline.simulation.solver_kind, md::SolverKind::local_global);
  EXPECT_FALSE(settings.pipeline.simulation.model.fix_fibre_ends);
  EXPECT_EQ(settings.pipeline.simulation.model.attachment_distance_m, 0.0);  // an integer where a number is asked

  std::ofstream(path) << "nearest_neighbours: 0\n";
  const std::string message =
      md::testing::errorMessageOf<std::invalid_argument>([&] { md::readSettingsYaml(path.string(), settings); });
  EXPECT_CONTAINS(message, path.string());
  EXPECT_CONTAINS(message, "nearest_neighbours is 0, must be in [1, 1000]");
}
