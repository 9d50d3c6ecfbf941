// What the command-line tools built on the core share (generate_fibres, prepare_scene): their options, numbers, the
// fibre generator's settings and package:// URIs found the way rosrun finds packages.
#pragma once

#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/preprocessing/fibre_generator.hpp"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation::tools {

// A wrong command line: the tool prints the message and its usage.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// A tool's main: prints `usage` for --help, else runs `run(argc, argv)`; a UsageError is printed with the usage, any
// other error alone, and either exits 1.
template <typename Run>
int runTool(const char* tool, const std::string& usage, int argc, char** argv, Run run) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << usage;
      return 0;
    }
  }
  try {
    return run(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << tool << ": " << e.what() << "\n" << usage;
  } catch (const std::exception& e) {
    std::cerr << tool << ": " << e.what() << "\n";
  }
  return 1;
}

// The command line as options and their values. An option in `value_options` takes the next word as its value (given
// twice is an error unless it is also in `repeatable`); one in `flags` takes none.
class Arguments {
 public:
  Arguments(int argc, char** argv, const std::set<std::string>& value_options, const std::set<std::string>& flags,
            const std::set<std::string>& repeatable = {}) {
    for (int i = 1; i < argc; ++i) {
      const std::string option = argv[i];
      if (flags.count(option)) {
        values_[option].push_back("");
        continue;
      }
      if (!value_options.count(option)) throw UsageError("unknown option '" + option + "'");
      if (i + 1 >= argc) throw UsageError(option + " needs a value");
      if (values_.count(option) && !repeatable.count(option)) throw UsageError(option + " given twice");
      values_[option].push_back(argv[++i]);
    }
  }
  bool has(const std::string& option) const { return values_.count(option) > 0; }
  const std::string& value(const std::string& option) const { return values_.at(option).front(); }
  std::vector<std::string> values(const std::string& option) const {
    return has(option) ? values_.at(option) : std::vector<std::string>{};
  }
  // The whole command as typed, for reports.
  static std::string joined(int argc, char** argv) {
    std::string out;
    for (int i = 0; i < argc; ++i) out += (i ? " " : "") + std::string(argv[i]);
    return out;
  }

 private:
  std::map<std::string, std::vector<std::string>> values_;
};

inline double parseNumber(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(value)) {
    throw UsageError(option + " expects a number, got '" + text + "'");
  }
  return value;
}

inline long parseCount(const std::string& option, const std::string& text, long minimum) {
  char* end = nullptr;
  const long value = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0') throw UsageError(option + " expects a whole number, got '" + text + "'");
  if (value < minimum) throw UsageError(option + " must be at least " + std::to_string(minimum));
  return value;
}

inline double parsePositive(const std::string& option, const std::string& text, const char* unit) {
  const double value = parseNumber(option, text);
  if (!(value > 0)) throw UsageError(option + " must be positive (" + unit + ")");
  return value;
}

// The fibre generator's options every tool takes, and their usage lines.
inline const std::set<std::string> kFibreOptionNames = {"--fibres", "--voxel", "--min-voxels", "--points",
                                                        "--attach", "--min-separation", "--seed-section"};
inline const char* const kFibreOptionsUsage =
    "  --fibres N        number of fibres (default 64)\n"
    "  --voxel M         voxel edge in metres (default 0.002; refined for small muscles, see --min-voxels)\n"
    "  --min-voxels N    refine the voxel until the interior holds N voxels (default 50000, 0 = off)\n"
    "  --points N        points per fibre (default 30)\n"
    "  --attach M        surface vertices within M metres of a bone form its patch (default 0.005)\n"
    "  --min-separation M  reseed one of two fibres closer than M metres (default 2e-5)\n"
    "  --seed-section S  largest (default): seed the fibres on the muscle's largest cross-section, in its belly;\n"
    "                    mid: on the field's mid-value (how the bundled fibres were made; a thin tendon takes it)\n";

