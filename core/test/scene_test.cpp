// Specifications of scene loading: URDF skeleton and forward kinematics, the scene YAML, and the bundled scene.
#include "muscle_deformation/core/scene/scene.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace md = muscle_deformation;
namespace fs = std::filesystem;

namespace {

const std::string kPackage = MD_PACKAGE_DIR;
const std::string kBundledUrdf = kPackage + "/urdf/right_hip_thigh.urdf";
const std::string kBundledScene = kPackage + "/config/scenes/right_hip_thigh.yaml";



// Two links, a revolute joint about z at (1, 0, 0.5) in the base frame, the child's origin 2 m along its x.
const char* const kArmUrdf = R"(<?xml version="1.0"?>
<robot name="arm">
  <link name="base"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/>
    <child link="upper"/>
    <origin xyz="1 0 0.5" rpy="0 0 0"/>
    <axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <link name="upper"/>
  <joint name="hand_fixed" type="fixed">
    <parent link="upper"/>
    <child link="hand"/>
    <origin xyz="2 0 0" rpy="0 0 0"/>
  </joint>
  <link name="hand"/>
</robot>)";

// A prismatic slider, and a revolute joint mimicking it (2 rad per metre, offset 0.1 rad).
const char* const kSliderUrdf = R"(<?xml version="1.0"?>
<robot name="slider">
  <link name="base"/>
  <joint name="slide" type="prismatic">
    <parent link="base"/>
    <child link="carriage"/>
    <origin xyz="0 0 0" rpy="0 0 0"/>
    <axis xyz="0 2 0"/>
    <limit lower="0" upper="1" effort="1" velocity="1"/>
  </joint>
  <link name="carriage"/>
  <joint name="follower" type="revolute">
    <parent link="carriage"/>
    <child link="wheel"/>
    <origin xyz="0 0 1" rpy="0 0 1.5707963267948966"/>
    <axis xyz="1 0 0"/>
    <limit lower="-10" upper="10" effort="1" velocity="1"/>
    <mimic joint="slide" multiplier="2" offset="0.1"/>
  </joint>
  <link name="wheel"/>
</robot>)";

std::string writeTemp(const std::string& name, const std::string& text) {
  const fs::path path = fs::temp_directory_path() / ("md_scene_test_" + name);
  std::ofstream(path) << text;
  return path.string();
}

// A scene of one muscle 'a' whose entry ends with `extra_key` (e.g. "color: [1, 2, 0]") on the file's line 5.
std::string writeOneMuscleScene(const std::string& name, const std::string& extra_key) {
  return writeTemp(name, "urdf: r.urdf\nframe: base\nmuscles:\n"
                         "- {name: a, surface: a.stl, fibres: a.vtk, origin_bone: b, insertion_bone: b,\n"
                         "   " + extra_key + "}\n");
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------
// Skeleton

TEST(Skeleton, RevoluteJointGivesTheAnalyticLinkPoses) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(kArmUrdf, "arm");
  EXPECT_EQ(skeleton.rootLink(), "base");
  ASSERT_EQ(skeleton.links().size(), 3u);
  EXPECT_EQ(skeleton.links()[1].parent_link, "base");
  EXPECT_EQ(skeleton.links()[1].parent_joint, "shoulder");
  EXPECT_EQ(skeleton.movableJointNames(), std::vector<std::string>{"shoulder"});

  const double q = 0.3;
  const auto poses = skeleton.linkPoses({{"shoulder", q}});
  const Eigen::Vector3d shoulder(1, 0, 0.5);
  EXPECT_TRUE(poses.at("base").isApprox(Eigen::Isometry3d::Identity()));
  EXPECT_TRUE(poses.at("upper").translation().isApprox(shoulder, 1e-12));
  EXPECT_TRUE(poses.at("upper").linear().isApprox(Eigen::AngleAxisd(q, Eigen::Vector3d::UnitZ()).toRotationMatrix()));
  const Eigen::Vector3d hand = shoulder + 2.0 * Eigen::Vector3d(std::cos(q), std::sin(q), 0);
  EXPECT_TRUE(poses.at("hand").translation().isApprox(hand, 1e-12)) << poses.at("hand").translation().transpose();
}

TEST(Skeleton, MissingJointValuesMeanZero) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(kArmUrdf, "arm");
  const auto poses = skeleton.linkPoses({});
  EXPECT_TRUE(poses.at("hand").translation().isApprox(Eigen::Vector3d(3, 0, 0.5), 1e-12));
}

