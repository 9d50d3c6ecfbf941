// scene.yaml, report.md and view.rviz of a prepared scene directory.
#include "muscle_deformation/preprocessing/scene_directory.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>

namespace muscle_deformation {

namespace fs = std::filesystem;

namespace {

std::string fixed(double value, int decimals) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(decimals) << value;
  return out.str();
}

// A site coordinate in metres to a tenth of a micrometre, without trailing zeros.
std::string coordinate(double metres) {
  std::ostringstream out;
  out << std::setprecision(7) << metres;
  return out.str();
}

std::string millimetres(double metres) { return fixed(metres * 1e3, 1) + " mm"; }

// Sites as the scene file's list items, each point in its link's frame (metres).
void writeSites(std::ostream& y, const std::vector<PreparedSite>& sites) {
  for (const PreparedSite& site : sites)
    y << "  - {link: " << doubleQuoted(site.site.link) << ", point: [" << coordinate(site.site.point.x()) << ", "
      << coordinate(site.site.point.y()) << ", " << coordinate(site.site.point.z()) << "]}\n";
}

std::string colourList(const std::array<float, 4>& colour) {
  std::string out = "[";
  for (std::size_t k = 0; k < colour.size(); ++k) out += (k ? ", " : "") + fixed(colour[k], 2);
  return out + "]";
}

void writeFile(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path.string() + ": cannot open for writing: " + std::strerror(errno));
  out << text;
  out.close();
  if (!out) throw std::runtime_error(path.string() + ": write failed");
}

// The URDF from the scene directory: relative, so that the directory and the URDF can move together.
std::string urdfFromSceneDirectory(const ScenePreparation& p) {
  return fs::path(p.urdf_file).lexically_relative(p.out_dir).string();
}

std::string sceneYaml(const ScenePreparation& p) {
  std::ostringstream y;
  y << "# Scene made by prepare_scene (report.md says what was done and measured). Run it with\n"
    << "#   roslaunch muscle_deformation gait_playback.launch scene:=<this file> urdf:=<the urdf below> bag:=...\n"
    << "# Metres; muscle surfaces and fibres in the frame of link `frame` at the URDF's zero configuration. Paths are\n"
    << "# relative to this file's folder.\n"
    << "urdf: " << doubleQuoted(urdfFromSceneDirectory(p)) << "\n"
    << "frame: " << doubleQuoted(p.frame) << "\n";
  if (!p.osim_file.empty())
    y << "# The OpenSim model of the same skeleton the attachment sites come from (each body's frame its link's).\n"
      << "reference_model:\n  osim: " << doubleQuoted(fs::path(p.osim_file).lexically_relative(p.out_dir).string())
      << "\n";
  bool any_stand_in = false;
  for (const BoneMeshCheck& bone : p.bone_meshes) any_stand_in = any_stand_in || !bone.stand_in.empty();
  if (any_stand_in) {
    y << "# Closed copies of the URDF's bone meshes that were not closed (same units and frame as the mesh they\n"
      << "# replace: the URDF's scale and origin apply to them).\n"
      << "bone_surfaces:\n";
    for (const BoneMeshCheck& bone : p.bone_meshes)
      if (!bone.stand_in.empty())
        y << "- mesh: " << doubleQuoted(bone.uri) << "\n  surface: " << doubleQuoted(bone.stand_in) << "\n";
  }
  y << "muscles:\n";
  for (const PreparedMuscle& m : p.muscles) {
    if (!m.prepared()) continue;
    y << "- name: " << doubleQuoted(m.source.name) << "\n"
      << "  surface: " << doubleQuoted(m.surface_file) << "\n"
      << "  fibres: " << doubleQuoted(m.fibre_file) << "\n"
      << "  origin_bone: " << doubleQuoted(m.source.origin_link) << "\n"
      << "  insertion_bone: " << doubleQuoted(m.source.insertion_link) << "\n"
      << "  color: " << colourList(m.colour) << "\n"
      << "  rest_volume_ml: " << fixed(m.volume_m3 * 1e6, 1) << "\n"
      << "  source: " << doubleQuoted(fs::absolute(m.source.mesh_file).lexically_normal().string()) << "\n";
    if (p.resolution)
      for (const MuscleResolution& chosen : p.resolution->muscles)
        if (chosen.muscle == m.source.name)
          y << "  particles_per_fibre: " << chosen.chosen << "  # chosen for the surface error target (report.md)\n";
    if (m.sites.empty() && m.sites.reference_muscles.empty()) continue;
    // The tendons' paths, each point in its link's frame (metres): the node runs the fibre ends' tendons through them.
    for (const auto& [key, path] : {std::pair{"origin_path", &m.sites.origin_path},
                                    std::pair{"insertion_path", &m.sites.insertion_path}}) {
      y << "  " << key << ":" << (path->empty() ? " []" : "") << "\n";
      writeSites(y, *path);
    }
    // The via points the belly covers: the line its tone measures each fibre's span along.
    if (!m.sites.belly_path.empty()) {
      y << "  belly_path:\n";
      writeSites(y, m.sites.belly_path);
    }
    y << "  reference_muscles: [";
    for (std::size_t k = 0; k < m.sites.reference_muscles.size(); ++k)
      y << (k ? ", " : "") << doubleQuoted(m.sites.reference_muscles[k]);
    y << "]\n  sites_source: " << doubleQuoted(m.sites.source()) << "\n";
  }
  return y.str();
}

