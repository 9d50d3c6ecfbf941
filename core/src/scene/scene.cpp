// The scene half of scene loading: URI resolution, the scene YAML, and assembling bones and muscles at rest.
#include "muscle_deformation/core/scene/scene.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/io/surface_repair.hpp"
#include "muscle_deformation/core/base/inside_test.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <filesystem>
#include <set>
#include <sstream>
#include <utility>

namespace muscle_deformation {

namespace fs = std::filesystem;

namespace {

bool startsWith(const std::string& text, const std::string& prefix) {
  return text.compare(0, prefix.size(), prefix) == 0;
}

// "file line N" (yaml-cpp lines are 0-based; editors count from 1).
std::string where(const std::string& path, const YAML::Mark& mark) {
  if (mark.line < 0) return path;
  return path + " line " + std::to_string(mark.line + 1);
}

std::string requiredString(const YAML::Node& map, const char* key, const std::string& path, const std::string& what) {
  const YAML::Node value = map[key];
  if (!value.IsDefined() || value.IsNull()) {
    throw SceneError(where(path, map.Mark()) + ": " + what + " has no '" + key + "' key");
  }
  if (!value.IsScalar() || value.Scalar().empty()) {
    throw SceneError(where(path, value.Mark()) + ": '" + key + "' of " + what + " must be a non-empty string");
  }
  return value.Scalar();
}

// A list of {link, point: [x, y, z]} (a tendon path), or nothing when the key is absent.
std::vector<SitePoint> parseSitePath(const YAML::Node& node, const std::string& key, const std::string& path,
                                     const std::string& named) {
  std::vector<SitePoint> points;
  const YAML::Node list = node[key];
  if (!list.IsDefined() || list.IsNull()) return points;
  if (!list.IsSequence()) throw SceneError(where(path, list.Mark()) + ": '" + key + "' of " + named + " must be a list");
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string what = "'" + key + "' point #" + std::to_string(i + 1) + " of " + named;
    if (!list[i].IsMap()) throw SceneError(where(path, list[i].Mark()) + ": " + what + " must be {link, point}");
    SitePoint site;
    site.link = requiredString(list[i], "link", path, what);
    const YAML::Node xyz = list[i]["point"];
    if (!xyz.IsDefined() || !xyz.IsSequence() || xyz.size() != 3)
      throw SceneError(where(path, list[i].Mark()) + ": " + what + " needs 'point: [x, y, z]' (metres, link frame)");
    for (std::size_t k = 0; k < 3; ++k) {
      try {
        site.point[static_cast<Eigen::Index>(k)] = xyz[k].as<double>();
      } catch (const YAML::Exception&) {
        throw SceneError(where(path, xyz[k].Mark()) + ": " + what + ": '" + xyz[k].Scalar() + "' is not a number");
      }
      if (!std::isfinite(site.point[static_cast<Eigen::Index>(k)]))
        throw SceneError(where(path, xyz[k].Mark()) + ": " + what + ": coordinates must be finite");
    }
    points.push_back(site);
  }
  return points;
}

MuscleDescription parseMuscle(const YAML::Node& node, std::size_t index, const std::string& path) {
  const std::string what = "muscle #" + std::to_string(index + 1);
  if (!node.IsMap()) throw SceneError(where(path, node.Mark()) + ": " + what + " must be a map of keys");
  MuscleDescription m;
  m.name = requiredString(node, "name", path, what);
  const std::string named = "muscle '" + m.name + "'";
  m.surface_file = requiredString(node, "surface", path, named);
  m.fibre_file = requiredString(node, "fibres", path, named);
  m.origin_bone = requiredString(node, "origin_bone", path, named);
  m.insertion_bone = requiredString(node, "insertion_bone", path, named);

  // YAML::Node assignment writes through to the document, so pick the key with a copy-construction instead.
  const YAML::Node colour = node["color"].IsDefined() ? node["color"] : node["colour"];
  if (colour.IsDefined() && !colour.IsNull()) {
    if (!colour.IsSequence() || (colour.size() != 3 && colour.size() != 4)) {
      throw SceneError(where(path, colour.Mark()) + ": 'color' of " + named +
                       " must be a list of 3 or 4 numbers in [0, 1] (RGB or RGBA)");
    }
    for (std::size_t k = 0; k < colour.size(); ++k) {
      double c = 0;
      try {
        c = colour[k].as<double>();
      } catch (const YAML::Exception&) {
        throw SceneError(where(path, colour[k].Mark()) + ": 'color' of " + named + ": '" + colour[k].Scalar() +
                         "' is not a number");
      }
      if (!(c >= 0.0 && c <= 1.0)) {
        throw SceneError(where(path, colour[k].Mark()) + ": 'color' of " + named + ": components must be in [0, 1]");
      }
      m.colour[k] = static_cast<float>(c);
    }
    if (colour.size() == 3) m.colour[3] = 1.0f;
  }

  const YAML::Node tags = node["tags"];
  if (tags.IsDefined() && !tags.IsNull()) {
    if (!tags.IsSequence()) throw SceneError(where(path, tags.Mark()) + ": 'tags' of " + named + " must be a list");
    for (const auto& tag : tags) {
      if (!tag.IsScalar()) throw SceneError(where(path, tag.Mark()) + ": tags of " + named + " must be strings");
      m.tags.push_back(tag.Scalar());
    }
  }
  m.origin_path = parseSitePath(node, "origin_path", path, named);
  m.insertion_path = parseSitePath(node, "insertion_path", path, named);
  m.belly_path = parseSitePath(node, "belly_path", path, named);
  const YAML::Node references = node["reference_muscles"];
  if (references.IsDefined() && !references.IsNull()) {
    if (!references.IsSequence())
      throw SceneError(where(path, references.Mark()) + ": 'reference_muscles' of " + named + " must be a list");
    for (const auto& reference : references) {
      if (!reference.IsScalar())
        throw SceneError(where(path, reference.Mark()) + ": reference_muscles of " + named + " must be strings");
      m.reference_muscles.push_back(reference.Scalar());
    }
  }
  const YAML::Node resolution = node["particles_per_fibre"];
  if (resolution.IsDefined() && !resolution.IsNull()) {
    int particles = 0;
    try {
      particles = resolution.as<int>();
    } catch (const YAML::Exception&) {
      throw SceneError(where(path, resolution.Mark()) + ": 'particles_per_fibre' of " + named + ": '" +
                       resolution.Scalar() + "' is not an integer");
    }
    if (particles < 2 || particles > 10000)
      throw SceneError(where(path, resolution.Mark()) + ": 'particles_per_fibre' of " + named + " is " +
                       std::to_string(particles) + ", must be in [2, 10000] (leave it out for the model's)");
    m.particles_per_fibre = particles;
  }
  return m;
}

}  // namespace

