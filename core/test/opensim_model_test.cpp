// Specifications of the OpenSim model reader on gait2392 (data/opensim/gait2392_millard2012muscle.osim): poses, path
// points and musculotendon lengths checked against values worked out here from the numbers of the file, scaling, the
// motion-row helper and the errors.
#include "muscle_deformation/core/scene/opensim_model.hpp"
#include "muscle_deformation/core/scene/simm_spline.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;
using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

const std::string kGait2392 = std::string(MD_PACKAGE_DIR) + "/data/opensim/gait2392_millard2012muscle.osim";
const std::string kOneCycle = std::string(MD_PACKAGE_DIR) + "/data/opensim/subject01_walk1_ik_1cycle.mot";

const md::OpenSimModel& gait2392() {
  static const md::OpenSimModel model = md::OpenSimModel::fromFile(kGait2392);
  return model;
}

Matrix3d rotationX(double a) {
  Matrix3d r;
  r << 1, 0, 0, 0, std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a);
  return r;
}
Matrix3d rotationY(double a) {
  Matrix3d r;
  r << std::cos(a), 0, std::sin(a), 0, 1, 0, -std::sin(a), 0, std::cos(a);
  return r;
}
Matrix3d rotationZ(double a) {
  Matrix3d r;
  r << std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1;
  return r;
}

double pathLength(const std::vector<Vector3d>& points) {
  double length = 0;
  for (std::size_t i = 1; i < points.size(); ++i) length += (points[i] - points[i - 1]).norm();
  return length;
}

// gait2392's right leg, written out from the file (metres, radians), to place points in the pelvis frame without the
// reader. Lengths do not depend on where the pelvis is, so the pelvis frame serves as well as ground.
//   hip_r: pelvis offset (-0.0707, -0.0661, 0.0835), femur offset 0; R = Rz(flexion) Rx(adduction) Ry(rotation).
//   knee_r: both offsets 0; R = Rz(knee angle), translation (tx(q), ty(q), 0) in the femur frame, tx and ty splines.
struct RightLegPose {
  double hip_flexion = 0, hip_adduction = 0, hip_rotation = 0;
  double knee_angle = 0;
  double knee_tx = 0, knee_ty = 0;  // the knee splines at knee_angle: chosen at one of their knots, so read off

  Vector3d femurToPelvis(const Vector3d& p) const {
    const Vector3d hip_centre(-0.0707, -0.0661, 0.0835);
    return hip_centre + rotationZ(hip_flexion) * rotationX(hip_adduction) * rotationY(hip_rotation) * p;
  }
  Vector3d tibiaToPelvis(const Vector3d& p) const {
    return femurToPelvis(Vector3d(knee_tx, knee_ty, 0) + rotationZ(knee_angle) * p);
  }
  md::CoordinateValues coordinates() const {
    // The pelvis is moved too: the lengths must not notice.
    return {{"hip_flexion_r", hip_flexion}, {"hip_adduction_r", hip_adduction}, {"hip_rotation_r", hip_rotation},
            {"knee_angle_r", knee_angle},   {"pelvis_tilt", 0.1},               {"pelvis_tx", 0.4}};
  }
};

// Pose A: standing hip, knee at 20 degrees of flexion, which is a knot of both knee splines (tx knot 6, ty knot 4).
RightLegPose poseA() {
  RightLegPose pose;
  pose.knee_angle = -0.349066;
  pose.knee_tx = -0.001;
  pose.knee_ty = -0.3976;
  return pose;
}

// Pose B: hip flexed 57 degrees, adducted and turned inward, knee at 120 degrees: the first knot of both knee splines.
RightLegPose poseB() {
  RightLegPose pose;
  pose.hip_flexion = 1.0;
  pose.hip_adduction = 0.2;
  pose.hip_rotation = -0.3;
  pose.knee_angle = -2.0944;
  pose.knee_tx = -0.0032;
  pose.knee_ty = -0.4226;
  return pose;
}

