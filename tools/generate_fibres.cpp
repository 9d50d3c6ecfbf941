// generate_fibres: muscle fibres inside a closed surface (Laplace field + streamlines, Choi & Blemker 2013).
//
//   generate_fibres --surface muscle.stl [--origin-bone a.stl] [--insertion-bone b.stl] --out fibres.vtk
//                   [--fibres 64] [--voxel 0.002] [--scale 1] [--points 30] [--attach 0.005] [--min-voxels 50000]
//   generate_fibres --scene config/scenes/right_hip_thigh.yaml [--package-dir .] [--muscles a,b|tag] [--report r.json]
//   (paths in the scene start at its folder; package:// URIs are looked up in --package-dir, then ROS_PACKAGE_PATH)
//
// Exit status: 0 = fibres written and every check passed, 1 = bad input or a muscle failed (message on stderr; the
// other muscles are still done), 2 = fibres written but some check failed (listed on stdout).
#include "command_line.hpp"
#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/io/surface_repair.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/preprocessing/fibre_generator.hpp"
#include "muscle_deformation/preprocessing/scene_directory.hpp"

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace md = muscle_deformation;
namespace fs = std::filesystem;
using md::tools::UsageError;

namespace {

const std::string kUsage = std::string(
    "usage:\n"
    "  generate_fibres --surface MUSCLE [--origin-bone BONE] [--insertion-bone BONE] --out FIBRES.vtk [options]\n"
    "  generate_fibres --scene SCENE.yaml [--package-dir DIR] [--muscles NAME_OR_TAG,...] [--report FILE.json]\n"
    "                  [options]\n"
    "Surfaces: .stl .ply .vtk .vtp .obj (muscle: closed, 2-manifold). Output: VTK legacy polylines, metres,\n"
    "origin -> insertion; checks that failed are written into the file's title line, and the node warns of them.\n"
    "Without bones the origin is the end of the principal axis with greater Z.\n"
    "Scene mode: relative paths in the scene start at the scene file's folder; package:// URIs (the URDF's meshes)\n"
    "are looked up in --package-dir (a folder with a package.xml), then under ROS_PACKAGE_PATH. A muscle that fails\n"
    "does not stop the others.\n"
    "options:\n") +
    md::tools::kFibreOptionsUsage +
    "  --decimals N      decimal places of the written coordinates in metres (default 5 = 10 um)\n"
    "  --scale S         multiply input coordinates by S to get metres (default 1; 0.001 for mm)\n"
    "  --no-repair       refuse a muscle surface that is not closed instead of repairing it (holes, non-manifold\n"
    "                    edges, degenerate or flipped triangles, loose pieces; every change is printed)\n"
    "  --help            this text\n"
    "Exit status: 0 = fibres written and every check passed, 1 = bad input or a muscle failed (message on stderr),\n"
    "2 = fibres written but some check failed (listed on stdout).\n";

std::vector<std::string> splitList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
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

std::string jsonEntry(const std::string& name, const md::FibreGenerationResult& r, double seconds) {
  const md::FibreCheckReport& c = r.checks;
  std::ostringstream o;
  o << std::setprecision(6);
  o << "  " << md::doubleQuoted(name) << ": {\"fibres\": " << c.fibre_count << ", \"points_per_fibre\": "
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
  std::set<std::string> value_options = {"--surface", "--origin-bone", "--insertion-bone", "--out", "--decimals",
                                         "--scale", "--scene", "--package-dir", "--muscles", "--report"};
  value_options.insert(md::tools::kFibreOptionNames.begin(), md::tools::kFibreOptionNames.end());
  const md::tools::Arguments args(argc, argv, value_options, {"--no-repair"});
  const auto has = [&](const char* option) { return args.has(option); };
  const md::FibreGeneratorOptions options = md::tools::fibreOptions(args);
  const int decimals = has("--decimals") ? static_cast<int>(md::tools::parseCount("--decimals", args.value("--decimals"), 1)) : 5;
  const double scale = has("--scale") ? md::tools::parsePositive("--scale", args.value("--scale"), "to metres") : 1.0;
  const bool repair = !has("--no-repair");

  if (has("--scene") == has("--surface")) throw UsageError("give either --surface or --scene");
  if (has("--surface")) {
    for (const char* k : {"--package-dir", "--muscles", "--report"})
      if (has(k)) throw UsageError(std::string(k) + " is for --scene mode");
    if (!has("--out")) throw UsageError("--out FIBRES.vtk is required with --surface");
    const Timer timer;
    const md::TriangleMesh surface = loadMuscleSurface(args.value("--surface"), scale, repair, "").mesh;
    md::TriangleMesh origin, insertion;
    if (has("--origin-bone")) origin = md::loadTriangleMesh(args.value("--origin-bone"), scale);
    if (has("--insertion-bone")) insertion = md::loadTriangleMesh(args.value("--insertion-bone"), scale);
    const md::FibreGenerationResult result =
        md::generateFibres(surface, has("--origin-bone") ? &origin : nullptr,
                           has("--insertion-bone") ? &insertion : nullptr, options);
    md::saveFibresVtk(args.value("--out"), result.fibres, decimals, result.checks.failures);
    printResult(args.value("--out"), result, timer.seconds());
    return result.checks.passed() ? 0 : 2;
  }

  for (const char* k : {"--out", "--origin-bone", "--insertion-bone"})
    if (has(k)) throw UsageError(std::string(k) + " is for --surface mode (the scene names files and bones)");
  if (has("--scale")) throw UsageError("--scale is for --surface mode (scene files are in metres)");
  std::map<std::string, std::string> packages;
  if (has("--package-dir")) {
    const std::string& directory = args.value("--package-dir");
    const std::string name = md::tools::packageNameIn(directory);
    if (name.empty()) throw UsageError("--package-dir " + directory + ": no package.xml with a <name> there");
    packages[name] = directory;
  }
  const Timer total;
  const std::string& scene_file = args.value("--scene");
  const md::SceneDescription scene = md::loadSceneDescription(scene_file);
  const md::UriResolver resolve = md::tools::packageUriResolver(packages, scene.folder);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(scene, scene.urdf_file, resolve));
  const std::vector<md::MuscleDescription> muscles =
      md::selectMuscles(scene, has("--muscles") ? splitList(args.value("--muscles")) : std::vector<std::string>{});
  std::map<std::string, md::TriangleMesh> bones;
  for (md::Bone& bone : md::loadBones(scene, skeleton, resolve)) bones[bone.name] = std::move(bone.surface);
  auto boneOf = [&](const std::string& link, const std::string& muscle) -> const md::TriangleMesh* {
    const auto it = bones.find(link);
    if (it != bones.end()) return &it->second;
    std::cout << muscle << ": link '" << link << "' has no collision mesh: patch from the principal axis\n";
    return nullptr;
  };
  std::cout << "scene " << scene_file << ": " << muscles.size() << " muscles, " << bones.size() << " bones loaded in "
            << std::fixed << std::setprecision(1) << total.seconds() << " s\n";