UriResolver makeUriResolver(std::map<std::string, std::string> package_roots, std::string base_directory) {
  return [roots = std::move(package_roots), base = std::move(base_directory)](const std::string& uri) -> std::string {
    std::string path;
    if (startsWith(uri, "package://")) {
      const std::string rest = uri.substr(10);
      const std::size_t slash = rest.find('/');
      const std::string package = rest.substr(0, slash);
      const auto root = roots.find(package);
      if (root == roots.end()) {
        throw SceneError("'" + uri + "': unknown package '" + package + "' (no root directory given for it)");
      }
      path = slash == std::string::npos ? root->second : (fs::path(root->second) / rest.substr(slash + 1)).string();
    } else if (startsWith(uri, "file://")) {
      path = uri.substr(7);
      if (!startsWith(path, "/")) {
        throw SceneError("'" + uri + "': only local absolute file URIs (file:///path) are supported");
      }
    } else if (uri.find("://") != std::string::npos) {
      throw SceneError("'" + uri + "': unsupported URI scheme (use package://, file:// or a path)");
    } else if (uri.empty()) {
      throw SceneError("empty URI");
    } else {
      path = fs::path(uri).is_absolute() ? uri : (fs::path(base) / uri).string();
    }
    std::error_code error;
    if (!fs::is_regular_file(path, error)) {
      throw SceneError("'" + uri + "' resolves to '" + path + "', which is not a readable file");
    }
    return path;
  };
}

