// Attachment sites of prepared muscles: parsing, the OpenSim path points, and their placement against the belly.
#include "muscle_deformation/preprocessing/attachment_sites.hpp"

#include "muscle_deformation/core/base/inside_test.hpp"
#include "muscle_deformation/core/base/median.hpp"
#include "muscle_deformation/core/scene/opensim_model.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>

namespace muscle_deformation {

namespace {

std::string millimetres(double metres) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(1) << metres * 1e3 << " mm";
  return out.str();
}

// Arc length along the polyline `path` of the point of it nearest `x`; beyond an end along its end segment the
// segment's extension counts (negative before the start, past the length after the end), so that a belly reaching past
// an end of the path shows.
double arcPosition(const std::vector<Eigen::Vector3d>& path, const Eigen::Vector3d& x) {
  double best_distance = std::numeric_limits<double>::infinity(), best_arc = 0, start = 0;
  const std::size_t segments = path.size() - 1;
  for (std::size_t k = 0; k < segments; ++k) {
    const Eigen::Vector3d segment = path[k + 1] - path[k];
    const double length = segment.norm();
    const double raw = length > 0 ? (x - path[k]).dot(segment) / (length * length) : 0.0;
    const double t = std::clamp(raw, 0.0, 1.0);
    const double distance = (path[k] + t * segment - x).norm();
    if (distance < best_distance) {
      best_distance = distance;
      double along = t;
      if (k == 0 && raw < 0) along = raw;
      if (k + 1 == segments && raw > 1) along = raw;
      best_arc = start + along * length;
    }
    start += length;
  }
  return best_arc;
}

}  // namespace

