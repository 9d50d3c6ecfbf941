// The text files of a prepared scene directory (scene_preparation.hpp): scene.yaml, the node's scene with every path
// relative to it; report.md, what was done to each muscle and bone and what was measured; view.rviz, rviz framing the
// scene with the bones in a bone colour (the node's ~bones markers) and the muscles in their scene colours.
#pragma once

#include "muscle_deformation/preprocessing/scene_preparation.hpp"

namespace muscle_deformation {

inline constexpr char kSceneFileName[] = "scene.yaml";
inline constexpr char kReportFileName[] = "report.md";
inline constexpr char kRvizFileName[] = "view.rviz";

// `text` as a double-quoted string, valid in YAML and in JSON: file names and paths may hold ':' or '#'.
std::string doubleQuoted(const std::string& text);

// What carving a bone's copy did, in a line: e.g. "volume 355.1 ml -> 352.0 ml (-0.87 %), carved up to 7.9 mm deep,
// 4128 triangles (voxel 0.50 mm, clearance 0.50 mm)".
std::string describeCarve(const LevelSetRebuildReport& carve);

// Writes the three files into preparation.out_dir (scene.yaml only when a muscle was prepared: a scene needs one).
// Throws std::runtime_error naming a file that cannot be written.
void writeSceneDirectory(const ScenePreparation& preparation);

}  // namespace muscle_deformation