SceneDescription loadSceneDescription(const std::string& yaml_path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const YAML::BadFile&) {
    throw SceneError(yaml_path + ": cannot open the scene file");
  } catch (const YAML::Exception& e) {
    throw SceneError(where(yaml_path, e.mark) + ": not valid YAML: " + e.msg);
  }
  if (!root.IsMap()) throw SceneError(yaml_path + ": the scene file must be a map with urdf, frame and muscles");

  SceneDescription scene;
  scene.path = yaml_path;
  std::error_code error;
  const fs::path absolute = fs::absolute(yaml_path, error);
  scene.folder = (error ? fs::path(yaml_path) : absolute).lexically_normal().parent_path().string();
  scene.urdf_file = requiredString(root, "urdf", yaml_path, "the scene");
  scene.frame = requiredString(root, "frame", yaml_path, "the scene");
  if (const YAML::Node repair = root["repair_surfaces"]; repair.IsDefined() && !repair.IsNull()) {
    try {
      scene.repair_surfaces = repair.as<bool>();
    } catch (const YAML::Exception&) {
      throw SceneError(where(yaml_path, repair.Mark()) + ": 'repair_surfaces' must be true or false");
    }
  }
  if (const YAML::Node stand_ins = root["bone_surfaces"]; stand_ins.IsDefined() && !stand_ins.IsNull()) {
    if (!stand_ins.IsSequence())
      throw SceneError(where(yaml_path, stand_ins.Mark()) + ": 'bone_surfaces' must be a list of {mesh, surface}");
    for (std::size_t i = 0; i < stand_ins.size(); ++i) {
      const std::string what = "bone_surfaces entry #" + std::to_string(i + 1);
      if (!stand_ins[i].IsMap()) throw SceneError(where(yaml_path, stand_ins[i].Mark()) + ": " + what + " must be a map");
      const std::string mesh = requiredString(stand_ins[i], "mesh", yaml_path, what);
      if (!scene.bone_surfaces.emplace(mesh, requiredString(stand_ins[i], "surface", yaml_path, what)).second)
        throw SceneError(where(yaml_path, stand_ins[i].Mark()) + ": mesh '" + mesh + "' is replaced twice");
    }
  }
  if (const YAML::Node reference = root["reference_model"]; reference.IsDefined() && !reference.IsNull()) {
    if (!reference.IsMap()) throw SceneError(where(yaml_path, reference.Mark()) + ": 'reference_model' must be a map");
    scene.reference_model.osim_file = requiredString(reference, "osim", yaml_path, "reference_model");
    if (const YAML::Node scales = reference["body_scales"]; scales.IsDefined() && !scales.IsNull()) {
      if (!scales.IsMap())
        throw SceneError(where(yaml_path, scales.Mark()) + ": 'body_scales' must map body names to [x, y, z]");
      for (const auto& entry : scales) {
        const YAML::Node xyz = entry.second;
        const std::string body = entry.first.Scalar();
        if (!xyz.IsSequence() || xyz.size() != 3)
          throw SceneError(where(yaml_path, xyz.Mark()) + ": body_scales of '" + body + "' must be [x, y, z]");
        Eigen::Vector3d scale;
        for (std::size_t k = 0; k < 3; ++k) {
          try {
            scale[static_cast<Eigen::Index>(k)] = xyz[k].as<double>();
          } catch (const YAML::Exception&) {
            throw SceneError(where(yaml_path, xyz[k].Mark()) + ": body_scales of '" + body + "' must be numbers");
          }
        }
        if (!(scale.array() > 0).all() || !scale.allFinite())
          throw SceneError(where(yaml_path, xyz.Mark()) + ": body_scales of '" + body + "' must be positive");
        scene.reference_model.body_scales[body] = scale;
      }
    }
  }
  const YAML::Node muscles = root["muscles"];
  if (!muscles.IsDefined() || muscles.IsNull()) {
    throw SceneError(where(yaml_path, root.Mark()) + ": the scene has no 'muscles' key");
  }
  if (!muscles.IsSequence() || muscles.size() == 0) {
    throw SceneError(where(yaml_path, muscles.Mark()) + ": 'muscles' must be a non-empty list");
  }
  std::set<std::string> names;
  for (std::size_t i = 0; i < muscles.size(); ++i) {
    MuscleDescription m = parseMuscle(muscles[i], i, yaml_path);
    if (!names.insert(m.name).second) {
      throw SceneError(where(yaml_path, muscles[i].Mark()) + ": muscle name '" + m.name + "' is used twice");
    }
    scene.muscles.push_back(std::move(m));
  }
  return scene;
}

