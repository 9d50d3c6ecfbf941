#include "muscle_deformation/core/scene/joint_trajectory.hpp"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

namespace muscle_deformation {
namespace {

std::vector<std::string> splitCommas(const std::string& line) {
  std::vector<std::string> fields;
  std::stringstream stream(line);
  std::string field;
  while (std::getline(stream, field, ',')) {
    const auto first = field.find_first_not_of(" \t\r");
    const auto last = field.find_last_not_of(" \t\r");
    fields.push_back(first == std::string::npos ? std::string() : field.substr(first, last - first + 1));
  }
  if (!line.empty() && line.back() == ',') fields.emplace_back();
  return fields;
}

}  // namespace

JointTrajectory loadJointTrajectoryCsv(const std::string& path) {
  std::ifstream file(path);
  if (!file) throw SceneError(path + ": cannot open the joint trajectory file");
  const auto fail = [&](int line, const std::string& what) {
    throw SceneError(path + ":" + std::to_string(line) + ": " + what);
  };

  JointTrajectory trajectory;
  std::string line;
  int line_number = 0;
  bool have_header = false;
  while (std::getline(file, line)) {
    ++line_number;
    if (line.find_first_not_of(" \t\r") == std::string::npos || line[line.find_first_not_of(" \t")] == '#') continue;
    const std::vector<std::string> fields = splitCommas(line);
    if (!have_header) {
      if (fields.empty() || fields[0] != "time_s") fail(line_number, "the header must start with time_s");
      std::set<std::string> seen;
      for (std::size_t i = 1; i < fields.size(); ++i) {
        if (fields[i].empty()) fail(line_number, "column " + std::to_string(i + 1) + " has no joint name");
        if (!seen.insert(fields[i]).second) fail(line_number, "joint " + fields[i] + " appears twice");
        trajectory.joint_names.push_back(fields[i]);
      }
      if (trajectory.joint_names.empty()) fail(line_number, "the header names no joints");
      have_header = true;
      continue;
    }
    if (fields.size() != trajectory.joint_names.size() + 1) {
      fail(line_number, "expected " + std::to_string(trajectory.joint_names.size() + 1) + " columns, found " +
                            std::to_string(fields.size()));
    }
    std::vector<double> values(fields.size());
    for (std::size_t i = 0; i < fields.size(); ++i) {
      char* end = nullptr;
      errno = 0;
      values[i] = std::strtod(fields[i].c_str(), &end);
      if (fields[i].empty() || *end != '\0' || errno == ERANGE || !std::isfinite(values[i])) {
        fail(line_number, "column " + std::to_string(i + 1) + " ('" + fields[i] + "') is not a finite number");
      }
    }
    if (!trajectory.times_s.empty() && values[0] <= trajectory.times_s.back()) {
      fail(line_number, "time_s does not increase");
    }
    trajectory.times_s.push_back(values[0]);
    JointValues frame;
    for (std::size_t i = 0; i < trajectory.joint_names.size(); ++i) frame[trajectory.joint_names[i]] = values[i + 1];
    trajectory.frames.push_back(std::move(frame));
  }
  if (!have_header) throw SceneError(path + ": no header line (time_s,<joint>,...)");
  if (trajectory.frames.empty()) throw SceneError(path + ": no frames after the header");
  return trajectory;
}

std::vector<std::size_t> evenlySpacedFrames(std::size_t frame_count, std::size_t count) {
  std::vector<std::size_t> frames;
  if (frame_count == 0 || count == 0) return frames;
  if (count == 1 || frame_count == 1) return {0};
  count = std::min(count, frame_count);
  for (std::size_t i = 0; i < count; ++i) {
    frames.push_back(static_cast<std::size_t>(std::llround(static_cast<double>(i) * (frame_count - 1) / (count - 1))));
  }
  return frames;
}

}  // namespace muscle_deformation
