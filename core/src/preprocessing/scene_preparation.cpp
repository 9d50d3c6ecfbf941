// A scene directory from segmented muscle surfaces and a skeleton URDF: repair, bone checks, fibres, measurements.
#include "muscle_deformation/preprocessing/scene_preparation.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/base/inside_test.hpp"
#include "muscle_deformation/core/scene/opensim_model.hpp"
#include "muscle_deformation/preprocessing/resolution_choice.hpp"
#include "muscle_deformation/preprocessing/scene_directory.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>

namespace muscle_deformation {

namespace fs = std::filesystem;

namespace {

// Muscle colours, apart from each other and from the bones' ivory, in the order the muscles are given.
constexpr std::array<std::array<float, 4>, 8> kMusclePalette = {{{0.85f, 0.20f, 0.20f, 1.0f},
                                                                 {0.20f, 0.45f, 0.85f, 1.0f},
                                                                 {0.25f, 0.70f, 0.30f, 1.0f},
                                                                 {0.85f, 0.50f, 0.10f, 1.0f},
                                                                 {0.60f, 0.30f, 0.75f, 1.0f},
                                                                 {0.10f, 0.70f, 0.70f, 1.0f},
                                                                 {0.80f, 0.30f, 0.55f, 1.0f},
                                                                 {0.55f, 0.55f, 0.15f, 1.0f}}};

// Names become file names and YAML keys: letters, digits, '_', '-', '.', not starting with '.'.
bool isUsableName(const std::string& name) {
  if (name.empty() || name.front() == '.') return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == '.';
  });
}

bool isPlainRelativePath(const std::string& uri) {
  return uri.find("://") == std::string::npos && !fs::path(uri).is_absolute();
}

std::string listOf(const std::vector<std::string>& names) {
  std::string out;
  for (const std::string& name : names) out += (out.empty() ? "'" : ", '") + name + "'";
  return out.empty() ? "none" : out;
}

// Reads every collision mesh of the URDF as the node will, and repairs the ones that are not closed into the scene
// directory (meshes/bones/<link>_<file name>.stl, in the mesh's own units and frame).
std::vector<BoneMeshCheck> checkBoneMeshes(const Skeleton& skeleton, const UriResolver& resolve,
                                           const std::string& out_dir) {
  std::vector<BoneMeshCheck> checks;
  for (const SkeletonLink& link : skeleton.links()) {
    for (const CollisionMeshRef& ref : link.collision_meshes) {
      BoneMeshCheck check;
      check.link = link.name;
      check.uri = ref.uri;
      if (isPlainRelativePath(ref.uri))
        check.problem = "a relative path: the node reads the URDF from robot_description, which has no folder to "
                        "start it from; write it as an absolute path, a file:// or a package:// URI";
      TriangleMesh mesh;
      try {
        check.file = resolve(ref.uri);
        mesh = loadTriangleMesh(check.file);
      } catch (const std::exception& e) {
        throw SceneError(skeleton.source() + ": link '" + link.name + "': collision mesh '" + ref.uri + "': " + e.what());
      }
      check.triangles = static_cast<int>(mesh.triangleCount());
      try {
        const TriangleMesh closed = closedOrRepaired(mesh, check.file, check.repair, &check.defects);
        if (!check.defects.empty()) {
          check.stand_in = "meshes/bones/" + link.name + "_" + fs::path(check.file).stem().string() + ".stl";
          saveTriangleMeshStl((fs::path(out_dir) / check.stand_in).string(), closed);
        }
      } catch (const LoadError& e) {
        check.problem += (check.problem.empty() ? "" : "; ") + std::string(e.what());
      }
      checks.push_back(std::move(check));
    }
  }
  return checks;
}

// The scene as the node will read it, before its muscles are known: the frame and the bone stand-ins.
SceneDescription sceneSkeletonPart(const std::string& out_dir, const std::string& frame,
                                   const std::vector<BoneMeshCheck>& bone_meshes) {
  SceneDescription scene;
  scene.path = (fs::path(out_dir) / kSceneFileName).string();
  scene.folder = out_dir;
  scene.frame = frame;
  for (const BoneMeshCheck& check : bone_meshes)
    if (!check.stand_in.empty()) scene.bone_surfaces[check.uri] = check.stand_in;
  return scene;
}