std::vector<MuscleDescription> selectMuscles(const SceneDescription& scene, const std::vector<std::string>& selection) {
  if (selection.empty()) return scene.muscles;
  std::set<std::string> wanted(selection.begin(), selection.end());
  std::vector<std::string> unknown;
  for (const std::string& entry : selection) {
    const bool known = std::any_of(scene.muscles.begin(), scene.muscles.end(), [&](const MuscleDescription& m) {
      return m.name == entry || std::find(m.tags.begin(), m.tags.end(), entry) != m.tags.end();
    });
    if (!known && std::find(unknown.begin(), unknown.end(), entry) == unknown.end()) unknown.push_back(entry);
  }
  if (!unknown.empty()) {
    std::string list;
    for (const auto& u : unknown) list += (list.empty() ? "'" : ", '") + u + "'";
    throw SceneError(scene.path + ": no muscle or tag named " + list);
  }
  // Scene order, each muscle once, whatever the order and overlap of the entries.
  std::vector<MuscleDescription> out;
  for (const MuscleDescription& m : scene.muscles) {
    bool take = wanted.count(m.name) > 0;
    for (const auto& tag : m.tags) take = take || wanted.count(tag) > 0;
    if (take) out.push_back(m);
  }
  return out;
}

namespace {

// resolveScenePath without the scene file's name in front of its errors.
std::string resolvePathIn(const SceneDescription& scene, const std::string& path, const UriResolver& resolve_uri) {
  if (path.empty()) throw SceneError("empty path");
  if (startsWith(path, "package://") || startsWith(path, "file://")) {
    if (!resolve_uri) throw SceneError("'" + path + "': no resolver for package:// and file:// URIs given here");
    return resolve_uri(path);
  }
  if (fs::path(path).is_absolute()) return path;
  return (fs::path(scene.folder) / path).lexically_normal().string();
}

}  // namespace

std::string resolveScenePath(const SceneDescription& scene, const std::string& path, const UriResolver& resolve_uri) {
  try {
    return resolvePathIn(scene, path, resolve_uri);
  } catch (const SceneError& e) {
    throw SceneError(scene.path + ": " + e.what());
  }
}

std::vector<std::string> linksMissingFrom(const SceneDescription& description, const Skeleton& skeleton) {
  std::vector<std::string> missing;
  const auto check = [&](const std::string& link) {
    if (!skeleton.link(link) && std::find(missing.begin(), missing.end(), link) == missing.end())
      missing.push_back(link);
  };
  check(description.frame);
  for (const MuscleDescription& m : description.muscles) {
    check(m.origin_bone);
    check(m.insertion_bone);
    for (const std::vector<SitePoint>* tendon : {&m.origin_path, &m.insertion_path, &m.belly_path})
      for (const SitePoint& site : *tendon) check(site.link);
  }
  return missing;
}

