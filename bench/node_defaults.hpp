// The node's defaults (config/muscle_deformation.yaml) as core settings, read through the core's settings table like
// the node's parameters, so the benchmarks that speak for the node run what the node runs: its pipeline settings
// (model, solver, collision, threads, surfaces) and its stream session settings (the warm / cold / unchanged policy,
// how a frame's solve stops, the refinement of unfinished frames).
#pragma once

#include "muscle_deformation/core/pipeline/settings_table.hpp"

#include <string>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace bench {

inline muscle_deformation::CoreSettings loadNodeDefaults() {
  muscle_deformation::CoreSettings settings = muscle_deformation::nodeDefaultSettings();
  muscle_deformation::readSettingsYaml(std::string(MD_PACKAGE_DIR) + "/config/muscle_deformation.yaml", settings);
  return settings;
}

}  // namespace bench
