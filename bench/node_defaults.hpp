// The node's defaults (config/muscle_deformation.yaml) as core settings, so the benchmarks that speak for the node
// run what the node runs. Only the keys the core models; the string-valued solver rules the core has no parser for
// are checked against the core defaults instead of converted, and a mismatch stops the benchmark.
#pragma once

#include "muscle_deformation/core/collision/collision.hpp"
#include "muscle_deformation/core/pipeline/pose_stream.hpp"
#include "muscle_deformation/core/pipeline/simulation.hpp"
#include "muscle_deformation/core/model/spring_layout.hpp"

#include <yaml-cpp/yaml.h>

#include <stdexcept>
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
  const std::string path = std::string(MD_PACKAGE_DIR) + "/config/muscle_deformation.yaml";
  const YAML::Node yaml = YAML::LoadFile(path);
  const auto require_same = [&](const char* key, const std::string& core_default) {
    const std::string value = yaml[key].as<std::string>();
    if (value != core_default)
      throw std::runtime_error(path + ": " + key + " is '" + value + "' but the benchmark runs the core default '" +
                               core_default + "'");
  };
  require_same("dt_rule", "fixed");
  require_same("mass_rule", "stiffness_scaled");
  require_same("stopping_rule", "iterations");
  NodeDefaults defaults;
  md::SimulationSettings& s = defaults.simulation;
  s.model.particles_per_fibre = yaml["particles_per_fibre"].as<int>();
  s.model.spring_layout = md::springLayoutFromString(yaml["spring_layout"].as<std::string>());
  s.model.nearest_neighbours = yaml["nearest_neighbours"].as<int>();
  s.model.attachment_distance_m = yaml["attachment_distance_m"].as<double>();
  s.model.fix_fibre_ends = yaml["fix_fibre_ends"].as<bool>();
  s.model.spring_material_n = yaml["spring_material_n"].as<double>();
  s.model.density_kg_per_m3 = yaml["density_kg_per_m3"].as<double>();
  s.solver.dt_s = yaml["dt_s"].as<double>();
  s.solver.damping_scale = yaml["damping_scale"].as<double>();
  s.solver.max_iterations = yaml["max_iterations"].as<int>();
  s.solver_kind = md::solverKindFromString(yaml["solver"].as<std::string>());
  s.local_global.lbfgs_history = yaml["lbfgs_history"].as<int>();
  s.local_global.volume_weight = yaml["volume_weight"].as<double>();
  s.local_global.max_iterations = s.solver.max_iterations;
  s.collisions = yaml["collisions"].as<bool>();
  require_same("broad_phase", md::toString(s.collision.broad_phase));
  s.collision.bone_reach_margin_m = yaml["bone_reach_margin_m"].as<double>();
  defaults.stream.warm_start = yaml["warm_start"].as<bool>();
  defaults.stream.unchanged_translation_m = yaml["unchanged_translation_m"].as<double>();
  defaults.stream.unchanged_rotation_rad = yaml["unchanged_rotation_rad"].as<double>();
  defaults.stream.max_bone_speed_m_per_s = yaml["max_bone_speed_m_per_s"].as<double>();
  defaults.stream.max_bone_angular_speed_rad_per_s = yaml["max_bone_angular_speed_rad_per_s"].as<double>();
  return defaults;
}

}  // namespace bench