namespace {

std::vector<Bone> bonesAtRest(const Skeleton& skeleton, const UriResolver& resolve_mesh,
                              const std::map<std::string, Eigen::Isometry3d>& rest) {
  std::vector<Bone> bones;
  for (const SkeletonLink& link : skeleton.links()) {
    if (link.collision_meshes.empty()) continue;
    const auto pose = rest.find(link.name);
    if (pose == rest.end()) throw SceneError("link '" + link.name + "' has bones but is not connected to the root");
    Bone bone;
    bone.id = static_cast<int>(bones.size());
    bone.name = link.name;
    std::vector<TriangleMesh> parts;
    Eigen::Index vertex_count = 0, triangle_count = 0;
    for (const CollisionMeshRef& ref : link.collision_meshes) {
      TriangleMesh part = loadTriangleMesh(resolve_mesh(ref.uri));
      // URDF semantics: scale in the mesh frame, then the collision origin, then the link pose.
      const Eigen::Isometry3d to_scene = pose->second * ref.origin;
      part.vertices = to_scene * ref.scale.asDiagonal() * part.vertices;
      // A mirroring scale (odd number of negative factors) turns the surface inside out: restore the winding.
      if (ref.scale.prod() < 0) part.triangles.row(1).swap(part.triangles.row(2));
      vertex_count += part.vertexCount();
      triangle_count += part.triangleCount();
      parts.push_back(std::move(part));
    }
    bone.surface.vertices.resize(3, vertex_count);
    bone.surface.triangles.resize(3, triangle_count);
    Eigen::Index v = 0, t = 0;
    for (const TriangleMesh& part : parts) {
      bone.surface.vertices.middleCols(v, part.vertexCount()) = part.vertices;
      bone.surface.triangles.middleCols(t, part.triangleCount()) = part.triangles.array() + static_cast<int>(v);
      v += part.vertexCount();
      t += part.triangleCount();
    }
    bones.push_back(std::move(bone));
  }
  return bones;
}

// The URDF's mesh resolver with the scene's bone_surfaces in place of the meshes they stand in for. A stand-in for a
// mesh the URDF does not name is an error: the scene was made for another skeleton, and the bone it was meant to mend
// would be loaded broken.
UriResolver withBoneSurfaces(const SceneDescription& scene, const Skeleton& skeleton, const UriResolver& resolve_mesh) {
  if (scene.bone_surfaces.empty()) return resolve_mesh;
  std::set<std::string> named;
  for (const SkeletonLink& link : skeleton.links())
    for (const CollisionMeshRef& ref : link.collision_meshes) named.insert(ref.uri);
  std::map<std::string, std::string> files;
  for (const auto& [mesh, surface] : scene.bone_surfaces) {
    if (!named.count(mesh))
      throw SceneError(scene.path + ": bone_surfaces replaces mesh '" + mesh + "', which no link of the URDF (" +
                       skeleton.source() + ") names; is it the skeleton the scene was made for?");
    files[mesh] = resolveScenePath(scene, surface, resolve_mesh);
  }
  return [files = std::move(files), resolve_mesh](const std::string& uri) {
    const auto stand_in = files.find(uri);
    if (stand_in == files.end()) return resolve_mesh(uri);
    if (!fs::is_regular_file(stand_in->second))
      throw SceneError("'" + stand_in->second + "', the closed stand-in for '" + uri + "', is not a readable file");
    return stand_in->second;
  };
}

}  // namespace

std::vector<Bone> loadBones(const Skeleton& skeleton, const UriResolver& resolve_mesh, const std::string& frame) {
  return bonesAtRest(skeleton, resolve_mesh, linkPosesInFrame(skeleton, frame));
}

std::vector<Bone> loadBones(const SceneDescription& scene, const Skeleton& skeleton, const UriResolver& resolve_mesh) {
  return loadBones(skeleton, withBoneSurfaces(scene, skeleton, resolve_mesh), scene.frame);
}