std::string patchText(bool from_bone, const std::string& link) {
  return from_bone ? "bone region of '" + link + "'" : "the muscle's end along its principal axis";
}

std::string musclesTable(const ScenePreparation& p) {
  std::ostringstream r;
  r << "| muscle | prepared | surface | volume (ml) | fibres | fibre checks | origin / insertion patch | inside a bone at rest |\n"
    << "| --- | --- | --- | ---: | ---: | --- | --- | --- |\n";
  for (const PreparedMuscle& m : p.muscles) {
    r << "| " << m.source.name << " | ";
    if (!m.prepared()) {
      r << "**no** (below) | | | | | | |\n";
      continue;
    }
    r << "yes | " << (m.repair.level_set ? "rebuilt from a level set" : m.repair.changed() ? "repaired" : "closed as given")
      << " | " << fixed(m.volume_m3 * 1e6, 1)
      << " | " << m.fibres.fibres.size() << " | " << (m.fibres.checks.passed() ? "passed" : "**failed**") << " | "
      << (m.fibres.patches.origin_from_bone ? "bone" : "axis end") << " / "
      << (m.fibres.patches.insertion_from_bone ? "bone" : "axis end") << " | ";
    if (m.overlaps.empty()) r << "no";
    for (std::size_t i = 0; i < m.overlaps.size(); ++i)
      r << (i ? ", " : "") << m.overlaps[i].bone << " " << fixed(100 * m.overlaps[i].share, 1) << " %";
    r << " |\n";
  }
  return r.str();
}

// The tendons' paths to the attachment sites, each point with its distance to its bone, and what was left out.
std::string attachmentSitesText(const PreparedMuscle& m) {
  std::ostringstream r;
  if (m.sites.empty() && m.sites.notes.empty()) {
    r << "- Attachment sites: none given; the fibre ends away from their bone hang from its nearest point.\n";
    return r.str();
  }
  r << "- Attachment sites (tendon paths, in each link's frame; distance from the bone's surface, negative inside):\n";
  for (const auto& [which, path] : {std::pair{"origin", &m.sites.origin_path},
                                    std::pair{"insertion", &m.sites.insertion_path}}) {
    r << "  - " << which << ": ";
    if (path->empty()) r << "none (the bone's nearest point)";
    for (std::size_t k = 0; k < path->size(); ++k) {
      const PreparedSite& site = (*path)[k];
      r << (k ? "; " : "") << site.label << " on `" << site.site.link << "` at (" << fixed(site.site.point.x(), 4)
        << ", " << fixed(site.site.point.y(), 4) << ", " << fixed(site.site.point.z(), 4) << ") m, "
        << millimetres(site.bone_distance_m) << " from the bone";
      if (std::abs(site.bone_distance_m) > kSiteFarFromBoneM)
        r << " (**far from the bone**: is the site in the link's frame, in metres?)";
    }
    r << "\n";
  }
  for (const std::string& note : m.sites.notes) r << "  - " << note << ".\n";
  return r.str();
}