TEST(Skeleton, PrismaticJointTranslatesAlongItsNormalisedAxisAndMimicFollows) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(kSliderUrdf, "slider");
  const md::SkeletonJoint* follower = skeleton.joint("follower");
  ASSERT_NE(follower, nullptr);
  EXPECT_EQ(follower->mimic_joint, "slide");
  EXPECT_DOUBLE_EQ(follower->mimic_multiplier, 2.0);
  EXPECT_DOUBLE_EQ(follower->mimic_offset, 0.1);
  // A pose sets the slider; the follower takes its value from it.
  EXPECT_EQ(skeleton.movableJointNames(), std::vector<std::string>{"slide"});

  const double s = 0.25;
  const auto poses = skeleton.linkPoses({{"slide", s}});
  EXPECT_TRUE(poses.at("carriage").translation().isApprox(Eigen::Vector3d(0, s, 0), 1e-12));  // axis normalised
  // wheel = carriage * (translate z 1, yaw 90 deg) * rotate about x by 2 s + 0.1.
  const Eigen::Matrix3d expected = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                                   Eigen::AngleAxisd(2 * s + 0.1, Eigen::Vector3d::UnitX()).toRotationMatrix();
  EXPECT_TRUE(poses.at("wheel").translation().isApprox(Eigen::Vector3d(0, s, 1), 1e-12));
  EXPECT_TRUE(poses.at("wheel").linear().isApprox(expected, 1e-12));
}

TEST(Skeleton, ValueOutsideTheLimitsIsAcceptedWithAWarning) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(kArmUrdf, "arm");
  std::vector<std::string> warnings;
  skeleton.linkPoses({{"shoulder", 2.0}}, &warnings);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_CONTAINS(warnings[0], "shoulder");
}

TEST(Skeleton, UnknownJointAndNonFiniteValuesAreRejected) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(kArmUrdf, "arm");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { skeleton.linkPoses({{"elbow", 0.1}}); }), "unknown joint 'elbow'");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { skeleton.linkPoses({{"shoulder", std::nan("")}}); }), "non-finite");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { skeleton.linkPoses({{"shoulder", INFINITY}}); }), "'shoulder'");
}

TEST(Skeleton, MalformedUrdfNamesItsSource) {
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([] { md::Skeleton::fromUrdfString("<robot name='x'><link", "my.urdf"); }), "my.urdf");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([] { md::Skeleton::fromUrdfFile("/nonexistent/robot.urdf"); }), "/nonexistent/robot.urdf");
}

TEST(Skeleton, LinkDifferencesNameTheLinksOnlyOneSkeletonHasAndItsSource) {
  const md::Skeleton arm = md::Skeleton::fromUrdfString(kArmUrdf, "arm.urdf");
  const md::Skeleton slider = md::Skeleton::fromUrdfString(kSliderUrdf, "robot_description");
  EXPECT_EQ(md::describeLinkDifferences(arm, md::Skeleton::fromUrdfString(kArmUrdf, "again")), "");
  EXPECT_EQ(md::describeLinkDifferences(arm, slider),
            "only arm.urdf has 'hand', 'upper'; only robot_description has 'carriage', 'wheel'");
}

TEST(Skeleton, BundledUrdfParsesWithJointsInDocumentOrder) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kBundledUrdf);
  EXPECT_EQ(skeleton.rootLink(), "world");
  const std::vector<std::string> expected{"pelvis_tx",      "pelvis_ty",       "pelvis_tz",      "pelvis_tilt",
                                          "pelvis_list",    "pelvis_rotation", "hip_flexion_r",  "hip_adduction_r",
                                          "hip_rotation_r", "knee_tx_r",       "knee_ty_r",      "knee_angle_r"};
  EXPECT_EQ(skeleton.movableJointNames(), expected);
  for (const char* bone : {"pelvis", "femur_r", "tibia_r", "patella_r"}) {
    ASSERT_NE(skeleton.link(bone), nullptr) << bone;
    EXPECT_FALSE(skeleton.link(bone)->collision_meshes.empty()) << bone;
  }
}

