// Loading a scene: the skeleton from a URDF (bones = links with <collision> meshes) and the muscles from a scene YAML
// (config/scenes/*.yaml). ROS-free: the URDF arrives as a string (the node reads robot_description), and mesh URIs
// (package://, file://, relative paths) are turned into file paths by a resolver the caller supplies. Paths written in
// the scene YAML are relative to the YAML's own folder, so a scene directory can be moved or shared as it is.
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/scene/skeleton.hpp"

#include <Eigen/Geometry>

#include <array>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace muscle_deformation {

// Turns a mesh URI into a readable file path; throws SceneError if it cannot.
using UriResolver = std::function<std::string(const std::string& uri)>;
// package://<pkg>/rest -> package_roots[pkg]/rest; file:///abs -> /abs; a relative path -> base_directory/path.
UriResolver makeUriResolver(std::map<std::string, std::string> package_roots, std::string base_directory);

// ---------------------------------------------------------------------------------------------------------------
// Scene YAML

// A point of a tendon's path as the scene YAML gives it: a URDF link and a point in the link's frame (m).
struct SitePoint {
  std::string link;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
};

struct MuscleDescription {
  std::string name;
  std::string surface_file;  // as written: relative to the scene file's folder, absolute, package:// or file://
  std::string fibre_file;    // as written, the same forms
  std::string origin_bone, insertion_bone;  // URDF link names
  std::array<float, 4> colour{0.8f, 0.2f, 0.2f, 1.0f};  // RGBA 0-1
  std::vector<std::string> tags;                         // e.g. thigh13, hip
  // `origin_path` / `insertion_path` keys: the tendons' paths (Muscle::origin_path), each point in its link's frame.
  std::vector<SitePoint> origin_path, insertion_path;
  // `belly_path` key (optional): the via points the belly covers, from origin to insertion (Muscle::belly_path).
  std::vector<SitePoint> belly_path;
  // `reference_muscles` key: the reference model's musculotendons this muscle is compared with (empty: none).
  std::vector<std::string> reference_muscles;
  // `particles_per_fibre` key: this muscle's own resolution (Muscle::particles_per_fibre); 0 (no key): the model's.
  int particles_per_fibre = 0;
};

// `reference_model` key: the musculoskeletal model the sites and the length reference come from (an OpenSim model) and
// the per-body scale factors that make it the scene's skeleton.
struct ReferenceModel {
  std::string osim_file;  // as written (the forms of MuscleDescription::surface_file); empty: none
  std::map<std::string, Eigen::Vector3d> body_scales;
};

struct SceneDescription {
  std::string path;        // the YAML file
  std::string folder;      // the YAML file's folder (absolute): relative paths in the scene start here
  std::string urdf_file;   // `urdf:` key as written (the same forms as MuscleDescription::surface_file)
  std::string frame;       // `frame:` key: the link whose frame the muscle files use (the fixed frame at zero)
  std::vector<MuscleDescription> muscles;
  // `repair_surfaces:` key (default false): muscle surfaces that are not closed are repaired on loading
  // (io/surface_repair.hpp) instead of refused; Scene::repairs says what changed.
  bool repair_surfaces = false;
  // `bone_surfaces:` key: closed stand-ins for URDF collision meshes that are not closed (prepare_scene writes them):
  // the mesh as the URDF names it (its filename attribute, exactly) -> the file to load instead (the same forms as
  // MuscleDescription::surface_file), in the units and frame of the mesh it stands in for, so that the URDF's scale
  // and origin apply to it as they did to the original.
  std::map<std::string, std::string> bone_surfaces;
  ReferenceModel reference_model;
};

// Descriptions that only name the muscles (default colour, no files, no tags): for muscles made in code (the synthetic
// thigh, tests) that a pipeline needs described.
std::vector<MuscleDescription> describedByName(const std::vector<Muscle>& muscles);

// Reads the YAML; every missing or malformed key is a SceneError naming the file and the line.
SceneDescription loadSceneDescription(const std::string& yaml_path);

// The muscles to simulate: `selection` entries are muscle names or tags; empty = all. Unknown names are an error
// naming them.
std::vector<MuscleDescription> selectMuscles(const SceneDescription& scene, const std::vector<std::string>& selection);

// ---------------------------------------------------------------------------------------------------------------
// Everything loaded, in the scene frame of the zero configuration (metres)