// Why a link cannot be a muscle's origin or insertion, or "" when it can.
std::string attachmentProblem(const Skeleton& skeleton, const std::vector<Bone>& bones, const std::string& link,
                              const char* role) {
  std::vector<std::string> bone_names;
  for (const Bone& bone : bones) bone_names.push_back(bone.name);
  if (!skeleton.link(link))
    return std::string(role) + " link '" + link + "' is not a link of the URDF (links with bones: " +
           listOf(bone_names) + ")";
  if (std::find(bone_names.begin(), bone_names.end(), link) == bone_names.end())
    return std::string(role) + " link '" + link + "' has no <collision> mesh, so it is no bone the node can attach " +
           "the muscle to (links with bones: " + listOf(bone_names) + ")";
  return "";
}

// The muscle's surface in metres, closed: as read, or repaired (LoadError when it cannot be), written to the scene.
void readSurface(PreparedMuscle& muscle, double scale, const std::string& out_dir) {
  const TriangleMesh closed = closedOrRepaired(loadTriangleMesh(muscle.source.mesh_file, scale),
                                               muscle.source.mesh_file, muscle.repair, &muscle.defects);
  // The node reads the written file: the fibres are made on it (float coordinates, as STL stores them).
  muscle.surface_file = "meshes/muscles/" + muscle.source.name + ".stl";
  const std::string written = (fs::path(out_dir) / muscle.surface_file).string();
  saveTriangleMeshStl(written, closed);
  muscle.surface = loadClosedSurface(written);
  muscle.volume_m3 = std::abs(enclosedVolume(muscle.surface));
}

const TriangleMesh* boneSurface(const std::vector<Bone>& bones, const std::string& name) {
  for (const Bone& bone : bones)
    if (bone.name == name) return &bone.surface;
  return nullptr;
}

// Muscle vertices inside each (closed) bone at rest, with the deepest one's depth.
void measureOverlaps(std::vector<PreparedMuscle>& muscles, const std::vector<Bone>& bones,
                     const std::vector<BoneMeshCheck>& bone_meshes) {
  for (const Bone& bone : bones) {
    const bool usable = std::none_of(bone_meshes.begin(), bone_meshes.end(), [&](const BoneMeshCheck& check) {
      return check.link == bone.name && !check.problem.empty() && !check.defects.empty();
    });
    if (!usable) continue;  // an open surface has no inside
    const ClosedSurfaceInsideTest inside(bone.surface, bone.name);
    for (PreparedMuscle& muscle : muscles) {
      if (!muscle.prepared()) continue;
      BoneOverlap overlap;
      overlap.bone = bone.name;
      for (Eigen::Index v = 0; v < muscle.surface.vertexCount(); ++v) {
        const Eigen::Vector3d p = muscle.surface.vertices.col(v);
        const bool in_box = (p.array() >= inside.bounds().min.array()).all() &&
                            (p.array() <= inside.bounds().max.array()).all();
        if (!in_box || !inside.contains(p)) continue;
        ++overlap.vertices_inside;
        overlap.max_depth_m = std::max(overlap.max_depth_m, inside.distanceToSurface(p));
      }
      if (overlap.vertices_inside == 0) continue;
      overlap.share = static_cast<double>(overlap.vertices_inside) / static_cast<double>(muscle.surface.vertexCount());
      muscle.overlaps.push_back(overlap);
    }
  }
  for (PreparedMuscle& muscle : muscles)
    std::sort(muscle.overlaps.begin(), muscle.overlaps.end(),
              [](const BoneOverlap& a, const BoneOverlap& b) { return a.max_depth_m > b.max_depth_m; });
}

// The fewest triangles a carved bone copy is decimated to: enough for a bone given as a box to follow the muscles.
constexpr long kMinCarvedTriangles = 4000;