// gait2392's quadriceps end on tibia points that move back with knee flexion (its stand-in for a patella); the
// bundled patella follows their mean. Their mean displacement from knee angle 0, from gait2392's splines (tibia
// frame, mm: x forward, y up): at -0.5 rad (-16.3, 1.8), at -1.0 rad (-24.6, 2.8). Scaled by the tibia's 0.9 and
// carried by the knee chain, that is 14.8 and 22.2 mm; the URDF's line through 0 fitted over the gait's knee
// angles (23.7 mm/rad) gives 11.8 and 23.7 mm, within the fit's 4.1 mm of them.
TEST(Skeleton, TheBundledPatellaSlidesBackAlongTheTibiaWithKneeFlexion) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kBundledUrdf);
  ASSERT_NE(skeleton.joint("patella_slide_r"), nullptr);
  EXPECT_EQ(skeleton.joint("patella_slide_r")->mimic_joint, "knee_angle_r");
  auto patellaInTibia = [&](double knee) {
    const auto poses = skeleton.linkPoses({{"knee_angle_r", knee}});
    return Eigen::Vector3d(poses.at("tibia_r").inverse() * poses.at("patella_r").translation());
  };
  const Eigen::Vector3d rest = patellaInTibia(0.0);
  const Eigen::Vector3d half = patellaInTibia(-0.5) - rest, full = patellaInTibia(-1.0) - rest;
  EXPECT_NEAR(half.norm(), 0.0148, 0.0041);
  EXPECT_NEAR(full.norm(), 0.0222, 0.0041);
  EXPECT_LT(full.x(), -0.02);                            // backwards, towards the femur's condyles
  EXPECT_TRUE(full.isApprox(2.0 * half, 1e-9));          // one line: the URDF's slide is linear in the knee angle
  // The knee's own value drives it; a value given to the slide itself is ignored, with a warning.
  std::vector<std::string> warnings;
  const auto poses = skeleton.linkPoses({{"knee_angle_r", -1.0}, {"patella_slide_r", 0.3}}, &warnings);
  EXPECT_TRUE((poses.at("tibia_r").inverse() * poses.at("patella_r").translation() - rest).isApprox(full, 1e-12));
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_CONTAINS(warnings[0], "mimics 'knee_angle_r'");
}

TEST(Skeleton, EveryMeshTheBundledUrdfReferencesLoads) {
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kBundledUrdf);
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage + "/urdf");
  int meshes = 0;
  for (const md::SkeletonLink& link : skeleton.links()) {
    for (const md::CollisionMeshRef& ref : link.collision_meshes) {
      const md::TriangleMesh mesh = md::loadTriangleMesh(resolve(ref.uri));
      EXPECT_GT(mesh.triangleCount(), 100) << ref.uri;
      EXPECT_TRUE(md::checkSurfaceTopology(mesh).closedManifold()) << ref.uri << ": "
                                                                   << md::checkSurfaceTopology(mesh).describe();
      ++meshes;
    }
  }
  EXPECT_GE(meshes, 8);
}

// ---------------------------------------------------------------------------------------------------------------
// URIs

TEST(Scene, UriResolverHandlesPackageFileAndRelativeUris) {
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage + "/data");
  const std::string femur = kPackage + "/data/meshes/bones/femur_r.stl";
  EXPECT_TRUE(fs::equivalent(resolve("package://muscle_deformation/data/meshes/bones/femur_r.stl"), femur));
  EXPECT_TRUE(fs::equivalent(resolve("file://" + fs::absolute(femur).string()), femur));
  EXPECT_TRUE(fs::equivalent(resolve("meshes/bones/femur_r.stl"), femur));
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { resolve("package://other_pkg/a.stl"); }), "unknown package 'other_pkg'");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { resolve("http://example.com/a.stl"); }), "unsupported URI scheme");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { resolve("meshes/missing.stl"); }), "meshes/missing.stl");
}

// ---------------------------------------------------------------------------------------------------------------
// Scene YAML

TEST(Scene, BundledSceneDescriptionHasTwentySixMusclesOnUrdfLinks) {
  const md::SceneDescription scene = md::loadSceneDescription(kBundledScene);
  EXPECT_EQ(scene.urdf_file, "../../urdf/right_hip_thigh.urdf");  // relative to the scene file's folder
  EXPECT_EQ(scene.frame, "pelvis");
  ASSERT_EQ(scene.muscles.size(), 26u);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(scene, scene.urdf_file));
  for (const auto& m : scene.muscles) {
    EXPECT_NE(skeleton.link(m.origin_bone), nullptr) << m.name;
    EXPECT_NE(skeleton.link(m.insertion_bone), nullptr) << m.name;
    EXPECT_FALSE(m.tags.empty()) << m.name;
  }
  EXPECT_EQ(md::selectMuscles(scene, {"thigh13"}).size(), 13u);
}

TEST(Scene, MissingKeyNamesTheFileAndLine) {
  const std::string path = writeTemp("missing_key.yaml",
                                     "urdf: robot.urdf\n"
                                     "frame: base\n"
                                     "muscles:\n"
                                     "- name: a\n"
                                     "  surface: a.stl\n"
                                     "  fibres: a.vtk\n"
                                     "  origin_bone: base\n"
                                     "- name: b\n"
                                     "  surface: b.stl\n"
                                     "  fibres: b.vtk\n"
                                     "  insertion_bone: base\n");
  const std::string message = md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(path); });
  EXPECT_CONTAINS(message, path + " line 4");
  EXPECT_CONTAINS(message, "muscle 'a' has no 'insertion_bone' key");

  const std::string no_frame = writeTemp("no_frame.yaml", "urdf: robot.urdf\nmuscles: []\n");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(no_frame); }), "no 'frame' key");
}