std::string writeTemporary(const std::string& name, const std::string& text) {
  const std::string path = (std::filesystem::temp_directory_path() / name).string();
  std::ofstream(path) << text;
  return path;
}

// A two-body model: ground, a thigh on a PinJoint 0.5 m below ground's origin, a shank welded 0.4 m below the thigh,
// one muscle from ground to the shank; `shank_joint` and `wraps` replace parts of it for the other cases.
std::string smallModel(const std::string& shank_joint = "WeldJoint", const std::string& wraps = "") {
  return "<?xml version=\"1.0\"?>\n<OpenSimDocument Version=\"40000\">\n<Model name=\"small\">\n"
         "<Ground name=\"ground\"/>\n"
         "<BodySet><objects><Body name=\"thigh\"/><Body name=\"shank\"/></objects></BodySet>\n"
         "<JointSet><objects>\n"
         "<PinJoint name=\"hip\"><socket_parent_frame>ground_offset</socket_parent_frame>"
         "<socket_child_frame>/bodyset/thigh</socket_child_frame>"
         "<coordinates><Coordinate name=\"hip_angle\"><default_value>0</default_value><range>-2 2</range>"
         "</Coordinate></coordinates>"
         "<frames><PhysicalOffsetFrame name=\"ground_offset\"><socket_parent>/ground</socket_parent>"
         "<translation>0 -0.5 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame></frames>"
         "</PinJoint>\n"
         "<" + shank_joint + " name=\"knee\"><socket_parent_frame>thigh_offset</socket_parent_frame>"
         "<socket_child_frame>/bodyset/shank</socket_child_frame>"
         "<frames><PhysicalOffsetFrame name=\"thigh_offset\"><socket_parent>/bodyset/thigh</socket_parent>"
         "<translation>0 -0.4 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame></frames>"
         "</" + shank_joint + ">\n"
         "</objects></JointSet>\n"
         "<ForceSet><objects><Millard2012EquilibriumMuscle name=\"spanner\"><GeometryPath>"
         "<PathPointSet><objects>"
         "<PathPoint name=\"spanner-P1\"><socket_parent_frame>/ground</socket_parent_frame>"
         "<location>0.1 0 0</location></PathPoint>"
         "<PathPoint name=\"spanner-P2\"><socket_parent_frame>/bodyset/shank</socket_parent_frame>"
         "<location>0.1 0 0</location></PathPoint>"
         "</objects></PathPointSet>"
         "<PathWrapSet><objects>" + wraps + "</objects></PathWrapSet>"
         "</GeometryPath></Millard2012EquilibriumMuscle></objects></ForceSet>\n"
         "</Model>\n</OpenSimDocument>\n";
}

std::string loadError(const std::string& text) {
  const std::string path = writeTemporary("md_opensim_model_test.osim", text);
  return md::testing::errorMessageOf<md::SceneError>([&] { md::OpenSimModel::fromFile(path); });
}

}  // namespace

TEST(OpenSimModel, ReadsGait2392sBodiesCoordinatesAndMuscles) {
  const md::OpenSimModel& model = gait2392();
  EXPECT_EQ(model.bodyNames().size(), 13u);  // ground and 12 bodies
  EXPECT_EQ(model.bodyNames().front(), "ground");
  EXPECT_EQ(model.coordinates().size(), 23u);
  EXPECT_EQ(model.muscles().size(), 92u);
  for (const md::OpenSimMuscle& muscle : model.muscles()) EXPECT_TRUE(muscle.wrap_objects.empty()) << muscle.name;
  EXPECT_TRUE(model.kinematicConstraints().empty());
  EXPECT_EQ(model.muscle("rect_fem_r").type, "Millard2012EquilibriumMuscle");
  EXPECT_EQ(model.muscle("rect_fem_r").path_point_names,
            (std::vector<std::string>{"rect_fem_r-P1", "rect_fem_r-P2", "rect_fem_r-P3"}));
}