Scene loadScene(const SceneDescription& description, const Skeleton& skeleton, const UriResolver& resolve_mesh,
                const std::vector<std::string>& selection) {
  // Every name before anything is loaded, so that a scene written for another skeleton fails fast and names all the
  // links it lacks, not the first.
  if (const std::vector<std::string> missing = linksMissingFrom(description, skeleton); !missing.empty()) {
    constexpr int kUsersListed = 5;
    std::string links, users;
    int user_count = 0;
    const auto addUser = [&](const std::string& user) {
      if (++user_count <= kUsersListed) users += (users.empty() ? "" : ", ") + user;
    };
    for (const std::string& link : missing) links += (links.empty() ? "'" : ", '") + link + "'";
    if (std::find(missing.begin(), missing.end(), description.frame) != missing.end())
      addUser("the scene frame is '" + description.frame + "'");
    for (const MuscleDescription& m : description.muscles)
      for (const std::string* bone : {&m.origin_bone, &m.insertion_bone})
        if (std::find(missing.begin(), missing.end(), *bone) != missing.end())
          addUser("muscle '" + m.name + "' names '" + *bone + "'");
    if (user_count > kUsersListed) users += " and " + std::to_string(user_count - kUsersListed) + " more";
    throw SceneError(description.path + ": the URDF (" + skeleton.source() + ") has no link" +
                     (missing.size() > 1 ? "s " : " ") + links + " (" + users +
                     "); is it the skeleton the scene was made for?");
  }
  Scene scene;
  scene.skeleton = skeleton;
  try {
    scene.rest_link_poses = linkPosesInFrame(skeleton, description.frame);
  } catch (const SceneError& e) {
    throw SceneError(description.path + ": " + e.what());
  }
  scene.muscle_descriptions = selectMuscles(description, selection);
  scene.bones = bonesAtRest(skeleton, withBoneSurfaces(description, skeleton, resolve_mesh), scene.rest_link_poses);
  // Bones are the links with <collision> meshes: without one, a muscle's attachments follow nothing and the muscles
  // never move, which must not pass for a working scene.
  if (scene.bones.empty()) {
    throw SceneError(description.path + ": the URDF has no link with a <collision> mesh, so there are no bones to "
                     "attach the muscles to (bones are the links' collision meshes)");
  }
  std::set<std::string> bone_names, meshless;
  for (const Bone& bone : scene.bones) bone_names.insert(bone.name);
  std::string named_meshless;
  for (const MuscleDescription& m : scene.muscle_descriptions) {
    for (const std::string* bone : {&m.origin_bone, &m.insertion_bone}) {
      if (!bone_names.count(*bone)) {
        named_meshless += std::string(named_meshless.empty() ? "" : ", ") + "muscle '" + m.name + "' names '" + *bone + "'";
        meshless.insert(*bone);
      }
    }
  }
  if (!meshless.empty()) {
    std::string links;
    for (const std::string& name : meshless) links += (links.empty() ? "'" : ", '") + name + "'";
    throw SceneError(description.path + ": link" + (meshless.size() > 1 ? "s " : " ") + links +
                     " of the URDF ha" + (meshless.size() > 1 ? "ve" : "s") + " no <collision> mesh, so " +
                     (meshless.size() > 1 ? "they are" : "it is") + " no bone (" + named_meshless + ")");
  }
  for (const MuscleDescription& m : scene.muscle_descriptions) {
    Muscle muscle;
    muscle.name = m.name;
    muscle.origin_bone = m.origin_bone;
    muscle.insertion_bone = m.insertion_bone;
    muscle.particles_per_fibre = m.particles_per_fibre;
    // Tendon paths: each point from its link's frame into the scene frame at rest; a point must lie on a bone.
    const auto placed = [&](const std::vector<SitePoint>& sites, const char* key) {
      std::vector<AttachmentSite> points;
      for (const SitePoint& site : sites) {
        const auto rest = scene.rest_link_poses.find(site.link);
        if (!bone_names.count(site.link) || rest == scene.rest_link_poses.end())
          throw SceneError(description.path + ": muscle '" + m.name + "': " + key + " names link '" + site.link +
                           "', which has no <collision> mesh in the URDF, so no bone to carry the point");
        points.push_back({site.link, rest->second * site.point});
      }
      return points;
    };
    muscle.origin_path = placed(m.origin_path, "origin_path");
    muscle.insertion_path = placed(m.insertion_path, "insertion_path");
    muscle.belly_path = placed(m.belly_path, "belly_path");
    // package:// and file:// URIs go through the caller's resolver, as the URDF's meshes do; plain paths start at
    // the scene file's folder.
    std::string surface_path, fibre_path;
    try {
      surface_path = resolvePathIn(description, m.surface_file, resolve_mesh);
      fibre_path = resolvePathIn(description, m.fibre_file, resolve_mesh);
    } catch (const SceneError& e) {
      throw SceneError(description.path + ": muscle '" + m.name + "': " + e.what());
    }
    if (description.repair_surfaces) {
      SurfaceRepairReport repair;
      muscle.surface = loadRepairedClosedSurface(surface_path, 1.0, repair);
      if (repair.changed())
        scene.repairs.push_back("muscle '" + m.name + "': " + surface_path + " repaired: " + repair.describe());
    } else {
      muscle.surface = loadClosedSurface(surface_path);
    }
    if (!fs::is_regular_file(fibre_path)) {
      throw SceneError(description.path + ": fibre file of muscle '" + m.name + "' does not exist: " + fibre_path +
                       " (make it with generate_fibres --scene " + description.path + ")");
    }
    muscle.fibres = loadPolylines(fibre_path);
    if (muscle.fibres.empty()) throw SceneError(fibre_path + ": no fibres in the file (muscle '" + m.name + "')");
    if (const std::string failed = recordedFibreCheckFailures(fibre_path); !failed.empty())
      scene.warnings.push_back("muscle '" + m.name + "': its fibres failed their checks when they were generated (" +
                               failed + "; " + fibre_path + "): the muscle is simulated on them as they are");
    const FibreExcursion excursion = fibreExcursion(muscle);
    if (excursion.max_outside_m > kFibreOutsideToleranceM) {
      std::ostringstream message;
      message << fibre_path << ": fibre " << excursion.fibre << " of muscle '" << m.name << "' runs "
              << 1000.0 * excursion.max_outside_m << " mm outside the muscle's surface (at its point "
              << excursion.point << "; fibres may end at most " << 1000.0 * kFibreOutsideToleranceM
              << " mm outside). Is it the fibre file of another muscle, or in other units or another frame than "
              << surface_path << "? generate_fibres makes fibres that fit";
      throw SceneError(message.str());
    }
    scene.muscles.push_back(std::move(muscle));
  }
  return scene;
}