TEST(Scene, MalformedValuesAndYamlNameTheLine) {
  const std::string colour = writeOneMuscleScene("bad_colour.yaml", "color: [1, 2, 0]");
  const std::string message = md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(colour); });
  EXPECT_CONTAINS(message, " line 5");
  EXPECT_CONTAINS(message, "[0, 1]");

  const std::string broken = writeTemp("broken.yaml", "urdf: robot.urdf\nframe: [base\n");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(broken); }), "not valid YAML");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([] { md::loadSceneDescription("/nonexistent/scene.yaml"); }), "/nonexistent/scene.yaml");
}

TEST(Scene, AMuscleMayGiveItsOwnParticlesPerFibre) {
  const std::string path = writeTemp("own_resolution.yaml",
                                     "urdf: r.urdf\nframe: base\nmuscles:\n"
                                     "- {name: a, surface: a.stl, fibres: a.vtk, origin_bone: b, insertion_bone: b,\n"
                                     "   particles_per_fibre: 12}\n"
                                     "- {name: c, surface: c.stl, fibres: c.vtk, origin_bone: b, insertion_bone: b}\n");
  const md::SceneDescription scene = md::loadSceneDescription(path);
  ASSERT_EQ(scene.muscles.size(), 2u);
  EXPECT_EQ(scene.muscles[0].particles_per_fibre, 12);
  EXPECT_EQ(scene.muscles[1].particles_per_fibre, 0);  // the model's

  const std::string one = writeOneMuscleScene("one_particle.yaml", "particles_per_fibre: 1");
  const std::string message = md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(one); });
  EXPECT_CONTAINS(message, " line 5");
  EXPECT_CONTAINS(message, "'particles_per_fibre' of muscle 'a' is 1, must be in [2, 10000]");
  const std::string words = writeOneMuscleScene("many_particles.yaml", "particles_per_fibre: many");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(words); }),
                  "'many' is not an integer");
}

TEST(Scene, DuplicateMuscleNamesAreRejected) {
  const std::string path = writeTemp("duplicate.yaml",
                                     "urdf: r.urdf\nframe: base\nmuscles:\n"
                                     "- {name: a, surface: a.stl, fibres: a.vtk, origin_bone: b, insertion_bone: b}\n"
                                     "- {name: a, surface: a.stl, fibres: a.vtk, origin_bone: b, insertion_bone: b}\n");
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(path); }), "'a' is used twice");
}

TEST(Scene, SelectionTakesNamesAndTagsInSceneOrderAndNamesUnknownEntries) {
  const md::SceneDescription scene = md::loadSceneDescription(kBundledScene);
  const auto picked = md::selectMuscles(scene, {"piriformis", "thigh13", "rectus_femoris"});
  ASSERT_EQ(picked.size(), 14u);
  EXPECT_EQ(picked.front().name, scene.muscles.front().name);
  EXPECT_EQ(picked.back().name, "piriformis");
  EXPECT_EQ(md::selectMuscles(scene, {}).size(), scene.muscles.size());
  const std::string message = md::testing::errorMessageOf<md::SceneError>([&] { md::selectMuscles(scene, {"sartorius", "rectus_femur", "legs"}); });
  EXPECT_CONTAINS(message, "'rectus_femur', 'legs'");
}

// ---------------------------------------------------------------------------------------------------------------
// Bundled data

TEST(Scene, EveryBundledMuscleSurfaceIsClosedAndTwoManifold) {
  const md::SceneDescription scene = md::loadSceneDescription(kBundledScene);
  for (const auto& m : scene.muscles) {
    const md::TriangleMesh surface = md::loadTriangleMesh(md::resolveScenePath(scene, m.surface_file));
    const md::SurfaceTopologyReport report = md::checkSurfaceTopology(surface);
    EXPECT_TRUE(report.closedManifold()) << m.name << ": " << report.describe();
    EXPECT_GT(md::enclosedVolume(surface), 0.0) << m.name << " is wound inwards";
  }
}

