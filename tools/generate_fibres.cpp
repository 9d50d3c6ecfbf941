// generate_fibres: muscle fibres inside a closed surface (Laplace field + streamlines, Choi & Blemker 2013).
//
//   generate_fibres --surface muscle.stl [--origin-bone a.stl] [--insertion-bone b.stl] --out fibres.vtk
//                   [--fibres 64] [--voxel 0.002] [--scale 1] [--points 30] [--attach 0.005] [--min-voxels 50000]
//   generate_fibres --scene config/scenes/right_hip_thigh.yaml --package-dir . [--muscles a,b|tag] [--report r.json]
//   (paths in the scene start at its folder; --package-dir resolves package:// URIs)
//
// Exit status: 0 = fibres written and every check passed, 1 = bad input or failure (message on stderr),
// 2 = fibres written but some check failed (listed on stdout).
#include "muscle_deformation/preprocessing/fibre_generator.hpp"
#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/io/surface_repair.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace md = muscle_deformation;
namespace fs = std::filesystem;

namespace {

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

const char* const kUsage =
    "usage:\n"
    "  generate_fibres --surface MUSCLE [--origin-bone BONE] [--insertion-bone BONE] --out FIBRES.vtk [options]\n"
    "  generate_fibres --scene SCENE.yaml [--package-dir DIR] [--muscles NAME_OR_TAG,...] [--report FILE.json]\n"
    "                  [options]\n"
    "Surfaces: .stl .ply .vtk .vtp .obj (muscle: closed, 2-manifold). Output: VTK legacy polylines, metres,\n"
    "origin -> insertion. Without bones the origin is the end of the principal axis with greater Z.\n"
    "Scene mode: relative paths in the scene start at the scene file's folder; --package-dir (default .) is the\n"
    "package directory that package:// URIs (the URDF's meshes) point into.\n"
    "options:\n"
    "  --fibres N        number of fibres (default 64)\n"
    "  --voxel M         voxel edge in metres (default 0.002; refined for small muscles, see --min-voxels)\n"
    "  --min-voxels N    refine the voxel until the interior holds N voxels (default 50000, 0 = off)\n"
    "  --points N        points per fibre (default 30)\n"
    "  --attach M        surface vertices within M metres of a bone form its patch (default 0.005)\n"
    "  --min-separation M  reseed one of two fibres closer than M metres (default 2e-5)\n"
    "  --decimals N      decimal places of the written coordinates in metres (default 5 = 10 um)\n"
    "  --scale S         multiply input coordinates by S to get metres (default 1; 0.001 for mm)\n"
    "  --no-repair       refuse a muscle surface that is not closed instead of repairing it (holes, non-manifold\n"
    "                    edges, degenerate or flipped triangles, loose pieces; every change is printed)\n"
    "  --help            this text\n";

double parseNumber(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(value)) {
    throw UsageError(option + " expects a number, got '" + text + "'");
  }
  return value;
}

long parseCount(const std::string& option, const std::string& text, long minimum) {
  char* end = nullptr;
  const long value = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0') throw UsageError(option + " expects a whole number, got '" + text + "'");
  if (value < minimum) throw UsageError(option + " must be at least " + std::to_string(minimum));
  return value;
}

std::vector<std::string> splitList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

// The catkin package name of a package directory (package.xml <name>), for package:// mesh URIs.
std::string packageName(const std::string& directory) {
  std::ifstream in(fs::path(directory) / "package.xml");
  std::stringstream text;
  text << in.rdbuf();
  const std::string xml = text.str();
  const std::size_t open = xml.find("<name>"), close = xml.find("</name>");
  if (open == std::string::npos || close == std::string::npos || close < open) {
    throw UsageError("--package-dir " + directory + ": no package.xml with a <name> there");
  }
  std::string name = xml.substr(open + 6, close - open - 6);
  name.erase(0, name.find_first_not_of(" \t\n"));
  name.erase(name.find_last_not_of(" \t\n") + 1);
  return name;
}

struct Timer {
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  double seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
};

void printResult(const std::string& name, const md::FibreGenerationResult& r, double seconds) {
  std::cout << name << ": voxel " << std::fixed << std::setprecision(2) << r.voxel_size * 1e3 << " mm, "
            << r.inside_voxels << " voxels, CG " << r.solver_iterations << " iterations, patches "
            << r.patches.origin_vertices.size() << (r.patches.origin_from_bone ? " (bone)" : " (axis end)") << " / "
            << r.patches.insertion_vertices.size() << (r.patches.insertion_from_bone ? " (bone)" : " (axis end)")
            << " vertices, " << std::setprecision(1) << seconds << " s\n  " << r.checks.describe() << "\n";
  for (const auto& note : r.patches.notes) std::cout << "  note: " << note << "\n";
  for (const auto& warning : r.warnings) std::cout << "  warning: " << warning << "\n";
}

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

