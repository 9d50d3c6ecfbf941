// A reader of OpenSim 4 models (.osim) for what the product compares its muscles against: gait2392's musculotendon
// lengths and its muscles' path points (origin, via and insertion points). No OpenSim library is needed: the reader
// takes the kinematic tree (bodies, joints, coordinates) and every muscle's GeometryPath from the XML and evaluates
// them itself, with OpenSim's conventions:
//   - a joint places its child body by X_ground_child = X_ground_parent * X_parent_F * X_FM(q) * X_child_M^-1, where
//     F and M are the joint's parent and child offset frames (PhysicalOffsetFrame: translation, and orientation as
//     body-fixed X-Y-Z angles) and X_FM(q) is the joint's own motion;
//   - a CustomJoint's motion: rotation R(axis1, f1(q)) * R(axis2, f2(q)) * R(axis3, f3(q)) (each axis unit, the
//     second and third turning with the first), then translation f4 axis4 + f5 axis5 + f6 axis6 in F. Each f is a
//     function of at most one coordinate: LinearFunction, Constant, SimmSpline or a MultiplierFunction of one of
//     them; an axis with a coordinate and no function is that coordinate. PinJoint: rotation about F's z axis by its
//     coordinate; WeldJoint: none;
//   - a ConditionalPathPoint is in the path while its coordinate lies in its range (1e-5 tolerance, as OpenSim);
//   - a MovingPathPoint's x, y, z are functions of a coordinate, evaluated (as OpenSim) at its value clamped to its
//     range;
//   - a coordinate declared <clamped>true</clamped> is held to its range; a locked one takes the value it is given;
//   - the musculotendon length is the sum of the straight segments between consecutive active path points.
// Anything else that would change a pose or a path is refused with an error naming the file and element, never
// skipped: other joint types, reversed joints, other function types, frames other than bodies and their joint offset
// frames, and OpenSim 3 files (joints inside bodies). Wrap objects (WrapCylinder etc.) are read by name only: a muscle
// whose path wraps over one says so (OpenSimMuscle::wrap_objects) and its length is refused (the straight segments
// would be too short); its path points are still given. Kinematic constraints (ConstraintSet) are listed, not
// enforced (kinematicConstraints). gait2392 has neither wrap objects nor constraints.
// Units: metres and radians throughout, as in the file.
#pragma once

#include "muscle_deformation/core/scene/motion_file.hpp"
#include "muscle_deformation/core/scene/skeleton.hpp"

#include <Eigen/Geometry>

#include <cstddef>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace muscle_deformation {

// How a coordinate moves its joint, which decides its unit (rad or m) and whether a motion file's degrees apply to it.
// OpenSim's rule: rotational when it is the angle of one of its joint's rotation axes (identity function),
// translational when it is the displacement along a translation axis, coupled otherwise (e.g. it drives an axis only
// through a spline).
enum class CoordinateMotion { rotational, translational, coupled };

struct OpenSimCoordinate {
  std::string name;
  std::string joint;
  CoordinateMotion motion = CoordinateMotion::coupled;
  double default_value = 0;             // rad or m
  double range_min = 0, range_max = 0;  // rad or m
  bool clamped = false;                 // values are held to [range_min, range_max]
};

// What kind of path point, as OpenSim calls them: PathPoint, ConditionalPathPoint, MovingPathPoint.
enum class PathPointKind { fixed, conditional, moving };

struct OpenSimMuscle {
  std::string name;
  std::string type;                           // the element, e.g. Millard2012EquilibriumMuscle
  std::vector<std::string> path_point_names;  // every path point, active or not, in path order
  // Names of the wrap objects its GeometryPath wraps over. Not empty: musculotendonLength refuses this muscle.
  std::vector<std::string> wrap_objects;
};

// One path point of a muscle that is active at the given coordinates, e.g. the first is the origin, the last the
// insertion and those between are via points.
struct MusclePathPoint {
  std::string name;  // as in the model, e.g. rect_fem_r-P3
  PathPointKind kind = PathPointKind::fixed;
  std::string body;                    // the body it is fixed to
  Eigen::Vector3d location_in_body;    // m, in that body's frame (for a moving point: at these coordinates)
  Eigen::Vector3d location_in_ground;  // m
};

// Coordinate name -> value (rad or m). A coordinate that is not given is at its default value.
using CoordinateValues = std::map<std::string, double>;

