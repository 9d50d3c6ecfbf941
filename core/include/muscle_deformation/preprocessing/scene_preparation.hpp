// A scene from a user's own anatomy: segmented muscle surfaces (any format the loaders read, in any length unit) and a
// skeleton URDF become what the node runs on as it is. Each muscle surface is repaired where it has small defects (or
// refused, with the reason), the URDF's bone meshes are checked closed (and closed copies made where they are not),
// fibres are generated, and the overlaps with the bones and the attachments the node will make are measured. Everything
// is written into one directory: scene.yaml (paths relative to it), meshes/, fibres/, report.md and view.rviz
// (scene_directory.hpp writes the last three).
#pragma once

#include "muscle_deformation/core/io/level_set_rebuild.hpp"
#include "muscle_deformation/core/io/surface_repair.hpp"
#include "muscle_deformation/core/model/model_builder.hpp"
#include "muscle_deformation/core/scene/scene.hpp"
#include "muscle_deformation/preprocessing/attachment_sites.hpp"
#include "muscle_deformation/preprocessing/fibre_generator.hpp"
#include "muscle_deformation/preprocessing/resolution_choice.hpp"

#include <array>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace muscle_deformation {

// One muscle to prepare: its name in the scene, its surface file and the URDF links of its origin and insertion, with
// the attachment sites on them when the user gives them (metres in the link's frame).
struct MuscleSource {
  std::string name;
  std::string mesh_file;
  std::string origin_link, insertion_link;
  std::optional<Eigen::Vector3d> origin_site = std::nullopt, insertion_site = std::nullopt;
};

// NAME:MESH:ORIGIN_LINK:INSERTION_LINK (the mesh path may itself hold colons: the name is the first field, the links
// the last two); each link may carry its site, LINK@x,y,z (metres in the link's frame). Throws std::invalid_argument
// saying what is missing or malformed.
MuscleSource parseMuscleSource(const std::string& text);

// What preparation does where a muscle lies inside a bone at rest (a segmentation's bone and muscle overlap, or the
// bone comes from another body): report it (the node then keeps those particles from going deeper, never out), or
// carve the bone's copy by the muscles grown by kCarveClearanceM (the bundled scene's treatment), so that the muscles
// start outside their bones. The muscles stay as segmented.
enum class RestOverlapRule { report, carve_bones };

// The carve's voxel and clearance (m, in the scene's units): the bundled build's, measured there (data/README.md,
// "Bones carved by the muscles"). The clearance covers what the iso-surface and its decimation move the carved surface
// back, and keeps the muscle particles' centres out of the node's bone fields.
constexpr double kCarveVoxelM = 0.5e-3;
constexpr double kCarveClearanceM = 0.5e-3;

struct ScenePreparationRequest {
  std::string out_dir;           // created if missing; files of an earlier run there are overwritten
  std::string command_line;      // for the report: how it was made
  std::string urdf_file;
  std::vector<MuscleSource> muscles;
  double scale_to_metres = 1.0;  // of the muscle surface files (0.001 for millimetres)
  std::string frame;             // the URDF link whose frame the muscle files use at rest; empty = the URDF's root
  UriResolver resolve_uri;       // the URDF's mesh URIs (package://, file://, paths) to files
  FibreGeneratorOptions fibres;
  ModelSettings model;           // the attachment rule the report shows (the node's defaults)
  OpenSimSiteRequest osim;       // attachment sites from an OpenSim model of the same skeleton (none: osim_file empty)
  RestOverlapRule rest_overlaps = RestOverlapRule::report;
  // Each muscle's particles per fibre chosen for a surface error target (resolution_choice.hpp) and written into the
  // scene; none: every muscle at the node's resolution.
  std::optional<ResolutionChoiceRequest> resolution;
};

// One collision mesh of the URDF, as the node will load it.
struct BoneMeshCheck {
  std::string link;
  std::string uri;           // as the URDF writes it
  std::string file;          // what it resolved to ("" when it did not)
  int triangles = 0;
  std::string defects;       // what made it not closed ("" when it was)
  SurfaceRepairReport repair;
  std::string stand_in;      // the closed copy written for the node, relative to the scene directory ("" = none)
  std::string problem;       // why the node cannot use it as it is and the repair could not help ("" = usable)
  // RestOverlapRule::carve_bones: the muscles the copy was carved by ("" = not carved), what the carve did (volumes in
  // m^3 and distances in m, in the scene's units), and why a carve failed ("" = it did not).
  std::string carved_by;
  LevelSetRebuildReport carve;
  std::string carve_problem;
};

// A muscle vertex count inside one bone at rest.
struct BoneOverlap {
  std::string bone;
  int vertices_inside = 0;
  double share = 0;        // of the muscle's vertices
  double max_depth_m = 0;  // deepest such vertex below the bone's surface
};

struct PreparedMuscle {
  MuscleSource source;
  std::string refusal;     // why the muscle could not be prepared; "" = prepared
  std::string defects;     // what the surface had when read ("" when it was closed)
  SurfaceRepairReport repair;
  TriangleMesh surface;    // closed, metres, scene frame
  std::string surface_file, fibre_file;  // as written, relative to the scene directory
  double volume_m3 = 0;
  std::array<float, 4> colour{0.8f, 0.2f, 0.2f, 1.0f};
  FibreGenerationResult fibres;
  std::vector<BoneOverlap> overlaps;  // bones the muscle lies inside of at rest, deepest first (after any carve)
  std::vector<BoneOverlap> overlaps_before_carving;  // RestOverlapRule::carve_bones: as the bones were given
  TendonPaths sites;                  // the tendons' paths to the attachment sites (empty: none given)
  MuscleBuildSummary attachments;     // the particles the node fixes to which bone, tendons (ModelSettings)
  bool prepared() const { return refusal.empty(); }
};

struct ScenePreparation {
  std::string out_dir;
  std::string command_line;
  std::string urdf_file;
  std::string frame;
  double scale_to_metres = 1.0;
  int fibres_asked = 0;
  std::string osim_file;                // the OpenSim model the sites come from (absolute; "" = none)
  RestOverlapRule rest_overlaps = RestOverlapRule::report;
  std::optional<ResolutionChoice> resolution;  // ScenePreparationRequest::resolution: what was chosen and measured
  std::string resolution_problem;              // why the resolutions could not be chosen ("" = chosen, or not asked)
  std::vector<BoneMeshCheck> bone_meshes;
  std::vector<Bone> bones;              // at rest in the scene frame, with the stand-ins in place
  std::vector<PreparedMuscle> muscles;  // in the order asked for
  std::vector<std::string> warnings;    // of the model build (e.g. attachments on two bones a few millimetres apart)
  std::string model_problem;            // why the attachments could not be measured ("" when they were)
  // A bone mesh the node cannot use makes the whole scene unusable: every bone becomes a collision field.
  bool bonesUsable() const;
  int preparedCount() const;
};

// Prepares every muscle that can be prepared and writes the scene directory; a muscle that cannot be prepared is kept
// with its refusal (in the report, not in scene.yaml) and the others go on. Throws SceneError (or LoadError, or
// std::runtime_error for a file that cannot be written) only for what leaves no scene at all: an unreadable URDF or
// bone mesh, an unknown frame, no bones. `progress` hears one line per step finished.
ScenePreparation prepareScene(const ScenePreparationRequest& request,
                              const std::function<void(const std::string&)>& progress = {});

}  // namespace muscle_deformation
