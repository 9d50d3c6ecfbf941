// Where a prepared muscle's tendons attach: sites the user gives with the muscle (`LINK@x,y,z`) or the path points of
// an OpenSim model of the same skeleton (`--osim`). The points become the scene's `origin_path` and `insertion_path`
// (the form the bundled scene uses, scene.hpp): the node then runs each fibre end's tendon to the site through its via
// points instead of hanging it from the bone's nearest point, so that a joint between the belly and the site changes
// the muscle's length as it does in the body.
#pragma once

#include "muscle_deformation/core/base/anatomy.hpp"
#include "muscle_deformation/core/base/geometry.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include <Eigen/Geometry>

#include <map>
#include <optional>
#include <string>
#include <vector>

namespace muscle_deformation {

class OpenSimModel;

// One end of a muscle on the command line: a URDF link, optionally with the site on it (`LINK@x,y,z`, metres in the
// link's frame).
struct LinkWithSite {
  std::string link;
  std::optional<Eigen::Vector3d> site;
};

// `LINK` or `LINK@x,y,z`. Throws std::invalid_argument saying what is wrong (an empty link, not three numbers, a
// number that is not finite).
LinkWithSite parseLinkWithSite(const std::string& text);

// Sites from an OpenSim model (.osim) of the same skeleton: each body's frame is its link's frame, so a path point's
// location in its body is the site in the link's frame. Conditional and moving points are taken at every coordinate
// 0, the URDF's zero configuration the muscle files are given in.
struct OpenSimSiteRequest {
  std::string osim_file;                       // empty: no OpenSim sites
  std::map<std::string, std::string> muscles;  // scene muscle -> OpenSim muscle; not named: the one of its own name
  std::map<std::string, std::string> bodies;   // OpenSim body -> URDF link; not named: the link of its own name
};

// A site further than this from its bone's surface is flagged (m): a site in another frame or unit, or from a model of
// another skeleton, lies centimetres off, while a segmented bone and a model's site agree within millimetres.
constexpr double kSiteFarFromBoneM = 0.01;

// One point of a tendon path as prepared: where it came from, the point, and how far it lies from its bone.
struct PreparedSite {
  std::string label;  // e.g. "origin site (command line)", "semiten_r-P1 (origin)"
  SitePoint site;     // the link and the point in the link's frame (m), as the scene file takes it
  double bone_distance_m = 0;  // from its link's bone surface at rest: > 0 outside, < 0 inside
};

// The tendon paths of one muscle, in the scene's order (origin_path: the site first, then the via points towards the
// belly; insertion_path: the via points from the belly, then the site), and what was left out and why.
struct TendonPaths {
  std::vector<PreparedSite> origin_path, insertion_path;
  // The via points the belly covers (inside it, or beside it within its extent along the path), in path order: the
  // line its fibres follow between the tendons (the scene's `belly_path`, Muscle::belly_path).
  std::vector<PreparedSite> belly_path;
  std::vector<std::string> reference_muscles;  // the OpenSim muscle the points come from (empty: none)
  std::vector<std::string> notes;
  bool empty() const { return origin_path.empty() && insertion_path.empty(); }
  // The points further than kSiteFarFromBoneM from their bone, and the largest such distance (m).
  int farFromBone(double* largest_m = nullptr) const;
  // One line for the scene file's `sites_source` and the report.
  std::string source() const;
};

// A path point before it is placed against the belly: its label, its link and the point in the link's frame, and
// whether it is the origin or the insertion site (otherwise a via point).
struct PathCandidate {
  std::string label;
  SitePoint site;
  enum class Role { origin_site, via, insertion_site } role = Role::via;
};

// The candidates of one muscle, in path order (origin to insertion): from the OpenSim model when `osim` has this
// muscle (`osim_muscle` empty: none), then a command-line site replacing the model's site at its end. Throws
// std::invalid_argument when a path point's body maps to no link in `links_with_bones` (naming the body and the map).
std::vector<PathCandidate> pathCandidates(const std::string& muscle, const LinkWithSite& origin,
                                          const LinkWithSite& insertion, const OpenSimModel* osim,
                                          const std::string& osim_muscle, const std::map<std::string, std::string>& bodies,
                                          const std::vector<std::string>& links_with_bones, std::vector<std::string>& notes);

// Places the candidates against the belly (surface and fibres at rest, scene frame; `rest_link_poses`: link -> scene
// frame at the zero configuration): a point inside the belly is left out (a site inside it: its whole side is, the
// fibre ends there lie on the bone); a via point goes to the origin's tendon when it lies before the origin fibre ends'
// median position along the path, to the insertion's when after the insertion ends', and is left out between them (the
// belly covers it). Each point's distance to its link's bone is measured.
TendonPaths placeAgainstBelly(const std::vector<PathCandidate>& candidates, const TriangleMesh& belly,
                              const std::vector<Polyline>& fibres,
                              const std::map<std::string, Eigen::Isometry3d>& rest_link_poses,
                              const std::vector<Bone>& bones);

// The OpenSim muscle a scene muscle takes its sites from: the one `request` maps it to, else the one of its own name,
// else "" (none). Throws std::invalid_argument when the map names a muscle the model lacks.
std::string openSimCounterpart(const OpenSimModel& model, const OpenSimSiteRequest& request, const std::string& muscle);

}  // namespace muscle_deformation
