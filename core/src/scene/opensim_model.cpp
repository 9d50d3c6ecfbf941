#include "muscle_deformation/core/scene/opensim_model.hpp"

#include "muscle_deformation/core/scene/simm_spline.hpp"

#include <tinyxml2.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace muscle_deformation {
namespace {

using tinyxml2::XMLElement;

constexpr int kNoCoordinate = -1;
constexpr int kGround = 0;  // body index of ground
// OpenSim counts a conditional point as active this far outside its range (rad or m), so a point whose range ends at
// a coordinate's limit stays in the path at that limit despite rounding.
constexpr double kConditionalRangeTolerance = 1e-5;
// The first document version of OpenSim 4's format (joints in a JointSet, frames and sockets).
constexpr int kOpenSim4Version = 40000;

// A function of (at most) one coordinate, as OpenSim stores a transform axis's motion or a moving point's component.
struct CoordinateFunction {
  enum class Kind { constant, linear, spline };
  Kind kind = Kind::constant;
  double constant = 0;                      // Constant
  double slope = 0, intercept = 0;          // LinearFunction
  std::shared_ptr<const SimmSpline> spline;  // SimmSpline (shared: scaled copies of a model keep the knots)
  double scale = 1;                         // MultiplierFunction, and the factor scaled() applies

  double at(double q) const {
    switch (kind) {
      case Kind::constant: return scale * constant;
      case Kind::linear: return scale * (slope * q + intercept);
      case Kind::spline: return scale * spline->value(q);
    }
    return 0;
  }
  // The coordinate itself: the axis is that coordinate's degree of freedom.
  bool isIdentity() const { return kind == Kind::linear && slope * scale == 1 && intercept == 0; }
};

struct TransformAxis {
  int coordinate = kNoCoordinate;
  Eigen::Vector3d axis = Eigen::Vector3d::UnitX();  // unit, in the joint's parent offset frame F
  CoordinateFunction function;
};

// A joint's parent or child frame: fixed to a body, offset from its origin.
struct OffsetFrame {
  int body = kGround;
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();  // m, in the body frame
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();

  Eigen::Isometry3d transform() const {  // offset frame -> body frame
    Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
    out.linear() = rotation;
    out.translation() = translation;
    return out;
  }
};

struct Joint {
  std::string name;
  std::string type;  // the element: CustomJoint, PinJoint, WeldJoint
  OffsetFrame parent, child;
  // rotation1-3, then translation1-3 (PinJoint: rotation about z; WeldJoint: all constant 0).
  std::array<TransformAxis, 6> axes;
};

struct PathPoint {
  std::string name;
  PathPointKind kind = PathPointKind::fixed;
  int body = kGround;
  Eigen::Vector3d location = Eigen::Vector3d::Zero();  // fixed and conditional points
  int condition_coordinate = kNoCoordinate;            // conditional points
  double range_min = 0, range_max = 0;
  std::array<CoordinateFunction, 3> moving_location;   // moving points: x, y, z
  std::array<int, 3> moving_coordinates{kNoCoordinate, kNoCoordinate, kNoCoordinate};
};

}  // namespace

struct OpenSimModel::Data {
  std::string source;
  std::vector<std::string> bodies;  // ground first
  std::vector<OpenSimCoordinate> coordinates;
  std::vector<Joint> joints;  // ordered so that every joint's parent body is placed by an earlier joint (or is ground)
  std::vector<OpenSimMuscle> muscles;
  std::vector<std::vector<PathPoint>> muscle_paths;  // parallel to muscles
  std::vector<std::string> constraints;              // "<type> <name>", not enforced
  std::map<std::string, int> body_index, coordinate_index, muscle_index;
};