// The per-muscle resolution study: each candidate's worst surface RMS to the finest model, and the choice.
std::string resolutionSection(const ScenePreparation& p) {
  std::ostringstream r;
  if (!p.resolution_problem.empty())
    r << "## Resolution per muscle\n\nThe resolutions could not be chosen: " << p.resolution_problem << "\n\n";
  if (!p.resolution) return r.str();
  const ResolutionChoice& c = *p.resolution;
  r << "## Resolution per muscle\n\nEach muscle's particles per fibre: the coarsest whose skinned surface (before the "
       "bone contact and the volume projection) stays within the target RMS of the finest model's at every checked "
       "pose, each model solved cold to convergence (the node's settings). Checked poses: ";
  for (std::size_t k = 0; k < c.poses.size(); ++k) r << (k ? ", " : "") << c.poses[k];
  r << ". Measured in " << fixed(c.seconds, 0) << " s; the worst RMS (and largest vertex distance) in mm:\n\n| muscle |";
  for (std::size_t k = 0; k + 1 < c.resolutions.size(); ++k) r << " " << c.resolutions[k] << " per fibre |";
  r << " chosen |\n| --- |";
  for (std::size_t k = 0; k + 1 < c.resolutions.size(); ++k) r << " ---: |";
  r << " ---: |\n";
  for (const MuscleResolution& m : c.muscles) {
    r << "| " << m.muscle << " |";
    for (std::size_t k = 0; k < m.worst_rms_m.size(); ++k)
      r << " " << fixed(m.worst_rms_m[k] * 1e3, 2) << " (" << fixed(m.worst_max_m[k] * 1e3, 1) << ") |";
    r << " " << m.chosen << (m.met ? "" : " (**target not met**)") << " |\n";
  }
  r << "\nModel size, all muscles at one resolution:";
  for (std::size_t k = 0; k < c.model_particles.size(); ++k)
    r << (k ? "," : "") << " " << fixed(c.model_particles[k], 0) << " particles at " << c.resolutions[k];
  r << " per fibre (the last the reference).\n\n";
  return r.str();
}