struct Scene {
  Skeleton skeleton;
  std::vector<MuscleDescription> muscle_descriptions;  // same order as muscles
  std::vector<Muscle> muscles;                         // surfaces checked closed; fibres loaded
  std::vector<Bone> bones;  // one per link with collision meshes (all its meshes merged), placed at zero config
  std::map<std::string, Eigen::Isometry3d> rest_link_poses;  // link poses at zero configuration, scene frame
  // One line per muscle surface repaired on loading (SceneDescription::repair_surfaces), naming muscle, file and
  // changes; for the caller to show as warnings.
  std::vector<std::string> repairs;
  // One line per muscle whose fibre file records that its checks failed when it was generated
  // (recordedFibreCheckFailures), naming the muscle, the file and the failures; for the caller to show as warnings.
  std::vector<std::string> warnings;
};

// The links the scene names (its `frame`, every muscle's origin_bone and insertion_bone, of every muscle, selected or
// not) that are not links of `skeleton`, each once, in the order the scene first names them. Empty when the scene
// and the skeleton fit.
std::vector<std::string> linksMissingFrom(const SceneDescription& description, const Skeleton& skeleton);

// Loads the selected muscles and every bone with collision meshes (a mesh the scene's bone_surfaces replaces from the
// file it names). Relative scene paths start at the scene file's folder; package:// and file:// URIs, in the scene
// and in the URDF, go through `resolve_mesh`. Throws SceneError (or
// LoadError from the mesh loaders, naming the file) on any missing or broken input: among others links the scene names
// that the URDF lacks (all of them listed), a scene without bones (no link with a <collision> mesh), a muscle attached
// to a link without one, a bone_surfaces entry for a mesh no link of the URDF names, and fibres further than
// kFibreOutsideToleranceM outside their muscle's surface.
Scene loadScene(const SceneDescription& description, const Skeleton& skeleton, const UriResolver& resolve_mesh,
                const std::vector<std::string>& selection = {});

// How far a muscle's fibres stray outside its closed surface: the largest distance of a fibre point outside it (0
// when every point is inside), and which point that is.
struct FibreExcursion {
  double max_outside_m = 0;
  int fibre = -1, point = -1;  // -1: no point outside
};
FibreExcursion fibreExcursion(const Muscle& muscle);

// loadScene refuses fibres that leave their muscle's surface by more than this (m): fibres traced through a segmented
// volume end on or just outside its surface, while a fibre file of another muscle, in other units or in another frame
// lies centimetres away.
constexpr double kFibreOutsideToleranceM = 0.005;

// A path written in the scene (`urdf:`, `surface:`, `fibres:`) as a file path: package:// and file:// URIs through
// `resolve_uri` (which checks the file is there; an empty resolver refuses URIs), an absolute path as written, a
// relative one from the scene file's folder (not checked: a fibre file may be about to be written). Throws SceneError
// naming the scene file.
std::string resolveScenePath(const SceneDescription& scene, const std::string& path,
                             const UriResolver& resolve_uri = {});

// Only the bones of loadScene (one per link with collision meshes, ids = index, rest pose in the link `frame` of the
// zero configuration), e.g. for tools that run before fibre files exist. Throws SceneError for an unknown frame.
std::vector<Bone> loadBones(const Skeleton& skeleton, const UriResolver& resolve_mesh, const std::string& frame);
// The same for a scene: in its frame, with its bone_surfaces in place of the meshes they replace.
std::vector<Bone> loadBones(const SceneDescription& scene, const Skeleton& skeleton, const UriResolver& resolve_mesh);

// The pose of the bones (rest -> current, scene frame) for link poses given in the scene frame, e.g. from tf or
// from Skeleton::linkPoses: T_bone = T_link(current) * T_link(rest)^-1.
Pose poseFromLinkPoses(const Scene& scene, const std::map<std::string, Eigen::Isometry3d>& link_poses);
// The same from the bones and their links' rest poses, both in one frame (a scene being prepared has no Scene yet).
Pose poseFromLinkPoses(const std::vector<Bone>& bones, const std::map<std::string, Eigen::Isometry3d>& rest_link_poses,
                       const std::map<std::string, Eigen::Isometry3d>& link_poses);

// Every link's pose at the joint values `values` (zero configuration: none), re-expressed in the frame of link `frame`
// (the scene frame). Throws SceneError for a frame that is not a link of the skeleton or not connected to its root.
std::map<std::string, Eigen::Isometry3d> linkPosesInFrame(const Skeleton& skeleton, const std::string& frame,
                                                          const JointValues& values = {});

}  // namespace muscle_deformation