// The copies of the bones the muscles overlap at rest, carved by those muscles grown by kCarveClearanceM, in the mesh
// files' own units and frame (as every stand-in: the URDF's scale and origin still apply). Each carved copy replaces
// the bone's stand-in; a carve that fails leaves the bone as it was and says why.
void carveBonesAtRest(ScenePreparation& preparation, const Skeleton& skeleton,
                      const std::map<std::string, Eigen::Isometry3d>& rest_link_poses,
                      const std::function<void(const std::string&)>& say) {
  for (BoneMeshCheck& check : preparation.bone_meshes) {
    if (!check.problem.empty()) continue;
    std::vector<const PreparedMuscle*> cutters;
    for (const PreparedMuscle& muscle : preparation.muscles)
      if (muscle.prepared() &&
          std::any_of(muscle.overlaps_before_carving.begin(), muscle.overlaps_before_carving.end(),
                      [&](const BoneOverlap& o) { return o.bone == check.link; }))
        cutters.push_back(&muscle);
    if (cutters.empty()) continue;
    const SkeletonLink* link = skeleton.link(check.link);
    const auto ref = std::find_if(link->collision_meshes.begin(), link->collision_meshes.end(),
                                  [&](const CollisionMeshRef& r) { return r.uri == check.uri; });
    // Mesh file -> scene frame at rest: the link's rest pose, the collision's origin, the mesh's scale.
    const Eigen::Affine3d to_scene = Eigen::Affine3d(rest_link_poses.at(check.link)) * Eigen::Affine3d(ref->origin) *
                                     Eigen::Scaling(ref->scale);
    const Eigen::Affine3d to_mesh = to_scene.inverse();
    const double scale = ref->scale.cwiseAbs().minCoeff();  // mesh units per metre, at the least
    try {
      const TriangleMesh bone = loadTriangleMesh(
          check.stand_in.empty() ? check.file : (fs::path(preparation.out_dir) / check.stand_in).string());
      // A link may have several meshes (a pelvis of hip bones and a sacrum): each is carved only by the muscles that
      // enter it, and one that none enters stays as it is.
      const ClosedSurfaceInsideTest inside(bone, check.uri);
      std::vector<TriangleMesh> in_mesh_frame;
      for (const PreparedMuscle* muscle : cutters) {
        TriangleMesh moved = muscle->surface;
        moved.vertices = to_mesh * muscle->surface.vertices;
        bool enters = false;
        for (Eigen::Index v = 0; v < moved.vertexCount() && !enters; ++v) enters = inside.contains(moved.vertices.col(v));
        if (!enters) continue;
        in_mesh_frame.push_back(std::move(moved));
        check.carved_by += (check.carved_by.empty() ? "" : ", ") + muscle->source.name;
      }
      if (in_mesh_frame.empty()) continue;
      // A bone given as a few large triangles (a box) keeps about as many as the carve needs to follow the muscles.
      const long target = std::max<long>(static_cast<long>(bone.triangleCount()), kMinCarvedTriangles);
      const TriangleMesh carved = carvedFromLevelSet(bone, in_mesh_frame, kCarveClearanceM / scale,
                                                     kCarveVoxelM / scale, target, check.carve);
      // The report in the scene's units.
      const double volume_scale = std::abs(ref->scale.prod());
      check.carve.voxel_m *= scale;
      check.carve.volume_m3 *= volume_scale;
      if (check.carve.input_volume_m3) *check.carve.input_volume_m3 *= volume_scale;
      check.carve.pieces_dropped_volume_m3 *= volume_scale;
      check.carve.max_distance_to_input_m *= scale;
      check.carve.max_input_distance_m *= scale;
      check.stand_in = "meshes/bones/" + check.link + "_" + fs::path(check.file).stem().string() + "_carved.stl";
      // STL stores floats: the node reads the copy back through float coordinates, where a sliver of the iso-surface
      // may collapse. What it reads must be closed, so the copy is written as read back, repaired if it has to be.
      const std::string written = (fs::path(preparation.out_dir) / check.stand_in).string();
      saveTriangleMeshStl(written, carved);
      SurfaceRepairReport round_trip;
      const TriangleMesh read_back = closedOrRepaired(loadTriangleMesh(written), written, round_trip);
      if (round_trip.changed()) saveTriangleMeshStl(written, read_back);
      say("bone '" + check.link + "' " + check.uri + ": carved by " + check.carved_by + " into " + check.stand_in +
          ": " + describeCarve(check.carve));
    } catch (const std::exception& e) {
      check.carve_problem = e.what();
      check.carved_by.clear();
      say("bone '" + check.link + "' " + check.uri + ": NOT carved: " + check.carve_problem);
    }
  }
}

