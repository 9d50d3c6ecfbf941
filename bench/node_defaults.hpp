// The node's defaults (config/muscle_deformation.yaml) as core settings, read through the core's settings table like
// the node's parameters, so the benchmarks that speak for the node run what the node runs.
#pragma once

#include "muscle_deformation/core/pipeline/pose_stream.hpp"
#include "muscle_deformation/core/pipeline/settings_table.hpp"
#include "muscle_deformation/core/pipeline/simulation.hpp"

#include <string>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace bench {

struct NodeDefaults {
  muscle_deformation::SimulationSettings simulation;
  muscle_deformation::PoseStreamSettings stream;  // warm / cold / unchanged policy of the node's stream
};

inline NodeDefaults loadNodeDefaults() {
  namespace md = muscle_deformation;
  md::CoreSettings settings = md::nodeDefaultSettings();
  md::readSettingsYaml(std::string(MD_PACKAGE_DIR) + "/config/muscle_deformation.yaml", settings);
  NodeDefaults defaults;
  defaults.simulation = settings.pipeline.simulation;
  md::shareStoppingRule(defaults.simulation);  // one set of stopping parameters, as the node
  defaults.stream = settings.stream;
  return defaults;
}

}  // namespace bench
