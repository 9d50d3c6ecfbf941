// prepare_scene: a scene directory the node runs as it is, from segmented muscle surfaces and a skeleton URDF.
//
//   rosrun muscle_deformation prepare_scene --urdf SKELETON.urdf --muscle NAME:MESH:ORIGIN_LINK:INSERTION_LINK
//       [--muscle ...] --out DIR [--scale S] [--frame LINK] [--package-dir DIR] [attachment site options]
//       [fibre options]
//
// The work is the preprocessing library's (scene_preparation.hpp); this reads the command line and prints a summary.
// Exit status: 0 = every muscle prepared and every bone usable (fibre checks that failed are in report.md), 1 = a muscle
// could not be prepared or a bone mesh is unusable (after preparing all the others; report.md says why) or bad input.
#include "command_line.hpp"
#include "muscle_deformation/preprocessing/scene_directory.hpp"
#include "muscle_deformation/preprocessing/scene_preparation.hpp"

#include <filesystem>
#include <iostream>
#include <map>
#include <set>
#include <string>

namespace md = muscle_deformation;

namespace {

namespace fs = std::filesystem;
using UsageError = md::tools::UsageError;

// What --help prints, and what a wrong command line is answered with after the error.
const std::string kUsage = std::string(
    "usage: prepare_scene --urdf SKELETON.urdf --muscle NAME:MESH:ORIGIN_LINK:INSERTION_LINK [--muscle ...]\n"
    "                     --out DIR [--scale S] [--frame LINK] [--package-dir DIR] [options]\n"
    "Reads each muscle surface (.stl .ply .vtk .vtp .obj), repairs small defects (holes, non-manifold edges,\n"
    "degenerate, duplicated or flipped triangles, loose pieces) or refuses it saying why, checks that the URDF's\n"
    "bone meshes (its links' <collision> meshes) are closed and repairs copies of those that are not, generates the\n"
    "fibres and writes DIR/scene.yaml (paths relative to it), DIR/meshes/, DIR/fibres/, DIR/report.md and\n"
    "DIR/view.rviz. A muscle that cannot be prepared does not stop the others.\n"
    "  --urdf FILE        the skeleton; bones are its links' collision meshes (absolute paths, file:// or\n"
    "                     package:// URIs: the node reads the URDF from robot_description)\n"
    "  --muscle SPEC      NAME:MESH:ORIGIN_LINK:INSERTION_LINK, once per muscle; the links are URDF links with bones\n"
    "  --out DIR          the scene directory (created; an earlier run's files there are overwritten)\n"
    "  --scale S          multiply the muscle files' coordinates by S to get metres (default 1; 0.001 for mm)\n"
    "  --frame LINK       the link whose frame the muscle files use at the URDF's zero configuration (default: the\n"
    "                     URDF's root link); the node's fixed_frame must be this link or one that coincides with it\n"
    "  --package-dir DIR  a package folder for package:// URIs (others are looked up under ROS_PACKAGE_PATH)\n"
    "  --surface-error-mm E\n"
    "                     choose each muscle's particles per fibre (10, 15, 20 or 40) as the coarsest whose skinned\n"
    "                     surface stays within E mm RMS of an 80-per-fibre model's at poses bending each joint the\n"
    "                     muscles cross by 0.5 rad (minutes: five models solved to convergence); written into\n"
    "                     scene.yaml, the study into report.md\n"
    "  --rest-overlaps report|carve-bones\n"
    "                     where a muscle lies inside a bone at rest: report it (default; the node keeps those\n"
    "                     particles from going deeper, never out), or carve each such bone's copy by the muscles\n"
    "                     grown by 0.5 mm (0.5 mm voxels), written into DIR/meshes/bones/ for the node to use\n"
    "Attachment sites (where the tendons attach; without them a fibre end away from its bone hangs from the bone's\n"
    "nearest point, and a joint between the belly and the real attachment hardly changes the muscle's length):\n"
    "  LINK@x,y,z         in --muscle, either link may carry its site: metres in that link's frame, e.g.\n"
    "                     semitendinosus:st.stl:pelvis@-0.12,-0.1,-0.07:tibia_r@-0.03,-0.05,-0.02\n"
    "  --osim MODEL.osim  an OpenSim model of the same skeleton (each body's frame is its link's): a muscle takes\n"
    "                     the path points of the OpenSim muscle of its name (its origin, via and insertion points,\n"
    "                     conditional and moving ones at every coordinate 0); a site given in --muscle wins\n"
    "  --osim-muscle NAME=OSIM_MUSCLE   which OpenSim muscle a muscle takes its points from (repeatable)\n"
    "  --osim-body BODY=LINK            the URDF link of an OpenSim body named otherwise (repeatable)\n"
    "  The points go into scene.yaml (origin_path, insertion_path); report.md gives each one's distance to its\n"
    "  bone and the via points the belly covers (left out).\n") +
    md::tools::kFibreOptionsUsage +
    "  --help             this text\n"
    "Exit status: 0 = every muscle prepared and every bone usable (failed fibre checks are listed in report.md and\n"
    "the node warns of them); 1 = a muscle could not be prepared or a bone is unusable (report.md says why), or bad\n"
    "input.\n";

int run(int argc, char** argv) {
  std::set<std::string> value_options = {"--urdf",        "--muscle", "--out",         "--scale",    "--frame",
                                         "--package-dir", "--osim",   "--osim-muscle", "--osim-body",
                                         "--rest-overlaps", "--surface-error-mm"};
  value_options.insert(md::tools::kFibreOptionNames.begin(), md::tools::kFibreOptionNames.end());
  const md::tools::Arguments args(argc, argv, value_options, {}, {"--muscle", "--osim-muscle", "--osim-body"});
  for (const char* required : {"--urdf", "--muscle", "--out"})
    if (!args.has(required)) throw UsageError(std::string(required) + " is required");

  md::ScenePreparationRequest request;
  request.out_dir = args.value("--out");
  request.command_line = md::tools::Arguments::joined(argc, argv);
  request.urdf_file = args.value("--urdf");
  for (const std::string& spec : args.values("--muscle")) {
    try {
      request.muscles.push_back(md::parseMuscleSource(spec));
    } catch (const std::invalid_argument& e) {
      throw UsageError(std::string("--muscle ") + e.what());
    }
  }
  if (args.has("--scale")) request.scale_to_metres = md::tools::parsePositive("--scale", args.value("--scale"), "to metres");
  if (args.has("--frame")) request.frame = args.value("--frame");
  std::map<std::string, std::string> packages;
  if (args.has("--package-dir")) {
    const std::string& directory = args.value("--package-dir");
    const std::string name = md::tools::packageNameIn(directory);
    if (name.empty()) throw UsageError("--package-dir " + directory + ": no package.xml with a <name> there");
    packages[name] = directory;
  }
  // Plain paths in the URDF start at its folder here; the report flags them, as the node cannot resolve them.
  request.resolve_uri =
      md::tools::packageUriResolver(packages, fs::absolute(request.urdf_file).parent_path().string());
  request.fibres = md::tools::fibreOptions(args);
  if (args.has("--rest-overlaps")) {
    const std::string& rule = args.value("--rest-overlaps");
    if (rule == "carve-bones") request.rest_overlaps = md::RestOverlapRule::carve_bones;
    else if (rule != "report") throw UsageError("--rest-overlaps '" + rule + "': report or carve-bones");
  }
  if (args.has("--surface-error-mm")) {
    md::ResolutionChoiceRequest resolution;
    resolution.surface_error_m = 1e-3 * md::tools::parsePositive("--surface-error-mm", args.value("--surface-error-mm"),
                                                                "millimetres");
    request.resolution = resolution;
  }
  if (args.has("--osim")) request.osim.osim_file = args.value("--osim");
  for (const auto& [option, map] : {std::pair{"--osim-muscle", &request.osim.muscles},
                                    std::pair{"--osim-body", &request.osim.bodies}}) {
    if (args.has(option) && !args.has("--osim")) throw UsageError(std::string(option) + " needs --osim");
    for (const std::string& entry : args.values(option)) {
      const std::size_t equals = entry.find('=');
      if (equals == std::string::npos || equals == 0 || equals + 1 == entry.size())
        throw UsageError(std::string(option) + " '" + entry + "' is not NAME=OTHER");
      if (!map->emplace(entry.substr(0, equals), entry.substr(equals + 1)).second)
        throw UsageError(std::string(option) + " names '" + entry.substr(0, equals) + "' twice");
    }
  }

  const md::ScenePreparation scene =
      md::prepareScene(request, [](const std::string& line) { std::cout << line << std::endl; });
  int checks_failed = 0;
  for (const md::PreparedMuscle& muscle : scene.muscles)
    if (muscle.prepared() && !muscle.fibres.checks.passed()) ++checks_failed;
  const fs::path dir = scene.out_dir;
  std::cout << scene.preparedCount() << " of " << scene.muscles.size() << " muscles prepared"
            << (checks_failed ? " (" + std::to_string(checks_failed) + " with failed fibre checks)" : "") << "; report "
            << (dir / md::kReportFileName).string() << "\n";
  if (!scene.bonesUsable()) std::cout << "a bone mesh is unusable: the node cannot run this scene (see the report)\n";
  if (scene.preparedCount() > 0)
    std::cout << "run it: roslaunch muscle_deformation gait_playback.launch scene:=" << (dir / md::kSceneFileName).string()
              << " urdf:=" << scene.urdf_file << (scene.frame == "pelvis" ? "" : " fixed_frame:=" + scene.frame)
              << " rviz_config:=" << (dir / md::kRvizFileName).string() << " bag:=YOUR.bag\n";
  // A muscle whose fibre checks failed is prepared (the report and the node say what failed): only a muscle left out,
  // or a bone that leaves the whole scene unusable, is a failure of the command.
  return scene.preparedCount() < static_cast<int>(scene.muscles.size()) || !scene.bonesUsable() ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) { return md::tools::runTool("prepare_scene", kUsage, argc, argv, run); }