LinkWithSite parseLinkWithSite(const std::string& text) {
  LinkWithSite result;
  const std::size_t at = text.find('@');
  result.link = text.substr(0, at);
  if (result.link.empty()) throw std::invalid_argument("'" + text + "': the link is empty");
  if (at == std::string::npos) return result;
  const std::string coordinates = text.substr(at + 1);
  Eigen::Vector3d site;
  std::size_t begin = 0;
  for (int k = 0; k < 3; ++k) {
    const std::size_t comma = coordinates.find(',', begin);
    if ((k < 2) != (comma != std::string::npos))
      throw std::invalid_argument("'" + text + "': the site must be LINK@x,y,z (three numbers, metres in the link's "
                                  "frame)");
    const std::string number = coordinates.substr(begin, k < 2 ? comma - begin : std::string::npos);
    std::size_t used = 0;
    try {
      site[k] = std::stod(number, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (number.empty() || used != number.size())
      throw std::invalid_argument("'" + text + "': '" + number + "' is not a number (the site is LINK@x,y,z, metres)");
    if (!std::isfinite(site[k])) throw std::invalid_argument("'" + text + "': the site's coordinates must be finite");
    begin = comma + 1;
  }
  result.site = site;
  return result;
}

int TendonPaths::farFromBone(double* largest_m) const {
  int far = 0;
  double largest = 0;
  for (const std::vector<PreparedSite>* path : {&origin_path, &insertion_path})
    for (const PreparedSite& site : *path) {
      if (std::abs(site.bone_distance_m) <= kSiteFarFromBoneM) continue;
      ++far;
      largest = std::max(largest, std::abs(site.bone_distance_m));
    }
  if (largest_m) *largest_m = largest;
  return far;
}

std::string TendonPaths::source() const {
  std::ostringstream out;
  const auto list = [&](const std::vector<PreparedSite>& sites) {
    for (std::size_t k = 0; k < sites.size(); ++k) out << (k ? ", then " : "") << sites[k].label;
  };
  out << "origin: ";
  if (origin_path.empty()) out << "none (the bone's nearest point)";
  list(origin_path);
  out << "; insertion: ";
  if (insertion_path.empty()) out << "none (the bone's nearest point)";
  list(insertion_path);
  for (const std::string& note : notes) out << "; " << note;
  return out.str();
}

std::string openSimCounterpart(const OpenSimModel& model, const OpenSimSiteRequest& request,
                               const std::string& muscle) {
  const auto has = [&](const std::string& name) {
    const auto& muscles = model.muscles();
    return std::any_of(muscles.begin(), muscles.end(), [&](const OpenSimMuscle& m) { return m.name == name; });
  };
  if (const auto mapped = request.muscles.find(muscle); mapped != request.muscles.end()) {
    if (!has(mapped->second))
      throw std::invalid_argument("--osim-muscle " + muscle + "=" + mapped->second + ": " + model.source() +
                                  " has no muscle '" + mapped->second + "'");
    return mapped->second;
  }
  return has(muscle) ? muscle : "";
}

std::vector<PathCandidate> pathCandidates(const std::string& muscle, const LinkWithSite& origin,
                                          const LinkWithSite& insertion, const OpenSimModel* osim,
                                          const std::string& osim_muscle, const std::map<std::string, std::string>& bodies,
                                          const std::vector<std::string>& links_with_bones, std::vector<std::string>& notes) {
  std::vector<PathCandidate> candidates;
  if (osim && !osim_muscle.empty()) {
    CoordinateValues zero;
    for (const OpenSimCoordinate& coordinate : osim->coordinates()) zero[coordinate.name] = 0.0;
    const std::vector<MusclePathPoint> points = osim->activePathPoints(osim_muscle, zero);
    for (std::size_t k = 0; k < points.size(); ++k) {
      const MusclePathPoint& point = points[k];
      const auto mapped = bodies.find(point.body);
      const std::string link = mapped == bodies.end() ? point.body : mapped->second;
      if (std::find(links_with_bones.begin(), links_with_bones.end(), link) == links_with_bones.end())
        throw std::invalid_argument("muscle '" + muscle + "': path point " + point.name + " of OpenSim muscle '" +
                                    osim_muscle + "' lies on body '" + point.body + "', and link '" + link +
                                    "' is no link of the URDF with a bone (map the body with --osim-body " +
                                    point.body + "=LINK)");
      PathCandidate candidate{point.name + " (" + osim_muscle + ")", {link, point.location_in_body},
                              PathCandidate::Role::via};
      if (k == 0) candidate.role = PathCandidate::Role::origin_site;
      else if (k + 1 == points.size()) candidate.role = PathCandidate::Role::insertion_site;
      candidates.push_back(std::move(candidate));
    }
    const OpenSimMuscle& described = osim->muscle(osim_muscle);
    if (const std::size_t inactive = described.path_point_names.size() - points.size(); inactive > 0)
      notes.push_back(std::to_string(inactive) + " conditional path point" + (inactive > 1 ? "s" : "") +
                      " of " + osim_muscle + " inactive at the zero configuration left out");
    if (!described.wrap_objects.empty())
      notes.push_back(osim_muscle + " wraps over " + described.wrap_objects.front() +
                      (described.wrap_objects.size() > 1 ? " and others" : "") +
                      " in OpenSim; here its tendons follow its path points only");
  }
  const auto given = [&](const LinkWithSite& end, PathCandidate::Role role, const char* which) {
    if (!end.site) return;
    PathCandidate site{std::string(which) + " site (command line)", {end.link, *end.site}, role};
    const bool origin_end = role == PathCandidate::Role::origin_site;
    PathCandidate* model_site = candidates.empty() ? nullptr : origin_end ? &candidates.front() : &candidates.back();
    if (model_site && model_site->role == role) {
      notes.push_back("the command line's " + std::string(which) + " site replaces " + model_site->label);
      *model_site = site;
    } else if (origin_end) {
      candidates.insert(candidates.begin(), site);
    } else {
      candidates.push_back(site);
    }
  };
  given(origin, PathCandidate::Role::origin_site, "origin");
  given(insertion, PathCandidate::Role::insertion_site, "insertion");
  return candidates;
}

TendonPaths placeAgainstBelly(const std::vector<PathCandidate>& candidates, const TriangleMesh& belly,
                              const std::vector<Polyline>& fibres,
                              const std::map<std::string, Eigen::Isometry3d>& rest_link_poses,
                              const std::vector<Bone>& bones) {
  TendonPaths paths;
  if (candidates.empty()) return paths;
  const ClosedSurfaceInsideTest inside_belly(belly, "the muscle's surface");
  std::map<std::string, std::unique_ptr<ClosedSurfaceInsideTest>> bone_tests;
  const auto placed = [&](const PathCandidate& candidate) {
    PreparedSite site{candidate.label, candidate.site, 0.0};
    const Eigen::Vector3d at = rest_link_poses.at(candidate.site.link) * candidate.site.point;
    const auto bone = std::find_if(bones.begin(), bones.end(), [&](const Bone& b) { return b.name == site.site.link; });
    if (bone != bones.end()) {
      auto& test = bone_tests[bone->name];
      if (!test) test = std::make_unique<ClosedSurfaceInsideTest>(bone->surface, bone->name);
      site.bone_distance_m = (test->contains(at) ? -1.0 : 1.0) * test->distanceToSurface(at);
    }
    return site;
  };

  std::vector<Eigen::Vector3d> path;
  for (const PathCandidate& c : candidates) path.push_back(rest_link_poses.at(c.site.link) * c.site.point);
  std::vector<bool> inside(candidates.size());
  for (std::size_t k = 0; k < candidates.size(); ++k) inside[k] = inside_belly.contains(path[k]);

  // Where the belly's two ends lie along the path: the median arc position of the fibres' first and last points.
  double origin_end = -std::numeric_limits<double>::infinity(), insertion_end = std::numeric_limits<double>::infinity();
  std::vector<double> arcs(candidates.size(), 0.0);
  if (path.size() >= 2 && !fibres.empty()) {
    std::vector<double> first, last;
    for (const Polyline& fibre : fibres) {
      if (fibre.cols() == 0) continue;
      first.push_back(arcPosition(path, fibre.col(0)));
      last.push_back(arcPosition(path, fibre.col(fibre.cols() - 1)));
    }
    if (!first.empty()) {
      origin_end = upperMedian(first);
      insertion_end = upperMedian(last);
    }
    for (std::size_t k = 1; k < path.size(); ++k) arcs[k] = arcs[k - 1] + (path[k] - path[k - 1]).norm();
  }

  bool origin_open = true, insertion_open = true;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    const PathCandidate& c = candidates[k];
    if (c.role == PathCandidate::Role::via) continue;
    if (!inside[k]) continue;
    const bool origin = c.role == PathCandidate::Role::origin_site;
    (origin ? origin_open : insertion_open) = false;
    paths.notes.push_back(c.label + " lies inside the belly (" + millimetres(inside_belly.distanceToSurface(path[k])) +
                          " deep): the " + (origin ? "origin" : "insertion") +
                          " fibre ends hang from the bone's nearest point");
  }
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    const PathCandidate& c = candidates[k];
    if (c.role == PathCandidate::Role::origin_site) {
      if (origin_open) paths.origin_path.push_back(placed(c));
    } else if (c.role == PathCandidate::Role::insertion_site) {
      if (insertion_open) paths.insertion_path.push_back(placed(c));
    } else if (inside[k]) {
      paths.belly_path.push_back(placed(c));
      paths.notes.push_back(c.label + " left out: inside the belly (on the belly's path)");
    } else if (origin_open && arcs[k] < origin_end) {
      paths.origin_path.push_back(placed(c));
    } else if (insertion_open && arcs[k] > insertion_end) {
      paths.insertion_path.push_back(placed(c));  // the insertion site comes last in path order
    } else {
      paths.belly_path.push_back(placed(c));
      paths.notes.push_back(c.label + " left out: within the belly's extent along the path (on the belly's path)");
    }
  }
  return paths;
}

}  // namespace muscle_deformation