  std::vector<std::string> entries, failed_checks, failed;
  for (const md::MuscleDescription& m : muscles) {
    const Timer timer;
    // One muscle's bad file or shape is its own failure: the others are still made, and the report still written.
    try {
      const LoadedSurface loaded =
          loadMuscleSurface(md::resolveScenePath(scene, m.surface_file, resolve), 1.0, repair, m.name);
      if (loaded.repaired && !scene.repair_surfaces)
        std::cout << m.name << ": set 'repair_surfaces: true' in " << scene_file
                  << " so that the node repairs the surface the same way\n";
      const md::FibreGenerationResult result =
          md::generateFibres(loaded.mesh, boneOf(m.origin_bone, m.name), boneOf(m.insertion_bone, m.name), options);
      const std::string out = md::resolveScenePath(scene, m.fibre_file, resolve);
      if (fs::path(out).has_parent_path()) fs::create_directories(fs::path(out).parent_path());
      md::saveFibresVtk(out, result.fibres, decimals, result.checks.failures);
      printResult(m.name + " -> " + m.fibre_file, result, timer.seconds());
      entries.push_back(jsonEntry(m.name, result, timer.seconds()));
      if (!result.checks.passed()) failed_checks.push_back(m.name);
    } catch (const std::exception& e) {
      std::cerr << "generate_fibres: muscle '" << m.name << "' FAILED: " << e.what() << "\n";
      entries.push_back("  " + md::doubleQuoted(m.name) + ": {\"error\": " + md::doubleQuoted(e.what()) + "}");
      failed.push_back(m.name);
    }
    std::cout << std::flush;
  }
  if (has("--report")) {
    std::ofstream report(args.value("--report"));
    if (!report) throw std::runtime_error(args.value("--report") + ": cannot open for writing");
    report << "{\n";
    for (std::size_t i = 0; i < entries.size(); ++i) report << entries[i] << (i + 1 < entries.size() ? ",\n" : "\n");
    report << "}\n";
    if (!report) throw std::runtime_error(args.value("--report") + ": write failed");
  }
  std::cout << muscles.size() << " muscles in " << std::setprecision(1) << total.seconds() << " s";
  if (failed.empty() && failed_checks.empty()) {
    std::cout << ", every check passed\n";
    return 0;
  }
  for (const auto& [what, names] : {std::pair{"; FAILED (no fibres written):", &failed},
                                    std::pair{"; checks FAILED for:", &failed_checks}}) {
    if (names->empty()) continue;
    std::cout << what;
    for (const auto& name : *names) std::cout << " " << name;
  }
  std::cout << "\n";
  return failed.empty() ? 2 : 1;
}

}  // namespace

int main(int argc, char** argv) { return md::tools::runTool("generate_fibres", kUsage, argc, argv, run); }