TEST(Scene, BundledSceneLoadsWithBonesFibresAndRestPoses) {
  const md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  const md::Scene scene = md::loadScene(description, skeleton, resolve, {"sartorius", "piriformis"});
  ASSERT_EQ(scene.muscles.size(), 2u);
  EXPECT_EQ(scene.muscles[0].name, "sartorius");
  EXPECT_EQ(scene.muscle_descriptions[1].name, "piriformis");
  for (const md::Muscle& m : scene.muscles) EXPECT_GE(m.fibres.size(), 16u) << m.name;

  // Bones: the links with collision meshes, in URDF order, ids = index.
  std::vector<std::string> names;
  for (std::size_t i = 0; i < scene.bones.size(); ++i) {
    EXPECT_EQ(scene.bones[i].id, static_cast<int>(i));
    names.push_back(scene.bones[i].name);
  }
  EXPECT_EQ(names, (std::vector<std::string>{"pelvis", "femur_r", "tibia_r", "patella_r"}));
  // The pelvis carries sacrum, coccyx and both hip bones: all four merged.
  const auto& pelvis = scene.bones[0].surface;
  EXPECT_TRUE(md::checkSurfaceTopology(pelvis).closedManifold());
  EXPECT_GT(pelvis.triangleCount(), 4 * 2000);

  // Scene frame = pelvis, which sits at the world origin at zero: the femur is placed by the hip joint origin.
  EXPECT_TRUE(scene.rest_link_poses.at("pelvis").isApprox(Eigen::Isometry3d::Identity()));
  EXPECT_TRUE(scene.rest_link_poses.at("femur_r").translation().isApprox(
      Eigen::Vector3d(-0.0737727, -0.0992777, -0.0591175), 1e-9));
  // A bone at rest lies where its link frame puts its mesh: the femur spans the thigh below the hip.
  const md::AlignedBox femur = md::boundsOf(scene.bones[1].surface.vertices);
  EXPECT_LT(femur.min.z(), -0.35);
  EXPECT_GT(femur.max.z(), -0.1);
}

TEST(Scene, UnknownBoneOrMissingFibreFileIsASceneError) {
  md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  description.muscles[0].insertion_bone = "kneecap";
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadScene(description, skeleton, resolve, {description.muscles[0].name}); }),
                  "no link 'kneecap'");
  description = md::loadSceneDescription(kBundledScene);
  description.muscles[0].fibre_file = "data/fibres/none.vtk";
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadScene(description, skeleton, resolve, {description.muscles[0].name}); }),
                  "generate_fibres");
  description.frame = "thorax";
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] { md::loadScene(description, skeleton, resolve); }), "'thorax'");
}

TEST(Scene, RelativePathsStartAtTheSceneFilesFolderWhereverItIsAndWhateverTheWorkingDirectory) {
  // A scene directory of the user's own, outside any package: meshes/ and fibres/ next to scene.yaml, the URDF one
  // level up. The URDF's meshes stay package:// URIs of the bundled package.
  const fs::path root = fs::temp_directory_path() / "md_scene_test_own_anatomy";
  const fs::path folder = root / "hip";
  fs::remove_all(root);
  fs::create_directories(folder / "meshes");
  fs::create_directories(folder / "fibres");
  fs::copy_file(kPackage + "/data/meshes/muscles/sartorius.stl", folder / "meshes" / "sartorius.stl");
  fs::copy_file(kPackage + "/data/fibres/sartorius.vtk", folder / "fibres" / "sartorius.vtk");
  fs::copy_file(kBundledUrdf, root / "skeleton.urdf");
  std::ofstream(folder / "scene.yaml") << "urdf: ../skeleton.urdf\nframe: pelvis\nmuscles:\n"
                                          "- {name: sartorius, surface: meshes/sartorius.stl, fibres: fibres/sartorius.vtk,\n"
                                          "   origin_bone: pelvis, insertion_bone: tibia_r}\n";

  const fs::path working_directory = fs::current_path();
  fs::current_path(root);  // the scene named by a path relative to the working directory
  md::SceneDescription description;
  std::string urdf;
  try {
    description = md::loadSceneDescription("hip/scene.yaml");
    urdf = md::resolveScenePath(description, description.urdf_file);
  } catch (...) {
    fs::current_path(working_directory);
    throw;
  }
  fs::current_path("/");  // and loaded from anywhere else
  EXPECT_TRUE(fs::equivalent(description.folder, folder)) << description.folder;
  EXPECT_TRUE(fs::equivalent(urdf, root / "skeleton.urdf")) << urdf;
  // Not the package root, not the working directory: the scene's folder.
  EXPECT_EQ(md::resolveScenePath(description, "data/fibres/a.vtk"), (folder / "data/fibres/a.vtk").string());
  EXPECT_EQ(md::resolveScenePath(description, "/abs/a.vtk"), "/abs/a.vtk");
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  md::Scene scene;
  try {
    scene = md::loadScene(description, md::Skeleton::fromUrdfFile(urdf), resolve);
  } catch (...) {
    fs::current_path(working_directory);
    throw;
  }
  fs::current_path(working_directory);
  ASSERT_EQ(scene.muscles.size(), 1u);
  EXPECT_EQ(scene.muscles[0].fibres.size(), 64u);
  EXPECT_EQ(scene.muscles[0].origin_bone, "pelvis");
  EXPECT_EQ(scene.muscles[0].insertion_bone, "tibia_r");

  // A path that is not there is named as resolved, with the scene file and the muscle.
  description.muscles[0].surface_file = "meshes/gone.stl";
  const std::string message =
      md::testing::errorMessageOf<md::LoadError>([&] { md::loadScene(description, md::Skeleton::fromUrdfFile(urdf), resolve); });
  EXPECT_CONTAINS(message, (folder / "meshes/gone.stl").string());
  // A URI without a resolver to turn it into a path is refused, naming the scene.
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>(
                      [&] { md::resolveScenePath(description, "package://muscle_deformation/x.stl"); }),
                  description.path);
  fs::remove_all(root);
}