// The prepared muscles as the node will model them: surface, fibres, links and tendon paths (scene frame at rest).
std::vector<Muscle> modelMuscles(const ScenePreparation& preparation,
                                 const std::map<std::string, Eigen::Isometry3d>& rest_link_poses) {
  std::vector<Muscle> muscles;
  for (const PreparedMuscle& prepared : preparation.muscles) {
    if (!prepared.prepared()) continue;
    Muscle muscle;
    muscle.name = prepared.source.name;
    muscle.surface = prepared.surface;
    muscle.fibres = prepared.fibres.fibres;
    muscle.origin_bone = prepared.source.origin_link;
    muscle.insertion_bone = prepared.source.insertion_link;
    for (const auto& [sites, path] : {std::pair{&prepared.sites.origin_path, &muscle.origin_path},
                                      std::pair{&prepared.sites.insertion_path, &muscle.insertion_path},
                                      std::pair{&prepared.sites.belly_path, &muscle.belly_path}})
      for (const PreparedSite& site : *sites)
        path->push_back({site.site.link, rest_link_poses.at(site.site.link) * site.site.point});
    muscles.push_back(std::move(muscle));
  }
  return muscles;
}

// The attachments the node will make with `settings` (fixed particles per bone, tendons), from the model builder.
void measureAttachments(ScenePreparation& preparation, const ModelSettings& settings,
                        const std::map<std::string, Eigen::Isometry3d>& rest_link_poses) {
  const std::vector<Muscle> muscles = modelMuscles(preparation, rest_link_poses);
  if (muscles.empty()) return;
  try {
    ModelBuildReport report;
    buildMassSpringSystem(muscles, preparation.bones, settings, &report);
    for (PreparedMuscle& prepared : preparation.muscles)
      for (const MuscleBuildSummary& summary : report.muscles)
        if (summary.name == prepared.source.name) prepared.attachments = summary;
    preparation.warnings = report.warnings;
  } catch (const std::exception& e) {
    preparation.model_problem = e.what();
  }
}

// The OpenSim maps name only what exists: scene muscles being prepared, muscles and bodies of the model, links of the
// URDF. Throws std::invalid_argument naming the entry.
void checkOpenSimMaps(const OpenSimModel& osim, const ScenePreparationRequest& request, const Skeleton& skeleton) {
  for (const auto& [muscle, counterpart] : request.osim.muscles) {
    if (std::none_of(request.muscles.begin(), request.muscles.end(),
                     [&, m = muscle](const MuscleSource& source) { return source.name == m; }))
      throw std::invalid_argument("--osim-muscle " + muscle + "=" + counterpart + ": no muscle '" + muscle +
                                  "' is given with --muscle");
    openSimCounterpart(osim, request.osim, muscle);  // throws for a muscle the model lacks
  }
  const std::vector<std::string> bodies = osim.bodyNames();
  for (const auto& [body, link] : request.osim.bodies) {
    if (std::find(bodies.begin(), bodies.end(), body) == bodies.end())
      throw std::invalid_argument("--osim-body " + body + "=" + link + ": " + osim.source() + " has no body '" + body +
                                  "'");
    if (!skeleton.link(link))
      throw std::invalid_argument("--osim-body " + body + "=" + link + ": '" + link + "' is not a link of the URDF");
  }
}

}  // namespace

MuscleSource parseMuscleSource(const std::string& text) {
  const std::size_t first = text.find(':');
  const std::size_t last = text.rfind(':');
  const std::size_t before_last = last == std::string::npos || last == 0 ? std::string::npos : text.rfind(':', last - 1);
  if (first == std::string::npos || before_last == std::string::npos || before_last <= first)
    throw std::invalid_argument("'" + text + "' is not NAME:MESH:ORIGIN_LINK:INSERTION_LINK");
  MuscleSource source{text.substr(0, first), text.substr(first + 1, before_last - first - 1),
                      text.substr(before_last + 1, last - before_last - 1), text.substr(last + 1), {}, {}};
  for (const auto& [field, value] : {std::pair{"NAME", &source.name}, std::pair{"MESH", &source.mesh_file},
                                     std::pair{"ORIGIN_LINK", &source.origin_link},
                                     std::pair{"INSERTION_LINK", &source.insertion_link}})
    if (value->empty()) throw std::invalid_argument("'" + text + "': " + field + " is empty");
  for (const auto& [link, site] : {std::pair{&source.origin_link, &source.origin_site},
                                   std::pair{&source.insertion_link, &source.insertion_site}}) {
    const LinkWithSite parsed = parseLinkWithSite(*link);
    *link = parsed.link;
    *site = parsed.site;
  }
  return source;
}