namespace {

Eigen::Matrix3d rotationAbout(const Eigen::Vector3d& unit_axis, double angle) {
  return Eigen::AngleAxisd(angle, unit_axis).toRotationMatrix();
}

std::string lastPathComponent(const std::string& path) {
  const auto slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

// Reads one .osim file into the model's data; every refusal names the file, the line and the element.
class ModelReader {
 public:
  explicit ModelReader(std::string path) : path_(std::move(path)) {}

  OpenSimModel::Data read();

 private:
  [[noreturn]] void fail(const XMLElement* element, const std::string& what) const {
    std::string where = path_;
    if (element) {
      where += ":" + std::to_string(element->GetLineNum()) + ": <" + element->Name();
      if (const char* name = element->Attribute("name")) where += std::string(" name=\"") + name + "\"";
      where += ">";
    }
    throw SceneError(where + ": " + what);
  }

  const XMLElement* child(const XMLElement* parent, const char* tag) const {
    const XMLElement* found = parent->FirstChildElement(tag);
    if (!found) fail(parent, std::string("has no <") + tag + ">");
    return found;
  }

  std::string textOf(const XMLElement* element) const {
    const char* text = element->GetText();
    if (!text) return "";
    std::string out(text);
    const auto first = out.find_first_not_of(" \t\r\n");
    if (first == std::string::npos) return "";
    return out.substr(first, out.find_last_not_of(" \t\r\n") - first + 1);
  }

  std::string nameOf(const XMLElement* element) const {
    const char* name = element->Attribute("name");
    if (!name || !*name) fail(element, "has no name");
    return name;
  }

  std::vector<double> numbersIn(const XMLElement* element) const {
    std::vector<double> numbers;
    std::istringstream stream(textOf(element));
    for (std::string field; stream >> field;) {
      char* end = nullptr;
      const double value = std::strtod(field.c_str(), &end);
      if (*end != '\0' || !std::isfinite(value)) fail(element, "'" + field + "' is not a finite number");
      numbers.push_back(value);
    }
    return numbers;
  }

  std::vector<double> numbersIn(const XMLElement* element, std::size_t count) const {
    std::vector<double> numbers = numbersIn(element);
    if (numbers.size() != count) {
      fail(element, "expected " + std::to_string(count) + " numbers, found " + std::to_string(numbers.size()));
    }
    return numbers;
  }

  Eigen::Vector3d vectorIn(const XMLElement* element) const {
    const std::vector<double> v = numbersIn(element, 3);
    return Eigen::Vector3d(v[0], v[1], v[2]);
  }

  double numberIn(const XMLElement* element) const { return numbersIn(element, 1)[0]; }

  bool flagIn(const XMLElement* parent, const char* tag) const {
    const XMLElement* element = parent->FirstChildElement(tag);
    if (!element) return false;
    const std::string text = textOf(element);
    if (text == "true") return true;
    if (text == "false") return false;
    fail(element, "must be true or false, not '" + text + "'");
  }

  // A body named by a socket path: /ground, /bodyset/<name> (or a bare body name, as some writers leave it).
  int bodyNamedBy(const XMLElement* socket) const {
    const std::string path = textOf(socket);
    if (path == "/ground" || path == "ground" || path == "../ground") return kGround;
    std::string name = path;
    if (path.rfind("/bodyset/", 0) == 0) name = path.substr(9);
    const auto found = data_->body_index.find(name);
    if (found == data_->body_index.end()) {
      fail(socket, "'" + path + "' is not a body of the model (only bodies and the joints' own offset frames are "
                                "read, not other frames)");
    }
    return found->second;
  }

  int coordinateNamedBy(const XMLElement* socket) const {
    const std::string name = lastPathComponent(textOf(socket));
    const auto found = data_->coordinate_index.find(name);
    if (found == data_->coordinate_index.end()) fail(socket, "'" + textOf(socket) + "' is not a coordinate");
    return found->second;
  }

  // The function a holder element carries: the function element itself as its child (OpenSim 4, e.g.
  // <SimmSpline name="function">), or wrapped in a <function> element (older files, and MultiplierFunction's inner
  // function). `skip` lists the holder's other children.
  const XMLElement* functionElementIn(const XMLElement* holder, const std::set<std::string>& skip) const {
    for (const XMLElement* e = holder->FirstChildElement(); e; e = e->NextSiblingElement()) {
      if (skip.count(e->Name())) continue;
      if (std::string(e->Name()) == "function" && !e->Attribute("name")) {
        const XMLElement* inner = e->FirstChildElement();
        if (!inner) fail(e, "holds no function");
        return inner;
      }
      return e;
    }
    return nullptr;
  }

  CoordinateFunction functionFrom(const XMLElement* element) const {
    CoordinateFunction function;
    const std::string tag = element->Name();
    if (tag == "Constant") {
      function.kind = CoordinateFunction::Kind::constant;
      function.constant = numberIn(child(element, "value"));
    } else if (tag == "LinearFunction") {
      const std::vector<double> coefficients = numbersIn(child(element, "coefficients"), 2);
      function.kind = CoordinateFunction::Kind::linear;
      function.slope = coefficients[0];
      function.intercept = coefficients[1];
    } else if (tag == "SimmSpline") {
      function.kind = CoordinateFunction::Kind::spline;
      try {
        function.spline = std::make_shared<const SimmSpline>(numbersIn(child(element, "x")),
                                                             numbersIn(child(element, "y")));
      } catch (const std::invalid_argument& e) {
        fail(element, e.what());
      }
    } else if (tag == "MultiplierFunction") {
      const XMLElement* inner = functionElementIn(element, {"scale"});
      if (!inner) fail(element, "holds no function");
      function = functionFrom(inner);
      const XMLElement* scale = element->FirstChildElement("scale");
      function.scale *= scale ? numberIn(scale) : 1.0;
    } else {
      fail(element, "is a function type this reader does not evaluate (it reads Constant, LinearFunction, "
                    "SimmSpline and MultiplierFunction)");
    }
    return function;
  }

  void readBodies(const XMLElement* model);
  void readJoint(const XMLElement* joint_element);
  void orderJoints(const XMLElement* joint_set);
  void readMuscle(const XMLElement* force, const XMLElement* path);
  PathPoint readPathPoint(const XMLElement* element) const;

  std::string path_;
  OpenSimModel::Data* data_ = nullptr;
};

OpenSimModel::Data ModelReader::read() {
  tinyxml2::XMLDocument document;
  const tinyxml2::XMLError loaded = document.LoadFile(path_.c_str());
  if (loaded == tinyxml2::XML_ERROR_FILE_NOT_FOUND || loaded == tinyxml2::XML_ERROR_FILE_COULD_NOT_BE_OPENED) {
    throw SceneError(path_ + ": cannot open the OpenSim model file");
  }
  if (loaded != tinyxml2::XML_SUCCESS) {
    throw SceneError(path_ + ":" + std::to_string(document.ErrorLineNum()) + ": not valid XML (" +
                     document.ErrorStr() + ")");
  }
  const XMLElement* root = document.RootElement();
  if (!root || std::string(root->Name()) != "OpenSimDocument") fail(root, "is not an OpenSimDocument");
  const int version = root->IntAttribute("Version", 0);
  if (version < kOpenSim4Version) {
    fail(root, "is format version " + std::to_string(version) + "; this reader reads OpenSim 4 files (version " +
                   std::to_string(kOpenSim4Version) + " or later): open and save it in OpenSim 4 first");
  }
  const XMLElement* model = child(root, "Model");
  if (const XMLElement* units = model->FirstChildElement("length_units")) {
    if (textOf(units) != "meters") fail(units, "lengths in '" + textOf(units) + "': only meters are read");
  }

  OpenSimModel::Data data;
  data.source = path_;
  data_ = &data;
  readBodies(model);
  const XMLElement* joint_set = child(child(model, "JointSet"), "objects");
  for (const XMLElement* joint = joint_set->FirstChildElement(); joint; joint = joint->NextSiblingElement()) {
    readJoint(joint);
  }
  orderJoints(joint_set);
  if (const XMLElement* constraint_set = model->FirstChildElement("ConstraintSet")) {
    if (const XMLElement* constraints = constraint_set->FirstChildElement("objects")) {
      for (const XMLElement* c = constraints->FirstChildElement(); c; c = c->NextSiblingElement()) {
        data.constraints.push_back(std::string(c->Name()) + " " + nameOf(c));
      }
    }
  }
  if (const XMLElement* force_set = model->FirstChildElement("ForceSet")) {
    for (const XMLElement* force = child(force_set, "objects")->FirstChildElement(); force;
         force = force->NextSiblingElement()) {
      if (const XMLElement* path = force->FirstChildElement("GeometryPath")) readMuscle(force, path);
    }
  }
  data_ = nullptr;
  return data;
}

void ModelReader::readBodies(const XMLElement* model) {
  const XMLElement* ground = child(model, "Ground");
  data_->bodies.push_back("ground");
  data_->body_index["ground"] = kGround;
  if (const char* name = ground->Attribute("name")) data_->body_index[name] = kGround;
  const XMLElement* bodies = child(child(model, "BodySet"), "objects");
  for (const XMLElement* body = bodies->FirstChildElement(); body; body = body->NextSiblingElement()) {
    if (std::string(body->Name()) != "Body") fail(body, "is not a Body");
    const std::string name = nameOf(body);
    if (!data_->body_index.emplace(name, static_cast<int>(data_->bodies.size())).second) {
      fail(body, "a second body of this name");
    }
    data_->bodies.push_back(name);
  }
}

void ModelReader::readJoint(const XMLElement* element) {
  Joint joint;
  joint.name = nameOf(element);
  joint.type = element->Name();
  if (joint.type != "CustomJoint" && joint.type != "PinJoint" && joint.type != "WeldJoint") {
    fail(element, "is a joint type this reader does not model (it reads CustomJoint, PinJoint and WeldJoint)");
  }
  if (flagIn(element, "reverse")) {
    fail(element, "is reversed (<reverse>true</reverse>), which this reader does not model");
  }

  // The joint's own offset frames, then its two sockets: one of those frames or a body.
  std::map<std::string, OffsetFrame> frames;
  if (const XMLElement* frame_list = element->FirstChildElement("frames")) {
    for (const XMLElement* frame = frame_list->FirstChildElement(); frame; frame = frame->NextSiblingElement()) {
      if (std::string(frame->Name()) != "PhysicalOffsetFrame") fail(frame, "is not a PhysicalOffsetFrame");
      OffsetFrame offset;
      offset.body = bodyNamedBy(child(frame, "socket_parent"));
      if (const XMLElement* translation = frame->FirstChildElement("translation")) {
        offset.translation = vectorIn(translation);
      }
      if (const XMLElement* orientation = frame->FirstChildElement("orientation")) {
        const Eigen::Vector3d angles = vectorIn(orientation);  // body-fixed X, then Y, then Z
        offset.rotation = rotationAbout(Eigen::Vector3d::UnitX(), angles.x()) *
                          rotationAbout(Eigen::Vector3d::UnitY(), angles.y()) *
                          rotationAbout(Eigen::Vector3d::UnitZ(), angles.z());
      }
      frames[nameOf(frame)] = offset;
    }
  }
  const auto frameNamedBy = [&](const XMLElement* socket) {
    const auto found = frames.find(textOf(socket));
    if (found != frames.end()) return found->second;
    OffsetFrame on_body;
    on_body.body = bodyNamedBy(socket);
    return on_body;
  };
  joint.parent = frameNamedBy(child(element, "socket_parent_frame"));
  joint.child = frameNamedBy(child(element, "socket_child_frame"));
  if (joint.child.body == kGround) fail(element, "moves ground");

  std::map<std::string, int> own_coordinates;  // name -> index in data_->coordinates
  if (const XMLElement* coordinate_list = element->FirstChildElement("coordinates")) {
    for (const XMLElement* c = coordinate_list->FirstChildElement(); c; c = c->NextSiblingElement()) {
      OpenSimCoordinate coordinate;
      coordinate.name = nameOf(c);
      coordinate.joint = joint.name;
      if (const XMLElement* value = c->FirstChildElement("default_value")) coordinate.default_value = numberIn(value);
      if (const XMLElement* range = c->FirstChildElement("range")) {
        const std::vector<double> limits = numbersIn(range, 2);
        coordinate.range_min = limits[0];
        coordinate.range_max = limits[1];
        if (coordinate.range_min > coordinate.range_max) fail(range, "the range's minimum exceeds its maximum");
      }
      coordinate.clamped = flagIn(c, "clamped");
      const int index = static_cast<int>(data_->coordinates.size());
      if (!data_->coordinate_index.emplace(coordinate.name, index).second) fail(c, "a second coordinate of this name");
      own_coordinates[coordinate.name] = index;
      data_->coordinates.push_back(coordinate);
    }
  }

  // Default axes for the axes a PinJoint or WeldJoint does not turn: three independent directions, each motion 0.
  for (int i = 0; i < 6; ++i) joint.axes[i].axis = Eigen::Vector3d::Unit(i % 3);
  if (joint.type == "PinJoint") {
    if (own_coordinates.size() != 1) fail(element, "a PinJoint needs exactly one coordinate");
    // The rotation about F's z axis comes first; the other two rotations are 0 about x and y.
    joint.axes[0].axis = Eigen::Vector3d::UnitZ();
    joint.axes[0].coordinate = own_coordinates.begin()->second;
    joint.axes[0].function.kind = CoordinateFunction::Kind::linear;
    joint.axes[0].function.slope = 1;
    joint.axes[2].axis = Eigen::Vector3d::UnitX();
  } else if (joint.type == "WeldJoint") {
    if (!own_coordinates.empty()) fail(element, "a WeldJoint has no coordinates");
  } else {
    const XMLElement* transform = child(element, "SpatialTransform");
    static const std::array<const char*, 6> kAxisNames = {"rotation1",    "rotation2",    "rotation3",
                                                          "translation1", "translation2", "translation3"};
    std::array<bool, 6> seen{};
    for (const XMLElement* a = transform->FirstChildElement(); a; a = a->NextSiblingElement()) {
      if (std::string(a->Name()) != "TransformAxis") fail(a, "is not a TransformAxis");
      const std::string axis_name = nameOf(a);
      const auto slot = std::find(kAxisNames.begin(), kAxisNames.end(), axis_name);
      if (slot == kAxisNames.end()) fail(a, "is not one of rotation1-3, translation1-3");
      const std::size_t i = static_cast<std::size_t>(slot - kAxisNames.begin());
      if (seen[i]) fail(a, "a second transform axis of this name");
      seen[i] = true;
      TransformAxis& axis = joint.axes[i];
      const Eigen::Vector3d direction = vectorIn(child(a, "axis"));
      if (direction.norm() < 1e-12) fail(a, "has a zero axis");
      axis.axis = direction.normalized();
      std::vector<std::string> names;
      if (const XMLElement* coordinates = a->FirstChildElement("coordinates")) {
        std::istringstream stream(textOf(coordinates));
        for (std::string name; stream >> name;) names.push_back(name);
      }
      if (names.size() > 1) fail(a, "depends on several coordinates, which this reader does not model");
      if (names.size() == 1) {
        const auto found = own_coordinates.find(names[0]);
        if (found == own_coordinates.end()) {
          fail(a, "names coordinate '" + names[0] + "', which its joint does not declare");
        }
        axis.coordinate = found->second;
      }
      if (const XMLElement* function = functionElementIn(a, {"coordinates", "axis"})) {
        axis.function = functionFrom(function);
      } else if (axis.coordinate != kNoCoordinate) {  // OpenSim's default: the coordinate itself
        axis.function.kind = CoordinateFunction::Kind::linear;
        axis.function.slope = 1;
      }
    }
    // Simbody needs independent directions within each triple (OpenSim refuses collinear axes on loading).
    for (int start : {0, 3}) {
      for (int a = 0; a < 3; ++a) {
        for (int b = a + 1; b < 3; ++b) {
          if (joint.axes[start + a].axis.cross(joint.axes[start + b].axis).norm() < 1e-5) {
            fail(transform, std::string("axes ") + kAxisNames[start + a] + " and " + kAxisNames[start + b] +
                                " are collinear");
          }
        }
      }
    }
  }

  // Motion types, from the axes the coordinates drive (OpenSim's rule, see CoordinateMotion).
  for (const auto& [name, index] : own_coordinates) {
    OpenSimCoordinate& coordinate = data_->coordinates[index];
    bool rotational = false, translational = false, used = false;
    for (int i = 0; i < 6; ++i) {
      if (joint.axes[i].coordinate != index) continue;
      used = true;
      if (joint.axes[i].function.isIdentity()) (i < 3 ? rotational : translational) = true;
    }
    if (!used) fail(element, "coordinate '" + name + "' drives none of the joint's axes");
    coordinate.motion = rotational      ? CoordinateMotion::rotational
                        : translational ? CoordinateMotion::translational
                                        : CoordinateMotion::coupled;
  }
  data_->joints.push_back(std::move(joint));
}

// Joints in an order that places each parent body before its children, starting at ground; every body placed once.
void ModelReader::orderJoints(const XMLElement* joint_set) {
  std::vector<int> placing_joint(data_->bodies.size(), -1);
  for (std::size_t j = 0; j < data_->joints.size(); ++j) {
    const int body = data_->joints[j].child.body;
    if (placing_joint[body] >= 0) {
      fail(joint_set, "joints '" + data_->joints[placing_joint[body]].name + "' and '" + data_->joints[j].name +
                          "' both move body '" + data_->bodies[body] + "' (closed loops are not modelled)");
    }
    placing_joint[body] = static_cast<int>(j);
  }
  std::vector<bool> placed(data_->bodies.size(), false);
  placed[kGround] = true;
  std::vector<Joint> ordered;
  std::vector<bool> taken(data_->joints.size(), false);
  for (bool progress = true; progress;) {
    progress = false;
    for (std::size_t j = 0; j < data_->joints.size(); ++j) {
      if (taken[j] || !placed[data_->joints[j].parent.body]) continue;
      taken[j] = progress = true;
      placed[data_->joints[j].child.body] = true;
      ordered.push_back(data_->joints[j]);
    }
  }
  for (std::size_t b = 1; b < data_->bodies.size(); ++b) {
    if (!placed[b]) {
      fail(joint_set, "body '" + data_->bodies[b] + "' is not connected to ground by joints");
    }
  }
  data_->joints = std::move(ordered);
}

PathPoint ModelReader::readPathPoint(const XMLElement* element) const {
  PathPoint point;
  point.name = nameOf(element);
  point.body = bodyNamedBy(child(element, "socket_parent_frame"));
  const std::string tag = element->Name();
  if (tag == "PathPoint" || tag == "ConditionalPathPoint") {
    point.location = vectorIn(child(element, "location"));
  }
  if (tag == "PathPoint") {
    point.kind = PathPointKind::fixed;
  } else if (tag == "ConditionalPathPoint") {
    point.kind = PathPointKind::conditional;
    point.condition_coordinate = coordinateNamedBy(child(element, "socket_coordinate"));
    const std::vector<double> range = numbersIn(child(element, "range"), 2);
    point.range_min = range[0];
    point.range_max = range[1];
  } else if (tag == "MovingPathPoint") {
    point.kind = PathPointKind::moving;
    static const std::array<const char*, 3> kLocations = {"x_location", "y_location", "z_location"};
    static const std::array<const char*, 3> kSockets = {"socket_x_coordinate", "socket_y_coordinate",
                                                        "socket_z_coordinate"};
    for (std::size_t i = 0; i < 3; ++i) {
      if (const XMLElement* socket = element->FirstChildElement(kSockets[i]); socket && !textOf(socket).empty()) {
        point.moving_coordinates[i] = coordinateNamedBy(socket);
      }
      const XMLElement* location = child(element, kLocations[i]);
      const XMLElement* function = functionElementIn(location, {});
      if (!function) fail(location, "holds no function");
      point.moving_location[i] = functionFrom(function);
    }
  } else {
    fail(element, "is a path point type this reader does not model (it reads PathPoint, ConditionalPathPoint and "
                  "MovingPathPoint)");
  }
  return point;
}

void ModelReader::readMuscle(const XMLElement* force, const XMLElement* path) {
  OpenSimMuscle muscle;
  muscle.name = nameOf(force);
  muscle.type = force->Name();
  std::vector<PathPoint> points;
  const XMLElement* point_set = child(child(path, "PathPointSet"), "objects");
  for (const XMLElement* p = point_set->FirstChildElement(); p; p = p->NextSiblingElement()) {
    points.push_back(readPathPoint(p));
    muscle.path_point_names.push_back(points.back().name);
  }
  if (points.size() < 2) fail(path, "has fewer than two path points");
  if (const XMLElement* wrap_set = path->FirstChildElement("PathWrapSet")) {
    if (const XMLElement* wraps = wrap_set->FirstChildElement("objects")) {
      for (const XMLElement* w = wraps->FirstChildElement(); w; w = w->NextSiblingElement()) {
        const XMLElement* object = w->FirstChildElement("wrap_object");
        muscle.wrap_objects.push_back(object ? textOf(object) : nameOf(w));
      }
    }
  }
  if (!data_->muscle_index.emplace(muscle.name, static_cast<int>(data_->muscles.size())).second) {
    fail(force, "a second force of this name");
  }
  data_->muscles.push_back(std::move(muscle));
  data_->muscle_paths.push_back(std::move(points));
}

// The joint's motion X_FM: child offset frame M in parent offset frame F.
Eigen::Isometry3d jointMotion(const Joint& joint, const std::vector<double>& q) {
  const auto axisValue = [&](const TransformAxis& axis) {
    return axis.function.at(axis.coordinate == kNoCoordinate ? 0.0 : q[axis.coordinate]);
  };
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  for (int i = 0; i < 3; ++i) rotation = rotation * rotationAbout(joint.axes[i].axis, axisValue(joint.axes[i]));
  motion.linear() = rotation;
  for (int i = 3; i < 6; ++i) motion.translation() += axisValue(joint.axes[i]) * joint.axes[i].axis;
  return motion;
}

}  // namespace

OpenSimModel OpenSimModel::fromFile(const std::string& path) {
  return OpenSimModel(std::make_shared<const Data>(ModelReader(path).read()));
}

const std::string& OpenSimModel::source() const { return data_->source; }

std::vector<std::string> OpenSimModel::bodyNames() const { return data_->bodies; }

const std::vector<OpenSimCoordinate>& OpenSimModel::coordinates() const { return data_->coordinates; }

const OpenSimCoordinate& OpenSimModel::coordinate(const std::string& name) const {
  const auto found = data_->coordinate_index.find(name);
  if (found == data_->coordinate_index.end()) {
    throw std::invalid_argument(data_->source + ": no coordinate '" + name + "' in the model");
  }
  return data_->coordinates[found->second];
}

bool OpenSimModel::hasCoordinate(const std::string& name) const { return data_->coordinate_index.count(name) > 0; }

const std::vector<std::string>& OpenSimModel::kinematicConstraints() const { return data_->constraints; }

const std::vector<OpenSimMuscle>& OpenSimModel::muscles() const { return data_->muscles; }

const OpenSimMuscle& OpenSimModel::muscle(const std::string& name) const {
  const auto found = data_->muscle_index.find(name);
  if (found == data_->muscle_index.end()) {
    throw std::invalid_argument(data_->source + ": no muscle '" + name + "' in the model");
  }
  return data_->muscles[found->second];
}

OpenSimModel OpenSimModel::scaled(const BodyScaleFactors& factors) const {
  auto data = std::make_shared<Data>(*data_);
  std::vector<Eigen::Vector3d> body_factors(data->bodies.size(), Eigen::Vector3d::Ones());
  for (const auto& [body, factor] : factors) {
    const auto found = data->body_index.find(body);
    if (found == data->body_index.end()) {
      throw std::invalid_argument(data->source + ": cannot scale body '" + body + "': no such body in the model");
    }
    if (found->second == kGround) throw std::invalid_argument(data->source + ": ground cannot be scaled");
    if (!factor.allFinite() || (factor.array() <= 0).any()) {
      throw std::invalid_argument(data->source + ": the scale factors of body '" + body +
                                  "' must be finite numbers > 0");
    }
    body_factors[found->second] = factor;
  }
  for (Joint& joint : data->joints) {
    joint.parent.translation = joint.parent.translation.cwiseProduct(body_factors[joint.parent.body]);
    joint.child.translation = joint.child.translation.cwiseProduct(body_factors[joint.child.body]);
    // A translation of the child along an axis of the parent's frame is a length of the parent body. F's axes are
    // the parent body's axes turned by F's orientation (identity in gait2392); OpenSim projects on the axis as
    // written in F, and so does this.
    for (int i = 3; i < 6; ++i) {
      TransformAxis& axis = joint.axes[i];
      if (axis.function.isIdentity()) continue;  // a degree of freedom, not a length of the model
      axis.function.scale *= axis.axis.dot(body_factors[joint.parent.body]);
    }
  }
  for (std::vector<PathPoint>& path : data->muscle_paths) {
    for (PathPoint& point : path) {
      const Eigen::Vector3d& factor = body_factors[point.body];
      point.location = point.location.cwiseProduct(factor);
      for (int i = 0; i < 3; ++i) point.moving_location[i].scale *= factor[i];
    }
  }
  return OpenSimModel(std::move(data));
}

namespace {

std::vector<double> coordinateVector(const OpenSimModel::Data& data, const CoordinateValues& values) {
  std::vector<double> q(data.coordinates.size());
  for (std::size_t i = 0; i < q.size(); ++i) q[i] = data.coordinates[i].default_value;
  for (const auto& [name, value] : values) {
    const auto found = data.coordinate_index.find(name);
    if (found == data.coordinate_index.end()) {
      throw std::invalid_argument(data.source + ": no coordinate '" + name + "' in the model");
    }
    if (!std::isfinite(value)) {
      throw std::invalid_argument(data.source + ": coordinate '" + name + "' given a value that is not finite");
    }
    const OpenSimCoordinate& coordinate = data.coordinates[found->second];
    q[found->second] = coordinate.clamped ? std::clamp(value, coordinate.range_min, coordinate.range_max) : value;
  }
  return q;
}

std::vector<Eigen::Isometry3d> bodyPoses(const OpenSimModel::Data& data, const std::vector<double>& q) {
  std::vector<Eigen::Isometry3d> poses(data.bodies.size(), Eigen::Isometry3d::Identity());
  for (const Joint& joint : data.joints) {
    poses[joint.child.body] = poses[joint.parent.body] * joint.parent.transform() * jointMotion(joint, q) *
                              joint.child.transform().inverse();
  }
  return poses;
}

bool isActive(const PathPoint& point, const std::vector<double>& q) {
  if (point.kind != PathPointKind::conditional) return true;
  const double value = q[point.condition_coordinate];
  return value >= point.range_min - kConditionalRangeTolerance && value <= point.range_max + kConditionalRangeTolerance;
}

Eigen::Vector3d locationInBody(const OpenSimModel::Data& data, const PathPoint& point, const std::vector<double>& q) {
  if (point.kind != PathPointKind::moving) return point.location;
  Eigen::Vector3d location;
  for (int i = 0; i < 3; ++i) {
    double argument = 0;  // a component without a coordinate is a constant
    if (point.moving_coordinates[i] != kNoCoordinate) {
      const OpenSimCoordinate& coordinate = data.coordinates[point.moving_coordinates[i]];
      argument = std::clamp(q[point.moving_coordinates[i]], coordinate.range_min, coordinate.range_max);
    }
    location[i] = point.moving_location[i].at(argument);
  }
  return location;
}

const std::vector<PathPoint>& pathOf(const OpenSimModel::Data& data, const std::string& muscle) {
  const auto found = data.muscle_index.find(muscle);
  if (found == data.muscle_index.end()) {
    throw std::invalid_argument(data.source + ": no muscle '" + muscle + "' in the model");
  }
  return data.muscle_paths[found->second];
}

}  // namespace

std::map<std::string, Eigen::Isometry3d> OpenSimModel::bodyPosesInGround(const CoordinateValues& values) const {
  const std::vector<Eigen::Isometry3d> poses = bodyPoses(*data_, coordinateVector(*data_, values));
  std::map<std::string, Eigen::Isometry3d> named;
  for (std::size_t b = 0; b < poses.size(); ++b) named.emplace(data_->bodies[b], poses[b]);
  return named;
}

std::vector<MusclePathPoint> OpenSimModel::activePathPoints(const std::string& muscle,
                                                            const CoordinateValues& values) const {
  const std::vector<PathPoint>& path = pathOf(*data_, muscle);
  const std::vector<double> q = coordinateVector(*data_, values);
  const std::vector<Eigen::Isometry3d> poses = bodyPoses(*data_, q);
  std::vector<MusclePathPoint> points;
  for (const PathPoint& point : path) {
    if (!isActive(point, q)) continue;
    MusclePathPoint active;
    active.name = point.name;
    active.kind = point.kind;
    active.body = data_->bodies[point.body];
    active.location_in_body = locationInBody(*data_, point, q);
    active.location_in_ground = poses[point.body] * active.location_in_body;
    points.push_back(std::move(active));
  }
  return points;
}

double OpenSimModel::musculotendonLength(const std::string& muscle, const CoordinateValues& values) const {
  const std::vector<std::string>& wraps = this->muscle(muscle).wrap_objects;
  if (!wraps.empty()) {
    throw SceneError(data_->source + ": muscle '" + muscle + "' wraps over '" + wraps.front() +
                     "', which this reader does not model: its straight-segment length would be too short");
  }
  const std::vector<MusclePathPoint> points = activePathPoints(muscle, values);
  double length = 0;
  for (std::size_t i = 1; i < points.size(); ++i) {
    length += (points[i].location_in_ground - points[i - 1].location_in_ground).norm();
  }
  return length;
}

CoordinateValues coordinateValuesAt(const OpenSimModel& model, const MotionTable& motion, std::size_t row) {
  if (row >= motion.rowCount()) {
    throw std::invalid_argument(motion.source + ": row " + std::to_string(row) + " asked for, the table has " +
                                std::to_string(motion.rowCount()));
  }
  constexpr double kRadiansPerDegree = EIGEN_PI / 180.0;
  CoordinateValues values;
  for (std::size_t c = 0; c < motion.column_names.size(); ++c) {
    const std::string& name = motion.column_names[c];
    if (!model.hasCoordinate(name)) continue;
    double value = motion.values(static_cast<Eigen::Index>(row), static_cast<Eigen::Index>(c));
    const CoordinateMotion kind = model.coordinate(name).motion;
    if (motion.angles_in_degrees && kind == CoordinateMotion::coupled) {
      throw std::invalid_argument(motion.source + ": column '" + name + "' is a coupled coordinate of " +
                                  model.source() + ", so whether it is in degrees is not known");
    }
    if (motion.angles_in_degrees && kind == CoordinateMotion::rotational) value *= kRadiansPerDegree;
    values[name] = value;
  }
  return values;
}

std::vector<std::string> motionColumnsNotInModel(const OpenSimModel& model, const MotionTable& motion) {
  std::vector<std::string> missing;
  for (const std::string& name : motion.column_names) {
    if (!model.hasCoordinate(name)) missing.push_back(name);
  }
  return missing;
}

}  // namespace muscle_deformation