std::string jsonEntry(const std::string& name, const md::FibreGenerationResult& r, double seconds) {
  const md::FibreCheckReport& c = r.checks;
  std::ostringstream o;
  o << std::setprecision(6);
  o << "  " << jsonString(name) << ": {\"fibres\": " << c.fibre_count << ", \"points_per_fibre\": "
    << (c.fibre_count ? c.points / c.fibre_count : 0) << ", \"length_min_mm\": " << c.min_length * 1e3
    << ", \"length_max_mm\": " << c.max_length * 1e3 << ", \"length_mean_mm\": " << c.mean_length * 1e3
    << ", \"voxel_mm\": " << r.voxel_size * 1e3 << ", \"inside_voxels\": " << r.inside_voxels
    << ", \"cg_iterations\": " << r.solver_iterations << ", \"origin_patch\": \""
    << (r.patches.origin_from_bone ? "bone" : "axis end") << "\", \"insertion_patch\": \""
    << (r.patches.insertion_from_bone ? "bone" : "axis end") << "\", \"points_outside\": " << c.points_outside
    << ", \"max_outside_mm\": " << c.max_outside_distance * 1e3 << ", \"max_start_mm\": " << c.max_start_distance * 1e3
    << ", \"max_end_mm\": " << c.max_end_distance * 1e3 << ", \"min_pair_distance_mm\": "
    << c.min_pairwise_distance * 1e3 << ", \"cross_section_cm2\": " << c.cross_section_area * 1e4
    << ", \"coverage\": " << c.coverage << ", \"coverage_radius_mm\": " << c.coverage_radius * 1e3
    << ", \"max_gap_mm\": " << c.max_gap * 1e3 << ", \"failed_seeds\": " << r.failed_seeds
    << ", \"passed\": " << (c.passed() ? "true" : "false") << ", \"seconds\": " << seconds << "}";
  return o.str();
}

struct LoadedSurface {
  md::TriangleMesh mesh;
  bool repaired = false;
};

// Scene preparation repairs what it can (and says what it changed): real segmentations often have a few defects.
LoadedSurface loadMuscleSurface(const std::string& path, double scale, bool repair, const std::string& muscle) {
  if (!repair) return {md::loadClosedSurface(path, scale), false};
  md::SurfaceRepairReport report;
  LoadedSurface loaded{md::loadRepairedClosedSurface(path, scale, report), report.changed()};
  if (loaded.repaired)
    std::cout << (muscle.empty() ? "" : muscle + ": ") << path << " repaired: " << report.describe() << "\n";
  return loaded;
}