bool ScenePreparation::bonesUsable() const {
  return std::all_of(bone_meshes.begin(), bone_meshes.end(),
                     [](const BoneMeshCheck& check) { return check.problem.empty(); });
}

int ScenePreparation::preparedCount() const {
  return static_cast<int>(std::count_if(muscles.begin(), muscles.end(),
                                        [](const PreparedMuscle& m) { return m.prepared(); }));
}

ScenePreparation prepareScene(const ScenePreparationRequest& request,
                              const std::function<void(const std::string&)>& progress) {
  const auto say = [&](const std::string& line) {
    if (progress) progress(line);
  };
  if (!(request.scale_to_metres > 0) || !std::isfinite(request.scale_to_metres))
    throw std::invalid_argument("the scale to metres must be a positive number");
  if (request.out_dir.empty()) throw std::invalid_argument("no output directory given");
  ScenePreparation preparation;
  preparation.out_dir = fs::absolute(request.out_dir).lexically_normal().string();
  preparation.command_line = request.command_line;
  preparation.urdf_file = fs::absolute(request.urdf_file).lexically_normal().string();
  preparation.scale_to_metres = request.scale_to_metres;
  preparation.fibres_asked = request.fibres.fibre_count;
  for (const char* folder : {"meshes/muscles", "meshes/bones", "fibres"})
    fs::create_directories(fs::path(preparation.out_dir) / folder);

  const Skeleton skeleton = Skeleton::fromUrdfFile(request.urdf_file);
  preparation.frame = request.frame.empty() ? skeleton.rootLink() : request.frame;
  if (!skeleton.link(preparation.frame))
    throw SceneError(request.urdf_file + ": the frame '" + preparation.frame + "' is not a link of the URDF");
  preparation.bone_meshes = checkBoneMeshes(skeleton, request.resolve_uri, preparation.out_dir);
  for (const BoneMeshCheck& check : preparation.bone_meshes) {
    if (!check.defects.empty())
      say("bone '" + check.link + "' " + check.uri + ": " + check.defects +
          (check.stand_in.empty() ? "; NOT repaired: " + check.problem
                                  : "; repaired into " + check.stand_in + ": " + check.repair.describe()));
    else if (!check.problem.empty())
      say("bone '" + check.link + "' " + check.uri + ": " + check.problem);
  }
  preparation.bones = loadBones(sceneSkeletonPart(preparation.out_dir, preparation.frame, preparation.bone_meshes),
                                skeleton, request.resolve_uri);
  if (preparation.bones.empty())
    throw SceneError(request.urdf_file + ": no link has a <collision> mesh, so there are no bones to attach muscles "
                     "to (bones are the links' collision meshes)");

  // Link poses at the zero configuration in the scene frame: the sites are given in their links' frames.
  const std::map<std::string, Eigen::Isometry3d> rest_link_poses = linkPosesInFrame(skeleton, preparation.frame);
  std::vector<std::string> links_with_bones;
  for (const Bone& bone : preparation.bones) links_with_bones.push_back(bone.name);
  std::optional<OpenSimModel> osim;
  if (!request.osim.osim_file.empty()) {
    osim = OpenSimModel::fromFile(request.osim.osim_file);
    preparation.osim_file = fs::absolute(request.osim.osim_file).lexically_normal().string();
    checkOpenSimMaps(*osim, request, skeleton);
  }

  std::set<std::string> names;
  for (std::size_t i = 0; i < request.muscles.size(); ++i) {
    PreparedMuscle muscle;
    muscle.source = request.muscles[i];
    muscle.colour = kMusclePalette[i % kMusclePalette.size()];
    const std::string& name = muscle.source.name;
    try {
      if (!isUsableName(name))
        muscle.refusal = "the name '" + name + "' must be letters, digits, '_', '-' or '.' (it names its files)";
      else if (!names.insert(name).second)
        muscle.refusal = "the name '" + name + "' is given to two muscles";
      for (const auto& [link, role] : {std::pair{&muscle.source.origin_link, "origin"},
                                       std::pair{&muscle.source.insertion_link, "insertion"}})
        if (muscle.refusal.empty()) muscle.refusal = attachmentProblem(skeleton, preparation.bones, *link, role);
      if (muscle.refusal.empty()) readSurface(muscle, request.scale_to_metres, preparation.out_dir);
      if (muscle.refusal.empty()) {
        muscle.fibres = generateFibres(muscle.surface, boneSurface(preparation.bones, muscle.source.origin_link),
                                       boneSurface(preparation.bones, muscle.source.insertion_link), request.fibres);
        muscle.fibre_file = "fibres/" + name + ".vtk";
        saveFibresVtk((fs::path(preparation.out_dir) / muscle.fibre_file).string(), muscle.fibres.fibres, 5,
                      muscle.fibres.checks.failures);
        const std::string counterpart = osim ? openSimCounterpart(*osim, request.osim, name) : "";
        std::vector<std::string> notes;
        const std::vector<PathCandidate> candidates =
            pathCandidates(name, {muscle.source.origin_link, muscle.source.origin_site},
                           {muscle.source.insertion_link, muscle.source.insertion_site}, osim ? &*osim : nullptr,
                           counterpart, request.osim.bodies, links_with_bones, notes);
        muscle.sites = placeAgainstBelly(candidates, muscle.surface, muscle.fibres.fibres, rest_link_poses,
                                         preparation.bones);
        muscle.sites.notes.insert(muscle.sites.notes.begin(), notes.begin(), notes.end());
        if (osim && counterpart.empty())
          muscle.sites.notes.push_back("no muscle of the OpenSim model is named '" + name +
                                       "' (map one with --osim-muscle " + name + "=OSIM_MUSCLE)");
        if (!counterpart.empty()) muscle.sites.reference_muscles = {counterpart};
      }
    } catch (const std::exception& e) {  // LoadError, FibreGenerationError: this muscle only
      muscle.refusal = e.what();
    }
    if (muscle.prepared()) {
      std::string line = "muscle '" + name + "': ";
      if (muscle.repair.changed()) line += "repaired (" + muscle.repair.describe() + "); ";
      line += std::to_string(muscle.fibres.fibres.size()) + " fibres, " +
              (muscle.fibres.checks.passed() ? "checks passed" : "checks FAILED");
      const int sites = static_cast<int>(muscle.sites.origin_path.size() + muscle.sites.insertion_path.size());
      if (sites > 0) line += ", " + std::to_string(sites) + " attachment site" + (sites > 1 ? "s" : "");
      double farthest = 0;
      if (const int far = muscle.sites.farFromBone(&farthest); far > 0)
        line += " (" + std::to_string(far) + " of them more than " + std::to_string(int(kSiteFarFromBoneM * 1e3)) +
                " mm from their bone, up to " + std::to_string(int(std::lround(farthest * 1e3))) +
                " mm: are they in the links' frames, in metres?)";
      say(line);
    } else {
      say("muscle '" + name + "' NOT prepared: " + muscle.refusal);
    }
    preparation.muscles.push_back(std::move(muscle));
  }
  measureOverlaps(preparation.muscles, preparation.bones, preparation.bone_meshes);
  preparation.rest_overlaps = request.rest_overlaps;
  if (request.rest_overlaps == RestOverlapRule::carve_bones) {
    for (PreparedMuscle& muscle : preparation.muscles) muscle.overlaps_before_carving.swap(muscle.overlaps);
    carveBonesAtRest(preparation, skeleton, rest_link_poses, say);
    preparation.bones = loadBones(sceneSkeletonPart(preparation.out_dir, preparation.frame, preparation.bone_meshes),
                                  skeleton, request.resolve_uri);
    measureOverlaps(preparation.muscles, preparation.bones, preparation.bone_meshes);
  }
  measureAttachments(preparation, request.model, rest_link_poses);
  if (request.resolution) {
    const std::vector<Muscle> muscles = modelMuscles(preparation, rest_link_poses);
    if (!muscles.empty()) {
      say("choosing each muscle's particles per fibre for " +
          std::to_string(request.resolution->surface_error_m * 1e3).substr(0, 4) + " mm surface RMS (" +
          std::to_string(request.resolution->candidates.size() + 1) + " models)");
      try {
        preparation.resolution = chooseResolutions(muscles, preparation.bones, skeleton, preparation.frame,
                                                   nodeDefaultSettings(), *request.resolution, say);
      } catch (const std::exception& e) {
        preparation.resolution_problem = e.what();
        say("the resolutions could not be chosen: " + preparation.resolution_problem);
      }
    }
  }
  writeSceneDirectory(preparation);
  return preparation;
}

}  // namespace muscle_deformation