TEST(OpenSimModel, TellsRotationalFromTranslationalCoordinates) {
  const md::OpenSimModel& model = gait2392();
  EXPECT_EQ(model.coordinate("knee_angle_r").motion, md::CoordinateMotion::rotational);
  EXPECT_EQ(model.coordinate("hip_flexion_r").motion, md::CoordinateMotion::rotational);
  EXPECT_EQ(model.coordinate("pelvis_ty").motion, md::CoordinateMotion::translational);
  EXPECT_EQ(model.coordinate("knee_angle_r").joint, "knee_r");
  EXPECT_DOUBLE_EQ(model.coordinate("knee_angle_r").range_max, 0.17453293);
  EXPECT_DOUBLE_EQ(model.coordinate("pelvis_ty").default_value, 0.95);
}

TEST(OpenSimModel, CoordinatesNotGivenStayAtTheirDefaults) {
  // pelvis_ty defaults to 0.95 m, everything else to 0: the femur origin is the hip centre 0.95 m up.
  const auto poses = gait2392().bodyPosesInGround({});
  EXPECT_TRUE(poses.at("femur_r").translation().isApprox(Vector3d(-0.0707, 0.95 - 0.0661, 0.0835), 1e-15));
  EXPECT_TRUE(poses.at("femur_r").linear().isIdentity(1e-15));
}

TEST(OpenSimModel, PsoasLengthMatchesHandWorkAndDropsItsConditionalPointInDeepHipFlexion) {
  // psoas_r: P1, P2 and P3 on the pelvis, P3 only while hip_flexion_r is in [-1.5708, 0.785398]; P4, P5 on the femur.
  const Vector3d p1(-0.0647, 0.0887, 0.0289), p2(-0.0238, -0.057, 0.0759), p3(-0.0288, -0.0805, 0.0816);
  const Vector3d p4(0.0016, -0.0507, 0.0038), p5(-0.0188, -0.0597, 0.0104);
  const RightLegPose a = poseA(), b = poseB();
  const double expected_a = pathLength({p1, p2, p3, a.femurToPelvis(p4), a.femurToPelvis(p5)});
  const double expected_b = pathLength({p1, p2, b.femurToPelvis(p4), b.femurToPelvis(p5)});  // flexion 1.0 > 0.785
  EXPECT_NEAR(gait2392().musculotendonLength("psoas_r", a.coordinates()), expected_a, 1e-12);
  EXPECT_NEAR(gait2392().musculotendonLength("psoas_r", b.coordinates()), expected_b, 1e-12);
  EXPECT_EQ(gait2392().activePathPoints("psoas_r", a.coordinates()).size(), 5u);
  EXPECT_EQ(gait2392().activePathPoints("psoas_r", b.coordinates()).size(), 4u);
}