int run(int argc, char** argv) {
  std::map<std::string, std::string> args;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "--help" || key == "-h") {
      std::cout << kUsage;
      std::exit(0);
    }
    if (key == "--no-repair") {  // the one option without a value
      args[key] = "";
      continue;
    }
    static const char* const known[] = {"--surface", "--origin-bone", "--insertion-bone", "--out", "--fibres",
                                        "--voxel", "--min-voxels", "--min-separation", "--decimals", "--points", "--attach", "--scale", "--scene",
                                        "--package-dir", "--muscles", "--report"};
    bool ok = false;
    for (const char* k : known) ok = ok || key == k;
    if (!ok) throw UsageError("unknown option '" + key + "'");
    if (i + 1 >= argc) throw UsageError(key + " needs a value");
    if (args.count(key)) throw UsageError(key + " given twice");
    args[key] = argv[++i];
  }
  auto has = [&](const char* k) { return args.count(k) > 0; };

  md::FibreGeneratorOptions options;
  if (has("--fibres")) options.fibre_count = static_cast<int>(parseCount("--fibres", args["--fibres"], 1));
  if (has("--points")) options.points_per_fibre = static_cast<int>(parseCount("--points", args["--points"], 2));
  if (has("--min-voxels")) options.min_inside_voxels = parseCount("--min-voxels", args["--min-voxels"], 0);
  int decimals = 5;
  if (has("--decimals")) decimals = static_cast<int>(parseCount("--decimals", args["--decimals"], 1));
  if (has("--min-separation")) {
    options.min_separation = parseNumber("--min-separation", args["--min-separation"]);
    if (options.min_separation < 0) throw UsageError("--min-separation must not be negative (metres)");
  }
  if (has("--voxel")) {
    options.voxel_size = parseNumber("--voxel", args["--voxel"]);
    if (!(options.voxel_size > 0)) throw UsageError("--voxel must be positive (metres)");
  }
  if (has("--attach")) {
    options.attachment_distance = parseNumber("--attach", args["--attach"]);
    if (!(options.attachment_distance > 0)) throw UsageError("--attach must be positive (metres)");
  }
  double scale = 1.0;
  if (has("--scale")) {
    scale = parseNumber("--scale", args["--scale"]);
    if (!(scale > 0)) throw UsageError("--scale must be positive");
  }

  if (has("--scene") == has("--surface")) throw UsageError("give either --surface or --scene");
  if (has("--surface")) {
    for (const char* k : {"--package-dir", "--muscles", "--report"})
      if (has(k)) throw UsageError(std::string(k) + " is for --scene mode");
    if (!has("--out")) throw UsageError("--out FIBRES.vtk is required with --surface");
    const Timer timer;
    const md::TriangleMesh surface = loadMuscleSurface(args["--surface"], scale, !has("--no-repair"), "").mesh;
    md::TriangleMesh origin, insertion;
    if (has("--origin-bone")) origin = md::loadTriangleMesh(args["--origin-bone"], scale);
    if (has("--insertion-bone")) insertion = md::loadTriangleMesh(args["--insertion-bone"], scale);
    const md::FibreGenerationResult result =
        md::generateFibres(surface, has("--origin-bone") ? &origin : nullptr,
                           has("--insertion-bone") ? &insertion : nullptr, options);
    md::saveFibresVtk(args["--out"], result.fibres, decimals);
    printResult(args["--out"], result, timer.seconds());
    return result.checks.passed() ? 0 : 2;
  }

  for (const char* k : {"--out", "--origin-bone", "--insertion-bone"})
    if (has(k)) throw UsageError(std::string(k) + " is for --surface mode (the scene names files and bones)");
  if (has("--scale")) throw UsageError("--scale is for --surface mode (scene files are in metres)");
  const std::string package = has("--package-dir") ? args["--package-dir"] : ".";
  const Timer total;
  const md::SceneDescription scene = md::loadSceneDescription(args["--scene"]);
  const md::UriResolver resolve = md::makeUriResolver({{packageName(package), package}}, package);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(scene, scene.urdf_file, resolve));
  const std::vector<md::MuscleDescription> muscles =
      md::selectMuscles(scene, has("--muscles") ? splitList(args["--muscles"]) : std::vector<std::string>{});
  std::map<std::string, md::TriangleMesh> bones;
  for (md::Bone& bone : md::loadBones(skeleton, resolve, scene.frame)) bones[bone.name] = std::move(bone.surface);
  auto boneOf = [&](const std::string& link, const std::string& muscle) -> const md::TriangleMesh* {
    const auto it = bones.find(link);
    if (it != bones.end()) return &it->second;
    std::cout << muscle << ": link '" << link << "' has no collision mesh: patch from the principal axis\n";
    return nullptr;
  };
  std::cout << "scene " << args["--scene"] << ": " << muscles.size() << " muscles, " << bones.size()
            << " bones loaded in " << std::fixed << std::setprecision(1) << total.seconds() << " s\n";

  std::vector<std::string> entries, failed;
  for (const md::MuscleDescription& m : muscles) {
    const Timer timer;
    const LoadedSurface loaded =
        loadMuscleSurface(md::resolveScenePath(scene, m.surface_file, resolve), 1.0, !has("--no-repair"), m.name);
    const md::TriangleMesh& surface = loaded.mesh;
    if (loaded.repaired && !scene.repair_surfaces)
      std::cout << m.name << ": set 'repair_surfaces: true' in " << args["--scene"]
                << " so that the node repairs the surface the same way\n";
    md::FibreGenerationResult result;
    try {
      result = md::generateFibres(surface, boneOf(m.origin_bone, m.name), boneOf(m.insertion_bone, m.name), options);
    } catch (const md::FibreGenerationError& e) {
      throw md::FibreGenerationError("muscle '" + m.name + "': " + e.what());
    }
    const std::string out = md::resolveScenePath(scene, m.fibre_file, resolve);
    if (fs::path(out).has_parent_path()) fs::create_directories(fs::path(out).parent_path());
    md::saveFibresVtk(out, result.fibres, decimals);
    printResult(m.name + " -> " + m.fibre_file, result, timer.seconds());
    std::cout << std::flush;
    entries.push_back(jsonEntry(m.name, result, timer.seconds()));
    if (!result.checks.passed()) failed.push_back(m.name);
  }
  if (has("--report")) {
    std::ofstream report(args["--report"]);
    if (!report) throw std::runtime_error(args["--report"] + ": cannot open for writing");
    report << "{\n";
    for (std::size_t i = 0; i < entries.size(); ++i) report << entries[i] << (i + 1 < entries.size() ? ",\n" : "\n");
    report << "}\n";
    if (!report) throw std::runtime_error(args["--report"] + ": write failed");
  }
  std::cout << muscles.size() << " muscles in " << std::setprecision(1) << total.seconds() << " s";
  if (failed.empty()) {
    std::cout << ", every check passed\n";
    return 0;
  }
  std::cout << "; checks FAILED for:";
  for (const auto& f : failed) std::cout << " " << f;
  std::cout << "\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "generate_fibres: " << e.what() << "\n" << kUsage;
  } catch (const std::exception& e) {
    std::cerr << "generate_fibres: " << e.what() << "\n";
  }
  return 1;
}