std::string muscleSection(const ScenePreparation& p, const PreparedMuscle& m) {
  std::ostringstream r;
  r << "### " << m.source.name << "\n\n"
    << "- Source: `" << m.source.mesh_file << "` (x " << p.scale_to_metres << " to metres); origin `"
    << m.source.origin_link << "`, insertion `" << m.source.insertion_link << "`.\n";
  if (!m.prepared()) {
    r << "- **Not prepared**: " << m.refusal << "\n\n";
    return r.str();
  }
  if (m.defects.empty())
    r << "- Surface: closed and 2-manifold as given; written unchanged to `" << m.surface_file << "`.\n";
  else
    r << "- Surface: " << m.defects << "; repaired: " << m.repair.describe() << "; written to `" << m.surface_file
      << "`.\n";
  r << "- Volume: " << fixed(m.volume_m3 * 1e6, 1) << " ml; " << m.surface.triangleCount() << " triangles.\n";
  const FibreCheckReport& c = m.fibres.checks;
  r << "- Fibres (`" << m.fibre_file << "`): " << m.fibres.fibres.size() << " of " << p.fibres_asked << ", voxel "
    << millimetres(m.fibres.voxel_size) << "; checks " << (c.passed() ? "passed" : "**FAILED**") << ": "
    << c.describe() << ".\n";
  for (const std::string& warning : m.fibres.warnings) r << "  - Warning: " << warning << ".\n";
  r << "- Attachment regions (where the fibres start and end): origin on "
    << patchText(m.fibres.patches.origin_from_bone, m.source.origin_link) << " ("
    << m.fibres.patches.origin_vertices.size() << " surface vertices), insertion on "
    << patchText(m.fibres.patches.insertion_from_bone, m.source.insertion_link) << " ("
    << m.fibres.patches.insertion_vertices.size() << " surface vertices).";
  for (const std::string& note : m.fibres.patches.notes) r << " " << note << ".";
  r << "\n";
  r << attachmentSitesText(m);
  const MuscleBuildSummary& a = m.attachments;
  if (a.particles > 0) {
    r << "- Attachments the node makes with its defaults: " << a.fixed_particles << " of " << a.particles
      << " particles fixed (";
    bool first = true;
    for (const auto& [bone, count] : a.fixed_by_bone) {
      r << (first ? "" : ", ") << count << " to " << bone;
      first = false;
    }
    if (first) r << "none";
    r << "); " << a.tendons << " fibre ends hang from their bone through a tendon";
    if (a.tendons > 0) r << " (longest " << millimetres(a.longest_tendon_m) << ")";
    if (std::isfinite(a.closest_attachments_m))
      r << "; closest particles fixed to two bones: " << millimetres(a.closest_attachments_m) << " apart ("
        << a.closest_attachment_bones[0] << ", " << a.closest_attachment_bones[1] << ")";
    r << ".\n";
  }
  if (p.rest_overlaps == RestOverlapRule::carve_bones) {
    r << "- Overlap with the bones as given, at rest:";
    if (m.overlaps_before_carving.empty()) r << " none.";
    for (const BoneOverlap& o : m.overlaps_before_carving)
      r << " " << o.bone << ": " << o.vertices_inside << " vertices (" << fixed(100 * o.share, 1) << " %), deepest "
        << millimetres(o.max_depth_m) << ";";
    r << (m.overlaps_before_carving.empty() ? "" : " those bones' copies were carved by the muscles (above).") << "\n";
  }
  if (m.overlaps.empty()) {
    r << "- Overlap with the bones" << (p.rest_overlaps == RestOverlapRule::carve_bones ? " the node uses" : "")
      << " at rest: none (no surface vertex inside a bone).\n";
  } else {
    r << "- Overlap with the bones at rest:";
    for (const BoneOverlap& o : m.overlaps)
      r << " " << o.bone << ": " << o.vertices_inside << " vertices (" << fixed(100 * o.share, 1)
        << " %), deepest " << millimetres(o.max_depth_m) << ";";
    r << " the node keeps those particles from going deeper, it does not push them out"
      << (p.rest_overlaps == RestOverlapRule::carve_bones ? "" : " (`--rest-overlaps carve-bones` carves the bones' copies)")
      << ".\n";
  }
  r << "\n";
  return r.str();
}

std::string reportMarkdown(const ScenePreparation& p) {
  std::ostringstream r;
  const int prepared = p.preparedCount();
  r << "# Scene preparation report\n\n";
  if (!p.command_line.empty()) r << "Made by `" << p.command_line << "`.\n\n";
  r << "Skeleton `" << p.urdf_file << "`, scene frame `" << p.frame << "`, " << p.bones.size()
    << " bones (links with collision meshes). " << prepared << " of " << p.muscles.size() << " muscles prepared"
    << (prepared == static_cast<int>(p.muscles.size()) ? "" : "; the others are left out of scene.yaml") << ".\n\n";
  if (!p.bonesUsable())
    r << "**The scene cannot run as it is**: a bone mesh below is unusable (the node makes every bone a collision "
         "field, which needs a closed surface).\n\n";
  r << "## Bones (the URDF's collision meshes)\n\n| link | mesh | triangles | as given | used by the node |\n"
    << "| --- | --- | ---: | --- | --- |\n";
  for (const BoneMeshCheck& b : p.bone_meshes) {
    r << "| " << b.link << " | `" << b.uri << "` | " << b.triangles << " | "
      << (b.defects.empty() ? "closed" : b.defects) << " | ";
    if (!b.carved_by.empty())
      r << "copy carved by " << b.carved_by << " `" << b.stand_in << "` (" << describeCarve(b.carve) << ")"
        << (b.defects.empty() ? "" : ", after its repair (" + b.repair.describe() + ")");
    else if (!b.stand_in.empty())
      r << "repaired copy `" << b.stand_in << "` (" << b.repair.describe() << ")";
    else if (b.problem.empty())
      r << "as given";
    else
      r << "**unusable**: " << b.problem;
    if (!b.carve_problem.empty()) r << "; **not carved**: " << b.carve_problem;
    r << " |\n";
  }
  r << "\n## Muscles\n\n" << musclesTable(p) << "\n";
  r << resolutionSection(p);
  for (const PreparedMuscle& m : p.muscles) r << muscleSection(p, m);
  if (!p.warnings.empty() || !p.model_problem.empty()) {
    r << "## Warnings of the model build\n\n";
    for (const std::string& w : p.warnings) r << "- " << w << "\n";
    if (!p.model_problem.empty()) r << "- The attachments could not be measured: " << p.model_problem << "\n";
    r << "\n";
  }
  if (prepared > 0) {
    r << "## Run it\n\n```\nroslaunch muscle_deformation gait_playback.launch scene:=" << p.out_dir << "/"
      << kSceneFileName << " \\\n    urdf:=" << p.urdf_file;
    if (p.frame != "pelvis") r << " fixed_frame:=" << p.frame;
    r << " rviz_config:=" << p.out_dir << "/" << kRvizFileName << " bag:=YOUR.bag\n```\n";
  }
  return r.str();
}