inline FibreGeneratorOptions fibreOptions(const Arguments& args) {
  FibreGeneratorOptions options;
  if (args.has("--fibres")) options.fibre_count = static_cast<int>(parseCount("--fibres", args.value("--fibres"), 1));
  if (args.has("--points"))
    options.points_per_fibre = static_cast<int>(parseCount("--points", args.value("--points"), 2));
  if (args.has("--min-voxels")) options.min_inside_voxels = parseCount("--min-voxels", args.value("--min-voxels"), 0);
  if (args.has("--min-separation")) {
    options.min_separation = parseNumber("--min-separation", args.value("--min-separation"));
    if (options.min_separation < 0) throw UsageError("--min-separation must not be negative (metres)");
  }
  if (args.has("--voxel")) options.voxel_size = parsePositive("--voxel", args.value("--voxel"), "metres");
  if (args.has("--attach")) options.attachment_distance = parsePositive("--attach", args.value("--attach"), "metres");
  if (args.has("--seed-section")) {
    const std::string& rule = args.value("--seed-section");
    if (rule == "largest") {
      options.seed_section = SeedSection::largest;
    } else if (rule == "mid") {
      options.seed_section = SeedSection::mid_value;
    } else {
      throw UsageError("--seed-section is 'largest' or 'mid', not '" + rule + "'");
    }
  }
  return options;
}

// The <name> of the package.xml in `directory`, or "" when there is none.
inline std::string packageNameIn(const std::filesystem::path& directory) {
  std::ifstream in(directory / "package.xml");
  if (!in) return "";
  std::stringstream text;
  text << in.rdbuf();
  const std::string xml = text.str();
  const std::size_t open = xml.find("<name>"), close = xml.find("</name>");
  if (open == std::string::npos || close == std::string::npos || close < open) return "";
  std::string name = xml.substr(open + 6, close - open - 6);
  name.erase(0, name.find_first_not_of(" \t\n"));
  name.erase(name.find_last_not_of(" \t\n") + 1);
  return name;
}

namespace detail {
// Looks for the package below `folder` as rospack does: a folder with a package.xml is a package and is not searched
// further; hidden folders are skipped.
inline std::string findPackageBelow(const std::filesystem::path& folder, const std::string& package, int depth) {
  namespace fs = std::filesystem;
  std::error_code error;
  if (!fs::is_directory(folder, error)) return "";
  if (fs::exists(folder / "package.xml", error)) return packageNameIn(folder) == package ? folder.string() : "";
  if (depth == 0) return "";
  for (const fs::directory_entry& entry : fs::directory_iterator(folder, error)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name.front() == '.' || !entry.is_directory(error)) continue;
    const std::string found = findPackageBelow(entry.path(), package, depth - 1);
    if (!found.empty()) return found;
  }
  return "";
}
}  // namespace detail

// Resolves package://, file:// and paths (relative ones from `base_directory`). A package is looked up in `known`
// first (name -> directory), then under each folder of ROS_PACKAGE_PATH (as `rosrun` sets it), then in
// /usr/share/<name> (where Debian installs ROS packages).
inline UriResolver packageUriResolver(std::map<std::string, std::string> known, std::string base_directory) {
  return [known = std::move(known), base = std::move(base_directory)](const std::string& uri) {
    std::map<std::string, std::string> roots = known;
    const std::string prefix = "package://";
    if (uri.rfind(prefix, 0) == 0) {
      const std::string package = uri.substr(prefix.size(), uri.find('/', prefix.size()) - prefix.size());
      if (!roots.count(package)) {
        std::string found;
        const char* path = std::getenv("ROS_PACKAGE_PATH");
        std::stringstream folders(path ? path : "");
        for (std::string folder; found.empty() && std::getline(folders, folder, ':');)
          if (!folder.empty()) found = detail::findPackageBelow(folder, package, 4);
        if (found.empty() && packageNameIn("/usr/share/" + package) == package) found = "/usr/share/" + package;
        if (found.empty())
          throw SceneError("'" + uri + "': package '" + package + "' not found: give its folder with --package-dir, " +
                           "or source the workspace that has it so that ROS_PACKAGE_PATH lists it");
        roots[package] = found;
      }
    }
    return makeUriResolver(roots, base)(uri);
  };
}

}  // namespace muscle_deformation::tools