FibreExcursion fibreExcursion(const Muscle& muscle) {
  FibreExcursion excursion;
  const ClosedSurfaceInsideTest surface(muscle.surface, muscle.name);
  for (std::size_t f = 0; f < muscle.fibres.size(); ++f) {
    const Polyline& fibre = muscle.fibres[f];
    for (Eigen::Index k = 0; k < fibre.cols(); ++k) {
      const Eigen::Vector3d point = fibre.col(k);
      if (!point.allFinite() || surface.contains(point)) continue;
      const double outside = surface.distanceToSurface(point);
      if (outside > excursion.max_outside_m) {
        excursion.max_outside_m = outside;
        excursion.fibre = static_cast<int>(f);
        excursion.point = static_cast<int>(k);
      }
    }
  }
  return excursion;
}

std::vector<MuscleDescription> describedByName(const std::vector<Muscle>& muscles) {
  std::vector<MuscleDescription> descriptions;
  for (const Muscle& muscle : muscles) {
    MuscleDescription description;
    description.name = muscle.name;
    description.origin_bone = muscle.origin_bone;
    description.insertion_bone = muscle.insertion_bone;
    descriptions.push_back(description);
  }
  return descriptions;
}

Pose poseFromLinkPoses(const Scene& scene, const std::map<std::string, Eigen::Isometry3d>& link_poses) {
  return poseFromLinkPoses(scene.bones, scene.rest_link_poses, link_poses);
}

Pose poseFromLinkPoses(const std::vector<Bone>& bones, const std::map<std::string, Eigen::Isometry3d>& rest_link_poses,
                       const std::map<std::string, Eigen::Isometry3d>& link_poses) {
  Pose pose;
  for (const Bone& bone : bones) {
    const auto current = link_poses.find(bone.name);
    const auto rest = rest_link_poses.find(bone.name);
    if (current == link_poses.end() || rest == rest_link_poses.end()) continue;  // stays at rest
    pose.bone_transforms[bone.name] = current->second * rest->second.inverse();
  }
  return pose;
}

std::map<std::string, Eigen::Isometry3d> linkPosesInFrame(const Skeleton& skeleton, const std::string& frame,
                                                          const JointValues& values) {
  if (!skeleton.link(frame)) throw SceneError("scene frame '" + frame + "' is not a link of the URDF");
  std::map<std::string, Eigen::Isometry3d> poses = skeleton.linkPoses(values);
  const auto frame_pose = poses.find(frame);
  if (frame_pose == poses.end()) throw SceneError("scene frame '" + frame + "' is not connected to the URDF root");
  const Eigen::Isometry3d to_frame = frame_pose->second.inverse();
  for (auto& [name, pose] : poses) pose = to_frame * pose;
  return poses;
}

}  // namespace muscle_deformation