TEST(OpenSimModel, RectusFemorisLengthAcrossTheKneeMatchesHandWork) {
  // rect_fem_r: P1 on the pelvis; P2 on the femur, only while knee_angle_r is in [-2.61799, -1.45997]; P3 on the
  // tibia, moving with the knee angle along splines (z constant 0.0014). Pose A's knee angle is their knot 9:
  // x 0.048391, y 0.0234197.
  const Vector3d p1(-0.0295, -0.0311, 0.0968), p2(0.0334, -0.403, 0.0019);
  const RightLegPose a = poseA(), b = poseB();
  const double expected_a = pathLength({p1, a.tibiaToPelvis(Vector3d(0.048391, 0.0234197, 0.0014))});
  EXPECT_NEAR(gait2392().musculotendonLength("rect_fem_r", a.coordinates()), expected_a, 1e-12);
  // Pose B's knee angle, -2.0944, lies 4.9e-6 rad below the knee's range (minimum -2.0943951); OpenSim evaluates a
  // moving point at its coordinate clamped to the range, so P3 comes from the splines at -2.0943951, just inside
  // their first knot (the spline itself is specified in simm_spline_test.cpp). The knee joint is not clamped.
  const md::SimmSpline p3_x(
      {-2.0944, -1.99997, -1.5708, -1.45752, -1.39626, -1.0472, -0.698132, -0.526391, -0.349066, -0.174533, 0,
       0.00017453, 0.00034907, 0.0279253, 0.0872665, 0.174533, 2.0944},
      {0.0155805, 0.0179938, 0.0275081, 0.0296564, 0.0307615, 0.0365695, 0.0422074, 0.0450902, 0.048391, 0.0534299,
       0.0617576, 0.0617669, 0.0617762, 0.0633083, 0.066994, 0.0733035, 0.0573481});
  const md::SimmSpline p3_y(
      {-2.0944, -1.99997, -1.5708, -1.45752, -1.39626, -1.0472, -0.698132, -0.526391, -0.349066, -0.174533, 0,
       0.00017453, 0.00034907, 0.0279253, 0.0872665, 0.174533, 2.0944},
      {0.0234116, 0.0237613, 0.0251141, 0.0252795, 0.0253146, 0.0249184, 0.0242373, 0.0238447, 0.0234197, 0.0227644,
       0.020984, 0.0209814, 0.0209788, 0.0205225, 0.0191754, 0.0159554, -0.0673774});
  const double clamped_knee = -2.0943950999999998;
  const Vector3d p3_b(p3_x.value(clamped_knee), p3_y.value(clamped_knee), 0.0014);
  EXPECT_GT((p3_b - Vector3d(0.0155805, 0.0234116, 0.0014)).norm(), 1e-7);  // the clamping shows
  const double expected_b = pathLength({p1, b.femurToPelvis(p2), b.tibiaToPelvis(p3_b)});
  EXPECT_NEAR(gait2392().musculotendonLength("rect_fem_r", b.coordinates()), expected_b, 1e-12);
}

TEST(OpenSimModel, ActivePathPointsGiveBodyLocationKindAndName) {
  const std::vector<md::MusclePathPoint> a = gait2392().activePathPoints("rect_fem_r", poseA().coordinates());
  ASSERT_EQ(a.size(), 2u);
  EXPECT_EQ(a[0].name, "rect_fem_r-P1");
  EXPECT_EQ(a[0].body, "pelvis");
  EXPECT_EQ(a[0].kind, md::PathPointKind::fixed);
  EXPECT_TRUE(a[0].location_in_body.isApprox(Vector3d(-0.0295, -0.0311, 0.0968), 1e-15));
  EXPECT_EQ(a[1].name, "rect_fem_r-P3");
  EXPECT_EQ(a[1].body, "tibia_r");
  EXPECT_EQ(a[1].kind, md::PathPointKind::moving);
  EXPECT_TRUE(a[1].location_in_body.isApprox(Vector3d(0.048391, 0.0234197, 0.0014), 1e-12));

  const std::vector<md::MusclePathPoint> b = gait2392().activePathPoints("rect_fem_r", poseB().coordinates());
  ASSERT_EQ(b.size(), 3u);
  EXPECT_EQ(b[1].name, "rect_fem_r-P2");
  EXPECT_EQ(b[1].body, "femur_r");
  EXPECT_EQ(b[1].kind, md::PathPointKind::conditional);
  const auto poses = gait2392().bodyPosesInGround(poseB().coordinates());
  EXPECT_TRUE(b[1].location_in_ground.isApprox(poses.at("femur_r") * b[1].location_in_body, 1e-15));
}