// The camera looks at the centre of the muscles and their bones from far enough to see all of them, along the
// horizontal axis the scene is thinnest in (for a hip or a thigh: from the front), turned a little for depth.
std::string rvizConfig(const ScenePreparation& p) {
  AlignedBox box;
  const auto add = [&](const TriangleMesh& mesh) {
    for (Eigen::Index v = 0; v < mesh.vertexCount(); ++v) box.extend(mesh.vertices.col(v));
  };
  for (const PreparedMuscle& m : p.muscles) {
    if (!m.prepared()) continue;
    add(m.surface);
    for (const Bone& bone : p.bones)
      if (bone.name == m.source.origin_link || bone.name == m.source.insertion_link) add(bone.surface);
  }
  if (box.empty())
    for (const Bone& bone : p.bones) add(bone.surface);
  const Eigen::Vector3d centre = box.empty() ? Eigen::Vector3d::Zero() : Eigen::Vector3d(0.5 * (box.min + box.max));
  const Eigen::Vector3d extent = box.empty() ? Eigen::Vector3d::Constant(1.0) : Eigen::Vector3d(box.max - box.min);
  constexpr double kFieldOfView = 0.785;  // rad, rviz's orbit view default
  const double distance = std::max(0.2, 0.5 * extent.norm() / std::sin(0.5 * kFieldOfView));
  const double yaw = (extent.x() < extent.y() ? 0.0 : 0.5 * M_PI) + 0.5;
  std::ostringstream v;
  v << R"(Panels:
  - Class: rviz/Displays
    Name: Displays
    Property Tree Widget:
      Expanded: ~
    Splitter Ratio: 0.5
    Tree Height: 500
Visualization Manager:
  Class: ""
  Displays:
    - Alpha: 0.5
      Cell Size: 0.1
      Class: rviz/Grid
      Color: 160; 160; 164
      Enabled: true
      Line Style:
        Line Width: 0.03
        Value: Lines
      Name: Grid
      Normal Cell Count: 0
      Offset:
        X: )" << fixed(centre.x(), 3) << R"(
        Y: )" << fixed(centre.y(), 3) << R"(
        Z: )" << fixed(box.empty() ? 0.0 : box.min.z(), 3) << R"(
      Plane: XY
      Plane Cell Count: 20
      Reference Frame: <Fixed Frame>
      Value: true
    - Class: rviz/MarkerArray
      Enabled: true
      Marker Topic: /muscle_deformation/bones
      Name: Bones
      Namespaces:
        {}
      Queue Size: 5
      Value: true
    - Alpha: 1
      Class: rviz/RobotModel
      Collision Enabled: false
      Enabled: false
      Links:
        All Links Enabled: true
        Expand Joint Details: false
        Expand Link Details: false
        Expand Tree: false
        Link Tree Style: Links in Alphabetic Order
      Name: Skeleton (URDF visuals)
      Robot Description: robot_description
      TF Prefix: ""
      Update Interval: 0
      Value: false
      Visual Enabled: true
    - Class: rviz/MarkerArray
      Enabled: true
      Marker Topic: /muscle_deformation/surface_markers
      Name: Muscle surfaces
      Namespaces:
        {}
      Queue Size: 5
      Value: true
    - Class: rviz/MarkerArray
      Enabled: true
      Marker Topic: /muscle_deformation/fibres
      Name: Fibres
      Namespaces:
        {}
      Queue Size: 5
      Value: true
    - Alpha: 1
      Autocompute Intensity Bounds: true
      Autocompute Value Bounds:
        Max Value: 10
        Min Value: -10
        Value: true
      Axis: Z
      Channel Name: strain
      Class: rviz/PointCloud2
      Color: 255; 255; 255
      Color Transformer: Intensity
      Decay Time: 0
      Enabled: false
      Invert Rainbow: false
      Max Color: 255; 255; 255
      Min Color: 0; 0; 0
      Name: Particles
      Position Transformer: XYZ
      Queue Size: 5
      Selectable: true
      Size (Pixels): 3
      Size (m): 0.003
      Style: Points
      Topic: /muscle_deformation/particles
      Unreliable: false
      Use Fixed Frame: true
      Use rainbow: true
      Value: false
  Enabled: true
  Global Options:
    Background Color: 48; 48; 48
    Default Light: true
    Fixed Frame: )" << p.frame << R"(
    Frame Rate: 30
  Name: root
  Tools:
    - Class: rviz/Interact
      Hide Inactive Objects: true
    - Class: rviz/MoveCamera
  Value: true
  Views:
    Current:
      Class: rviz/Orbit
      Distance: )" << fixed(distance, 3) << R"(
      Enable Stereo Rendering:
        Stereo Eye Separation: 0.06
        Stereo Focal Distance: 1
        Swap Stereo Eyes: false
        Value: false
      Field of View: )" << kFieldOfView << R"(
      Focal Point:
        X: )" << fixed(centre.x(), 3) << R"(
        Y: )" << fixed(centre.y(), 3) << R"(
        Z: )" << fixed(centre.z(), 3) << R"(
      Focal Shape Fixed Size: true
      Focal Shape Size: 0.05
      Invert Z Axis: false
      Name: Current View
      Near Clip Distance: 0.01
      Pitch: 0.15
      Target Frame: <Fixed Frame>
      Yaw: )" << fixed(yaw, 3) << R"(
    Saved: ~
Window Geometry:
  Displays:
    collapsed: true
  Height: 800
  Hide Left Dock: true
  Hide Right Dock: true
  Width: 1280
  X: 0
  Y: 0
)";
  return v.str();
}

}  // namespace

