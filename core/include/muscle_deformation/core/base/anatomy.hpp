// The anatomy the product deforms: rigid bones, muscles with fibres, and a skeleton pose.
#pragma once

#include "muscle_deformation/core/base/geometry.hpp"

#include <Eigen/Geometry>

#include <map>
#include <string>
#include <vector>

namespace muscle_deformation {

struct Bone {
  int id = -1;           // index in the scene's bone list
  std::string name;      // URDF link name, e.g. "femur_r"
  TriangleMesh surface;  // rest pose, metres, in the scene (fixed) frame
};

// A point on a bone a tendon runs through: where it attaches (the site) or wraps over the bone (a via point).
struct AttachmentSite {
  std::string bone;       // Bone::name (the URDF link)
  Eigen::Vector3d point;  // rest pose, metres, scene frame
};

struct Muscle {
  std::string name;               // e.g. "rectus_femoris"
  TriangleMesh surface;           // closed, 2-manifold, rest pose, scene frame
  std::vector<Polyline> fibres;   // origin to insertion, rest pose, scene frame
  // The bones (Bone::name) the muscle is attached to: its particles are fixed to these only, and collide with any
  // other bone. Both empty: the muscle is attached to whichever bone its particles are near (synthetic set-ups).
  std::string origin_bone, insertion_bone;
  // The tendons' paths where the belly ends short of its attachment (the tendon was not segmented): from the origin
  // site on its bone towards the belly (the last point is the one nearest the belly), and from the belly to the
  // insertion site (the first point nearest the belly). Empty: a fibre end away from its bone hangs from the bone's
  // nearest point (ModelSettings::tendons).
  std::vector<AttachmentSite> origin_path, insertion_path;
  // The line the belly's fibres follow between its tendons where it bends round a bone (the reference path's via
  // points the belly covers, e.g. the iliacus over the pelvic brim), from origin to insertion, each carried by its
  // bone. The belly's tone measures each fibre's span along it (ModelSettings::fibre_tone); empty: the straight line
  // between the fibre's attachments.
  std::vector<AttachmentSite> belly_path;
  // Particles sampled along each of this muscle's fibres; 0 = the model's (ModelSettings::particles_per_fibre). A
  // scene models each muscle only as finely as its error target needs (a small, stiff muscle keeps its shape with
  // fewer particles than a long, bending one).
  int particles_per_fibre = 0;
};

// Rigid transform of every bone from its rest placement to the current one (scene frame).
// Bones missing from the map stay at rest.
struct Pose {
  std::map<std::string, Eigen::Isometry3d> bone_transforms;

  Eigen::Isometry3d transformOf(const std::string& bone) const {
    auto it = bone_transforms.find(bone);
    return it == bone_transforms.end() ? Eigen::Isometry3d::Identity() : it->second;
  }
};

}  // namespace muscle_deformation