TEST(OpenSimModel, ScalingEveryBodyByTwoDoublesEveryLength) {
  // Every translation of the model doubles (offsets, knee splines, path points) and no rotation depends on scale; the
  // pelvis translations are degrees of freedom and move the whole body rigidly.
  md::BodyScaleFactors factors;
  for (const std::string& body : gait2392().bodyNames()) {
    if (body != "ground") factors[body] = Vector3d::Constant(2.0);
  }
  const md::OpenSimModel doubled = gait2392().scaled(factors);
  for (const md::CoordinateValues& pose : {poseA().coordinates(), poseB().coordinates()}) {
    for (const md::OpenSimMuscle& muscle : gait2392().muscles()) {
      const double length = gait2392().musculotendonLength(muscle.name, pose);
      EXPECT_NEAR(doubled.musculotendonLength(muscle.name, pose), 2 * length, 1e-12 * length) << muscle.name;
    }
  }
}

TEST(OpenSimModel, ScalingFollowsTheScaleToolPerBodyAndAxis) {
  const md::OpenSimModel& model = gait2392();
  const md::OpenSimModel scaled =
      model.scaled({{"pelvis", Vector3d(1.2, 1.0, 1.0)}, {"femur_r", Vector3d(1.0, 1.1, 1.3)}});
  const md::CoordinateValues standing = {{"pelvis_ty", 0.0}};
  const auto poses = scaled.bodyPosesInGround(standing);
  // The hip's offset on the pelvis scales with the pelvis: x by 1.2.
  EXPECT_TRUE(poses.at("femur_r").translation().isApprox(Vector3d(1.2 * -0.0707, -0.0661, 0.0835), 1e-15));
  // The knee's translation splines scale with the parent (femur) along their axes: ty (knee 0) by 1.1, tx by 1.0.
  const Vector3d knee = poses.at("tibia_r").translation() - poses.at("femur_r").translation();
  const Vector3d knee_unscaled = model.bodyPosesInGround(standing).at("tibia_r").translation() -
                                 model.bodyPosesInGround(standing).at("femur_r").translation();
  EXPECT_NEAR(knee.x(), knee_unscaled.x(), 1e-15);
  EXPECT_NEAR(knee.y(), 1.1 * knee_unscaled.y(), 1e-15);
  // Path points scale with their body: psoas_r-P4 on the femur.
  const auto points = scaled.activePathPoints("psoas_r", standing);
  EXPECT_TRUE(points[3].location_in_body.isApprox(Vector3d(0.0016, 1.1 * -0.0507, 1.3 * 0.0038), 1e-15));
  // The tibia is not scaled: its moving point is not.
  EXPECT_TRUE(scaled.activePathPoints("rect_fem_r", standing)
                  .back()
                  .location_in_body.isApprox(model.activePathPoints("rect_fem_r", standing).back().location_in_body));
}

TEST(OpenSimModel, ScalingRefusesUnknownBodiesGroundAndNonPositiveFactors) {
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>(
                      [] { gait2392().scaled({{"femur", Vector3d::Ones()}}); }),
                  "cannot scale body 'femur'");
  EXPECT_THROW(gait2392().scaled({{"ground", Vector3d::Ones()}}), std::invalid_argument);
  EXPECT_THROW(gait2392().scaled({{"femur_r", Vector3d(1, 0, 1)}}), std::invalid_argument);
}

TEST(OpenSimModel, MotionRowsBecomeRadiansForRotationalCoordinatesOnly) {
  const md::MotionTable motion = md::loadMotionFile(kOneCycle);
  const md::CoordinateValues values = md::coordinateValuesAt(gait2392(), motion, 0);
  EXPECT_NEAR(values.at("hip_flexion_r"), 19.67986891 * M_PI / 180, 1e-15);
  EXPECT_NEAR(values.at("knee_angle_r"), -55.15907196 * M_PI / 180, 1e-15);
  EXPECT_DOUBLE_EQ(values.at("pelvis_tx"), 0.60176933);  // metres, as written
  EXPECT_EQ(values.size(), 23u);
  EXPECT_TRUE(md::motionColumnsNotInModel(gait2392(), motion).empty());
}