namespace {

// The bundled URDF without the patella: its link and the joint that carries it.
std::string bundledUrdfWithoutPatella() {
  std::ifstream file(kBundledUrdf);
  const std::string xml((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  const std::regex patella("<joint name=\"patella_slide_r\"[\\s\\S]*?</joint>|<link name=\"patella_r\">[\\s\\S]*?</link>");
  return std::regex_replace(xml, patella, "");
}

}  // namespace

TEST(Scene, EveryLinkTheSceneNamesThatTheUrdfLacksIsListedBeforeAnythingLoads) {
  md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(bundledUrdfWithoutPatella(), "/robot_description");
  ASSERT_EQ(skeleton.link("patella_r"), nullptr);
  EXPECT_EQ(md::linksMissingFrom(description, skeleton), std::vector<std::string>{"patella_r"});
  EXPECT_TRUE(md::linksMissingFrom(description, md::Skeleton::fromUrdfFile(kBundledUrdf)).empty());

  description.frame = "thorax";
  description.muscles[3].origin_bone = "femur_l";
  EXPECT_EQ(md::linksMissingFrom(description, skeleton), (std::vector<std::string>{"thorax", "patella_r", "femur_l"}));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  // Even a selection of muscles on bones the URDF has: the scene and the skeleton do not fit.
  const std::string message = md::testing::errorMessageOf<md::SceneError>(
      [&] { md::loadScene(description, skeleton, resolve, {"sartorius"}); });
  EXPECT_CONTAINS(message, "/robot_description");
  EXPECT_CONTAINS(message, "has no links 'thorax', 'patella_r', 'femur_l'");
  EXPECT_CONTAINS(message, "the scene frame is 'thorax'");
  EXPECT_CONTAINS(message, "muscle '" + description.muscles[3].name + "' names 'femur_l'");
  EXPECT_CONTAINS(message, "more");  // the quadriceps all name the patella: a few listed, the rest counted
}

TEST(Scene, PoseFromLinkPosesMovesBonesRelativeToRest) {
  const md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  md::Scene scene;
  scene.skeleton = skeleton;
  scene.rest_link_poses = skeleton.linkPoses({});
  for (const char* name : {"pelvis", "femur_r"}) {
    md::Bone bone;
    bone.name = name;
    scene.bones.push_back(bone);
  }
  const auto bent = skeleton.linkPoses({{"hip_flexion_r", 0.5}});
  const md::Pose pose = md::poseFromLinkPoses(scene, bent);
  EXPECT_TRUE(pose.transformOf("pelvis").isApprox(Eigen::Isometry3d::Identity()));
  // The hip centre stays put and the femur turns by 0.5 rad.
  const Eigen::Vector3d hip = scene.rest_link_poses.at("femur_r").translation();
  EXPECT_TRUE((pose.transformOf("femur_r") * hip).isApprox(hip, 1e-12));
  EXPECT_NEAR(Eigen::AngleAxisd(pose.transformOf("femur_r").linear()).angle(), 0.5, 1e-12);
}

namespace {

// The bundled URDF with the <collision> elements of `link` (every link if empty) removed.
std::string bundledUrdfWithoutCollisions(const std::string& link = "") {
  std::ifstream file(kBundledUrdf);
  std::string xml((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  const std::regex collision("<collision[\\s\\S]*?</collision>");
  if (link.empty()) return std::regex_replace(xml, collision, "");
  const std::size_t begin = xml.find("<link name=\"" + link + "\"");
  const std::size_t end = xml.find("</link>", begin);
  return xml.substr(0, begin) + std::regex_replace(xml.substr(begin, end - begin), collision, "") + xml.substr(end);
}

}  // namespace

TEST(Scene, AUrdfWithoutCollisionMeshesIsRefusedForHavingNoBones) {
  const md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(bundledUrdfWithoutCollisions(), "robot_description");
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  EXPECT_CONTAINS(md::testing::errorMessageOf<md::SceneError>([&] {
                    md::loadScene(description, skeleton, resolve, {description.muscles[0].name});
                  }),
                  "no link with a <collision> mesh");
}

TEST(Scene, AMuscleOnALinkWithoutCollisionMeshIsRefusedNamingBoth) {
  const md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfString(bundledUrdfWithoutCollisions("pelvis"), "robot_description");
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  const md::MuscleDescription& muscle = description.muscles[0];
  ASSERT_EQ(muscle.origin_bone, "pelvis");
  const std::string message = md::testing::errorMessageOf<md::SceneError>(
      [&] { md::loadScene(description, skeleton, resolve, {muscle.name}); });
  EXPECT_CONTAINS(message, "'pelvis'");
  EXPECT_CONTAINS(message, "no <collision> mesh");
  EXPECT_CONTAINS(message, "muscle '" + muscle.name + "'");
}

TEST(Scene, PackageUrisInTheSceneFileResolveLikeTheUrdfsAndNameTheMuscleWhenTheyDoNot) {
  md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  md::MuscleDescription& muscle = description.muscles[0];
  muscle.surface_file = "package://muscle_deformation/data/meshes/muscles/" + muscle.name + ".stl";
  muscle.fibre_file = "package://muscle_deformation/data/fibres/" + muscle.name + ".vtk";
  const md::Scene scene = md::loadScene(description, skeleton, resolve, {muscle.name});
  ASSERT_EQ(scene.muscles.size(), 1u);
  EXPECT_GT(scene.muscles[0].fibres.size(), 0u);

  muscle.surface_file = "package://other_pkg/surface.stl";
  const std::string message = md::testing::errorMessageOf<md::SceneError>(
      [&] { md::loadScene(description, skeleton, resolve, {muscle.name}); });
  EXPECT_CONTAINS(message, "unknown package 'other_pkg'");
  EXPECT_CONTAINS(message, "muscle '" + muscle.name + "'");
  EXPECT_EQ(message.find(kPackage + "/package:"), std::string::npos) << "no path glued from the package root and a URI";
}

TEST(Scene, FibreExcursionIsTheDeepestFibrePointOutsideTheSurface) {
  md::Muscle muscle;
  muscle.name = "cube";
  muscle.surface = md::testing::unitCube();
  md::Polyline inside(3, 2), leaving(3, 3);
  inside << 0.2, 0.8, 0.5, 0.5, 0.5, 0.5;
  leaving << 0.5, 0.5, 0.5,  //
      0.5, 0.5, 0.5,         //
      0.5, 1.3, 1.1;
  muscle.fibres = {inside};
  EXPECT_EQ(md::fibreExcursion(muscle).max_outside_m, 0.0);
  EXPECT_EQ(md::fibreExcursion(muscle).fibre, -1);
  muscle.fibres.push_back(leaving);
  const md::FibreExcursion excursion = md::fibreExcursion(muscle);
  EXPECT_NEAR(excursion.max_outside_m, 0.3, 1e-12);
  EXPECT_EQ(excursion.fibre, 1);
  EXPECT_EQ(excursion.point, 1);
}

TEST(Scene, EveryBundledMusclesFibresStayWithinTheToleranceOfItsSurface) {
  const md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  const md::Scene scene = md::loadScene(description, skeleton, resolve);  // refuses a fibre further out
  double worst = 0;
  for (const md::Muscle& muscle : scene.muscles) worst = std::max(worst, md::fibreExcursion(muscle).max_outside_m);
  EXPECT_LE(worst, md::kFibreOutsideToleranceM);
  std::printf("bundled scene: fibres leave their surface by at most %.2f mm\n", 1000.0 * worst);
}

TEST(Scene, FibresFarOutsideTheirMuscleAreRefusedNamingMuscleFibreDistanceAndTolerance) {
  md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  md::MuscleDescription& muscle = description.muscles[0];
  // The muscle's own fibres shifted 5 cm: a fibre file in the wrong frame.
  std::vector<md::Polyline> fibres = md::loadPolylines(md::resolveScenePath(description, muscle.fibre_file));
  for (md::Polyline& fibre : fibres) fibre.row(0).array() += 0.05;
  const std::string shifted = (fs::temp_directory_path() / "md_scene_test_shifted_fibres.vtk").string();
  md::savePolylinesVtk(shifted, fibres);
  muscle.fibre_file = shifted;
  const std::string message = md::testing::errorMessageOf<md::SceneError>(
      [&] { md::loadScene(description, skeleton, resolve, {muscle.name}); });
  EXPECT_CONTAINS(message, "muscle '" + muscle.name + "'");
  EXPECT_CONTAINS(message, "mm outside the muscle's surface");
  EXPECT_CONTAINS(message, "at most 5 mm outside");
}

TEST(Scene, AMuscleSurfaceWithAHoleIsRefusedPointingAtTheRepairAndRepairedWhenTheSceneAsks) {
  md::SceneDescription description = md::loadSceneDescription(kBundledScene);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(md::resolveScenePath(description, description.urdf_file));
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);
  md::MuscleDescription& muscle = description.muscles[0];
  const md::TriangleMesh intact = md::loadClosedSurface(md::resolveScenePath(description, muscle.surface_file));
  md::TriangleMesh holed = intact;
  holed.triangles = intact.triangles.leftCols(intact.triangleCount() - 1);  // one triangle missing, as segmenters do
  const std::string path = (fs::temp_directory_path() / "md_scene_test_holed_muscle.stl").string();
  md::saveTriangleMeshStl(path, holed);
  muscle.surface_file = path;

  const std::string refusal = md::testing::errorMessageOf<md::LoadError>(
      [&] { md::loadScene(description, skeleton, resolve, {muscle.name}); });
  EXPECT_CONTAINS(refusal, path);
  EXPECT_CONTAINS(refusal, "3 boundary edges");
  EXPECT_CONTAINS(refusal, "repair_surfaces: true");

  description.repair_surfaces = true;
  const md::Scene scene = md::loadScene(description, skeleton, resolve, {muscle.name});
  ASSERT_EQ(scene.repairs.size(), 1u);
  EXPECT_CONTAINS(scene.repairs[0], "muscle '" + muscle.name + "'");
  EXPECT_CONTAINS(scene.repairs[0], "triangles added to close holes: 1");
  EXPECT_TRUE(md::checkSurfaceTopology(scene.muscles[0].surface).closedManifold());
  EXPECT_NEAR(md::enclosedVolume(scene.muscles[0].surface), md::enclosedVolume(intact), 1e-12);
}

TEST(Scene, RepairSurfacesKeyIsABoolean) {
  const std::string scene_text = "urdf: urdf/right_hip_thigh.urdf\nframe: pelvis\nrepair_surfaces: %s\nmuscles:\n"
                                 "  - {name: a, surface: a.stl, fibres: a.vtk, origin_bone: pelvis, insertion_bone: femur_r}\n";
  auto withRepair = [&](const std::string& value) {
    std::string text = scene_text;
    text.replace(text.find("%s"), 2, value);
    return writeTemp("repair_" + std::to_string(value.size()) + ".yaml", text);
  };
  EXPECT_TRUE(md::loadSceneDescription(withRepair("true")).repair_surfaces);
  EXPECT_FALSE(md::loadSceneDescription(withRepair("false")).repair_surfaces);
  const std::string message =
      md::testing::errorMessageOf<md::SceneError>([&] { md::loadSceneDescription(withRepair("maybe")); });
  EXPECT_CONTAINS(message, "line 3");
  EXPECT_CONTAINS(message, "'repair_surfaces' must be true or false");
}

// A scene may replace a URDF bone mesh that is not closed by a closed copy (bone_surfaces, as prepare_scene writes it):
// the copy is loaded where the URDF places the mesh. A copy for a mesh the URDF does not name means the scene was made
// for another skeleton, and is refused.
TEST(Scene, BoneSurfacesStandInForTheMeshTheyNameAndOneTheUrdfDoesNotNameIsRefused) {
  const std::string cube = (fs::temp_directory_path() / "md_scene_test_stand_in.stl").string();
  md::saveTriangleMeshStl(cube, md::testing::unitCube());
  const std::string patella = "package://muscle_deformation/data/meshes/bones/patella_r.stl";
  const std::string scene_file = writeTemp("bone_surfaces.yaml",
      "urdf: " + kBundledUrdf + "\nframe: pelvis\nbone_surfaces:\n  - mesh: " + patella + "\n    surface: " + cube +
      "\nmuscles:\n  - {name: a, surface: a.stl, fibres: a.vtk, origin_bone: pelvis, insertion_bone: femur_r}\n");
  md::SceneDescription description = md::loadSceneDescription(scene_file);
  ASSERT_EQ(description.bone_surfaces.size(), 1u);
  EXPECT_EQ(description.bone_surfaces.at(patella), cube);
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kBundledUrdf);
  const md::UriResolver resolve = md::makeUriResolver({{"muscle_deformation", kPackage}}, kPackage);

  const std::vector<md::Bone> bones = md::loadBones(description, skeleton, resolve);
  const auto bone = std::find_if(bones.begin(), bones.end(), [](const md::Bone& b) { return b.name == "patella_r"; });
  ASSERT_NE(bone, bones.end());
  ASSERT_EQ(bone->surface.triangleCount(), 12);
  // Link frames are parallel to the pelvis at zero: the unit cube lands at the patella link's origin.
  const Eigen::Vector3d origin = skeleton.linkPoses({}).at("patella_r").translation();
  const md::AlignedBox placed = md::boundsOf(bone->surface.vertices);
  EXPECT_LT((placed.min - origin).norm(), 1e-6);
  EXPECT_LT((placed.max - origin - Eigen::Vector3d::Ones()).norm(), 1e-6);

  description.bone_surfaces = {{"package://muscle_deformation/data/meshes/bones/ulna.stl", cube}};
  const std::string message =
      md::testing::errorMessageOf<md::SceneError>([&] { md::loadBones(description, skeleton, resolve); });
  EXPECT_CONTAINS(message, "bone_surfaces replaces mesh 'package://muscle_deformation/data/meshes/bones/ulna.stl'");
  EXPECT_CONTAINS(message, "which no link of the URDF");
}