std::string describeCarve(const LevelSetRebuildReport& carve) {
  std::ostringstream out;
  out << "volume " << fixed(carve.input_volume_m3.value_or(std::nan("")) * 1e6, 1) << " ml -> "
      << fixed(carve.volume_m3 * 1e6, 1) << " ml";
  if (const std::optional<double> change = carve.volumeChange())
    out << " (" << (*change >= 0 ? "+" : "") << fixed(100 * *change, 2) << " %)";
  out << ", carved up to " << millimetres(carve.max_distance_to_input_m) << " deep";
  if (carve.pieces_dropped_volume_m3 >= 0.005e-6)  // what shows in the report's 0.01 ml
    out << ", pieces cut off (" << fixed(carve.pieces_dropped_volume_m3 * 1e6, 2) << " ml) dropped";
  out << ", " << carve.triangles << " triangles (voxel " << fixed(carve.voxel_m * 1e3, 2) << " mm, clearance "
      << fixed(kCarveClearanceM * 1e3, 2) << " mm";
  if (!carve.decimation_note.empty()) out << "; " << carve.decimation_note;
  out << ")";
  return out.str();
}

std::string doubleQuoted(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

void writeSceneDirectory(const ScenePreparation& preparation) {
  const fs::path dir = preparation.out_dir;
  fs::create_directories(dir);
  const fs::path scene = dir / kSceneFileName;
  if (preparation.preparedCount() > 0) {
    writeFile(scene, sceneYaml(preparation));
  } else {
    std::error_code ignored;
    fs::remove(scene, ignored);  // an earlier run's scene would pass for this one's
  }
  writeFile(dir / kReportFileName, reportMarkdown(preparation));
  writeFile(dir / kRvizFileName, rvizConfig(preparation));
}

}  // namespace muscle_deformation