TEST(OpenSimModel, PinJointTurnsAboutZAndWeldJointHoldsItsOffset) {
  const md::OpenSimModel model = md::OpenSimModel::fromFile(writeTemporary("md_opensim_small.osim", smallModel()));
  // The shank point sits at thigh (0, -0.4) + (0.1, 0) turned by the hip angle about z, below the hip at (0, -0.5).
  const double angle = 0.6;
  const Vector3d shank_point = Vector3d(0, -0.5, 0) + rotationZ(angle) * Vector3d(0.1, -0.4, 0);
  EXPECT_NEAR(model.musculotendonLength("spanner", {{"hip_angle", angle}}),
              (shank_point - Vector3d(0.1, 0, 0)).norm(), 1e-15);
  EXPECT_EQ(model.coordinate("hip_angle").motion, md::CoordinateMotion::rotational);
}

TEST(OpenSimModel, AMuscleThatWrapsSaysSoAndItsLengthIsRefused) {
  const md::OpenSimModel model = md::OpenSimModel::fromFile(writeTemporary(
      "md_opensim_wrap.osim",
      smallModel("WeldJoint", "<PathWrap name=\"w1\"><wrap_object>femur_cylinder</wrap_object></PathWrap>")));
  EXPECT_EQ(model.muscle("spanner").wrap_objects, std::vector<std::string>{"femur_cylinder"});
  EXPECT_EQ(model.activePathPoints("spanner", {}).size(), 2u);
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { model.musculotendonLength("spanner", {}); }),
                  "muscle 'spanner' wraps over 'femur_cylinder'");
}

TEST(OpenSimModel, UnknownMusclesAndCoordinatesAreErrorsNamingTheFile) {
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>(
                      [] { gait2392().musculotendonLength("rectus_femoris", {}); }),
                  "gait2392_millard2012muscle.osim: no muscle 'rectus_femoris'");
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>(
                      [] { gait2392().musculotendonLength("rect_fem_r", {{"knee_r", 0.1}}); }),
                  "gait2392_millard2012muscle.osim: no coordinate 'knee_r'");
  EXPECT_THROW(gait2392().bodyPosesInGround({{"knee_angle_r", NAN}}), std::invalid_argument);
}

TEST(OpenSimModel, FileErrorsNameTheFileAndTheElement) {
  EXPECT_CONTAINS(
      md::testing::errorMessageOf<md::SceneError>([] { md::OpenSimModel::fromFile("/nonexistent/a.osim"); }),
      "/nonexistent/a.osim: cannot open");
  EXPECT_CONTAINS(loadError("<OpenSimDocument Version=\"40000\"><Model>"),
                  "md_opensim_model_test.osim:1: not valid XML");
  EXPECT_CONTAINS(loadError("<OpenSimDocument Version=\"30000\"><Model/></OpenSimDocument>"),
                  "is format version 30000");
  EXPECT_CONTAINS(loadError(smallModel("BallJoint")),
                  "md_opensim_model_test.osim:8: <BallJoint name=\"knee\">: is a joint type this reader does not "
                  "model");
  std::string moving = smallModel();
  moving.replace(moving.find("<PathPoint name=\"spanner-P2\">"), std::string("<PathPoint name=\"spanner-P2\">").size(),
                 "<MovingPathPoint name=\"spanner-P2\"><x_location><PolynomialFunction/></x_location>");
  moving.replace(moving.rfind("</PathPoint>"), std::string("</PathPoint>").size(), "</MovingPathPoint>");
  EXPECT_CONTAINS(loadError(moving), "<PolynomialFunction>: is a function type this reader does not evaluate");
  std::string unknown_body = smallModel();
  unknown_body.replace(unknown_body.find("/bodyset/shank</socket_parent_frame>"), 14, "/bodyset/foot");
  EXPECT_CONTAINS(loadError(unknown_body), "'/bodyset/foot' is not a body of the model");
}