// Body name -> scale factors along that body's x, y, z axes (dimensionless, > 0). Bodies not named keep factor 1.
using BodyScaleFactors = std::map<std::string, Eigen::Vector3d>;

class OpenSimModel {
 public:
  // Reads an .osim file. Throws SceneError naming the file (and the element and its line) for a missing or unparsable
  // file and for anything the reader refuses (see above).
  static OpenSimModel fromFile(const std::string& path);

  // A copy scaled as OpenSim's ScaleTool scales a model (per-body factors along the body's own axes):
  //   - every path point on a body: its location times the body's factors, component by component; a moving point's
  //     x, y, z functions times the body's x, y, z factor (OpenSim 4 leaves a component that names no coordinate
  //     unscaled; here it is scaled like the others: none of gait2392's moving points has such a component);
  //   - every joint: the translation of its parent offset frame times the factors of the body that frame is on (the
  //     parent body), the translation of its child offset frame times those of the child body;
  //   - a CustomJoint's translation functions (rotation functions never): each one times the parent body's factors
  //     projected on that translation's unit axis (for gait2392's knee: tx(q) times the femur's x factor, ty(q) times
  //     its y factor), except a translation that is a coordinate itself (identity LinearFunction, e.g. the pelvis
  //     translations): that is a degree of freedom, not a length of the model.
  // Not scaled: rotations, offset frame orientations, coordinate values, defaults and ranges, the ranges of
  // conditional points, the spline abscissae (coordinate values), wrap objects. Scaling twice multiplies the factors.
  // Throws std::invalid_argument for an unknown body, for ground (it cannot be scaled) or a factor that is not a
  // finite number > 0.
  OpenSimModel scaled(const BodyScaleFactors& factors) const;

  const std::string& source() const;  // the file it was read from
  // Bodies in the order the file declares them, ground (named "ground") first.
  std::vector<std::string> bodyNames() const;
  const std::vector<OpenSimCoordinate>& coordinates() const;  // in the order the joints declare them
  // Throws std::invalid_argument naming the model file for an unknown coordinate or muscle.
  const OpenSimCoordinate& coordinate(const std::string& name) const;
  bool hasCoordinate(const std::string& name) const;
  // The model's kinematic constraints (ConstraintSet, e.g. "CoordinateCouplerConstraint patella_coupler"). They are
  // not enforced: coordinates take the values they are given, so give values that satisfy them (as inverse kinematics
  // writes them).
  const std::vector<std::string>& kinematicConstraints() const;
  const std::vector<OpenSimMuscle>& muscles() const;  // every force of the ForceSet with a GeometryPath, in file order
  const OpenSimMuscle& muscle(const std::string& name) const;

  // Every body's pose in ground (body frame -> ground frame, m). Throws std::invalid_argument naming the model file for
  // an unknown coordinate or a value that is not finite.
  std::map<std::string, Eigen::Isometry3d> bodyPosesInGround(const CoordinateValues& values) const;
  // The muscle's path points that are active at these coordinates, in path order.
  std::vector<MusclePathPoint> activePathPoints(const std::string& muscle, const CoordinateValues& values) const;
  // Sum of the distances between consecutive active path points (m). Throws SceneError for a muscle whose path wraps.
  double musculotendonLength(const std::string& muscle, const CoordinateValues& values) const;

  struct Data;  // the parsed model; defined in the source file, so that the XML library stays out of this header

 private:
  explicit OpenSimModel(std::shared_ptr<const Data> data) : data_(std::move(data)) {}
  std::shared_ptr<const Data> data_;
};

// The coordinate values of one row of a motion table, in SI units: every column that names a coordinate of the model,
// rotational ones converted from degrees to radians when the table is in degrees (MotionTable::angles_in_degrees).
// Columns that are not coordinates of the model are left out (motionColumnsNotInModel lists them). Throws
// std::invalid_argument naming the motion file for a row past its end, and for a coupled coordinate in a table in
// degrees (its unit would be a guess).
CoordinateValues coordinateValuesAt(const OpenSimModel& model, const MotionTable& motion, std::size_t row);

// The columns of a motion table that name no coordinate of the model (e.g. speeds or forces written beside them).
std::vector<std::string> motionColumnsNotInModel(const OpenSimModel& model, const MotionTable& motion);

}  // namespace muscle_deformation
