// Specifications of scene preparation: from segmented surfaces with defects (in millimetres) and a URDF whose bone
// meshes are not all closed, to a scene directory the node loads as it is.
#include "muscle_deformation/preprocessing/scene_directory.hpp"
#include "muscle_deformation/preprocessing/scene_preparation.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/core/pipeline/settings_table.hpp"
#include "muscle_deformation/core/scene/opensim_model.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <tuple>

#include <unistd.h>  // getpid: a temporary folder per test process

namespace md = muscle_deformation;
namespace fs = std::filesystem;

namespace {

std::string readText(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

md::TriangleMesh withExtraTriangles(md::TriangleMesh mesh, const std::vector<Eigen::Vector3i>& extra) {
  const Eigen::Index first = mesh.triangleCount();
  mesh.triangles.conservativeResize(Eigen::NoChange, first + static_cast<Eigen::Index>(extra.size()));
  for (std::size_t i = 0; i < extra.size(); ++i) mesh.triangles.col(first + static_cast<Eigen::Index>(i)) = extra[i];
  return mesh;
}

const fs::path kSmallHip = fs::path(MD_TEST_DATA_DIR) / "prepare_scene" / "small_hip.urdf";

md::UriResolver packageResolver() { return md::makeUriResolver({{"muscle_deformation", MD_PACKAGE_DIR}}, MD_PACKAGE_DIR); }

// The small hip of test/data/prepare_scene (a `pelvis` box above the muscle, a `femur_r` box below it whose mesh has a
// hole, a `marker` box against the muscle's side that is neither its origin nor insertion) and a spindle muscle
// written in millimetres with the defects of a segmentation: a fin on one edge (a non-manifold edge), two degenerate
// triangles and a duplicated one.
class ScenePreparationTest : public ::testing::Test {
 protected:
  void SetUp() override {
    raw_ = fs::temp_directory_path() / ("md_scene_preparation_" + std::to_string(::getpid()));
    fs::remove_all(raw_);
    fs::create_directories(raw_);
    out_ = raw_ / "scene";
    md::TriangleMesh muscle =
        md::makeSpindleMuscle("muscle", {0, 0, 0.0}, {0, 0, 0.1}, 0.012, 1.0, 2, 10, 24, 30).surface;
    const Eigen::Vector3i t0 = muscle.triangles.col(0), t5 = muscle.triangles.col(5);
    muscle.vertices.conservativeResize(Eigen::NoChange, muscle.vertexCount() + 1);
    muscle.vertices.col(muscle.vertexCount() - 1) = 1.2 * muscle.vertices.col(t0[0]);  // the fin's tip
    const int tip = static_cast<int>(muscle.vertexCount() - 1);
    muscle = withExtraTriangles(muscle, {{t0[0], t0[1], tip}, {t5[0], t5[0], t5[1]}, {t5[1], t5[2], t5[2]}, t5});
    muscle.vertices *= 1000.0;  // millimetres
    md::saveTriangleMeshStl((raw_ / "muscle_mm.stl").string(), muscle);
  }
  void TearDown() override { fs::remove_all(raw_); }

  md::ScenePreparationRequest request(std::vector<md::MuscleSource> muscles) const {
    md::ScenePreparationRequest r;
    r.out_dir = out_.string();
    r.urdf_file = kSmallHip.string();
    r.muscles = std::move(muscles);
    r.scale_to_metres = 0.001;
    r.resolve_uri = packageResolver();
    r.fibres.fibre_count = 16;
    r.fibres.min_inside_voxels = 20000;
    return r;
  }
  md::MuscleSource goodMuscle() const { return {"spindle", (raw_ / "muscle_mm.stl").string(), "pelvis", "femur_r"}; }

  fs::path raw_, out_;
};

}  // namespace

TEST(ScenePreparationCommandLine, AMuscleIsNameMeshOriginAndInsertionAndTheMeshPathMayHoldColons) {
  const md::MuscleSource plain = md::parseMuscleSource("psoas:/data/psoas.ply:pelvis:femur_r");
  EXPECT_EQ(plain.name, "psoas");
  EXPECT_EQ(plain.mesh_file, "/data/psoas.ply");
  EXPECT_EQ(plain.origin_link, "pelvis");
  EXPECT_EQ(plain.insertion_link, "femur_r");
  EXPECT_EQ(md::parseMuscleSource("a:C:/x:y.stl:p:f").mesh_file, "C:/x:y.stl");
  EXPECT_THROW(md::parseMuscleSource("psoas:/data/psoas.ply:pelvis"), std::invalid_argument);
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>([] { md::parseMuscleSource("psoas::pelvis:femur_r"); }),
                  "MESH is empty");
}

TEST_F(ScenePreparationTest, DefectiveSurfacesAreRepairedAndEachRepairIsReported) {
  const md::ScenePreparation scene = md::prepareScene(request({goodMuscle()}));
  ASSERT_EQ(scene.muscles.size(), 1u);
  const md::PreparedMuscle& muscle = scene.muscles[0];
  ASSERT_TRUE(muscle.prepared()) << muscle.refusal;
  EXPECT_CONTAINS(muscle.defects, "non-manifold");
  EXPECT_EQ(muscle.repair.non_manifold_triangles_removed, 3);  // the fin and the two muscle triangles on its edge
  EXPECT_EQ(muscle.repair.degenerate_triangles_removed, 2);
  EXPECT_EQ(muscle.repair.duplicate_triangles_removed, 1);
  EXPECT_GE(muscle.repair.hole_triangles_added, 2);
  EXPECT_TRUE(md::checkSurfaceTopology(muscle.surface).closedManifold());
  EXPECT_NEAR(muscle.surface.vertices.row(2).maxCoeff(), 0.1, 1e-3);  // millimetres became metres

  const std::string report = readText(out_ / md::kReportFileName);
  EXPECT_CONTAINS(report, "triangles on non-manifold edges removed: 3");
  EXPECT_CONTAINS(report, "degenerate triangles removed: 2");
  EXPECT_CONTAINS(report, "duplicate triangles removed: 1");
}

TEST_F(ScenePreparationTest, ABoneMeshThatIsNotClosedIsRepairedIntoTheSceneAndTheSceneUsesTheCopy) {
  const md::ScenePreparation scene = md::prepareScene(request({goodMuscle()}));
  EXPECT_TRUE(scene.bonesUsable());
  const auto femur = std::find_if(scene.bone_meshes.begin(), scene.bone_meshes.end(),
                                  [](const md::BoneMeshCheck& b) { return b.link == "femur_r"; });
  ASSERT_NE(femur, scene.bone_meshes.end());
  EXPECT_CONTAINS(femur->defects, "boundary edges");
  EXPECT_GE(femur->repair.hole_triangles_added, 2);
  ASSERT_FALSE(femur->stand_in.empty());
  EXPECT_TRUE(md::checkSurfaceTopology(md::loadTriangleMesh((out_ / femur->stand_in).string())).closedManifold());

  const md::SceneDescription description = md::loadSceneDescription((out_ / md::kSceneFileName).string());
  ASSERT_EQ(description.bone_surfaces.count("package://muscle_deformation/test/data/prepare_scene/femur_mm.obj"), 1u);
  EXPECT_EQ(femur->stand_in, "meshes/bones/femur_r_femur_mm.stl");
  const md::Scene loaded = md::loadScene(description, md::Skeleton::fromUrdfFile(kSmallHip.string()), packageResolver());
  for (const md::Bone& bone : loaded.bones)
    EXPECT_TRUE(md::checkSurfaceTopology(bone.surface).closedManifold()) << bone.name;
}

// The node's own path: the scene as written loads, builds and solves a pose, from wherever the directory is moved to.
TEST_F(ScenePreparationTest, ThePreparedSceneLoadsFromItsFolderWhereverItIsAndSolvesAPose) {
  const md::ScenePreparation scene = md::prepareScene(request({goodMuscle()}));
  ASSERT_EQ(scene.preparedCount(), 1);
  const std::string yaml = readText(out_ / md::kSceneFileName);
  EXPECT_CONTAINS(yaml, "surface: \"meshes/muscles/spindle.stl\"");
  EXPECT_CONTAINS(yaml, "fibres: \"fibres/spindle.vtk\"");
  EXPECT_CONTAINS(yaml, "urdf: \"" + kSmallHip.lexically_relative(out_).string() + "\"");

  const fs::path moved = raw_ / "elsewhere" / "my_scene";
  fs::create_directories(moved.parent_path());
  fs::rename(out_, moved);
  const md::SceneDescription description = md::loadSceneDescription((moved / md::kSceneFileName).string());
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kSmallHip.string());
  md::Scene loaded = md::loadScene(description, skeleton, packageResolver());
  ASSERT_EQ(loaded.muscles.size(), 1u);
  EXPECT_TRUE(loaded.repairs.empty());   // the written surface is closed: nothing left to repair
  EXPECT_TRUE(loaded.warnings.empty());  // the fibre checks passed
  EXPECT_EQ(loaded.muscles[0].fibres.size(), 16u);

  md::PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 8;
  md::DeformationPipeline pipeline(loaded.muscle_descriptions, loaded.muscles, loaded.bones, settings);
  const md::Pose pose = md::poseFromLinkPoses(loaded, skeleton.linkPoses({{"hip_flexion_r", 0.3}}));
  // The Verlet solver of the default settings, 100 iterations.
  const md::FrameResult& frame = pipeline.solve(md::boneTransformsOf(pipeline.bones(), pose), md::StartMode::cold,
                                                md::FrameStopping::of(md::StoppingSettings::afterIterations(100)),
                                                true, true);
  EXPECT_TRUE(frame.stats.finite);
  EXPECT_TRUE(frame.has_surfaces);
}

// Particles are fixed to the muscle's origin and insertion bones only: the marker bone against its side holds none.
TEST_F(ScenePreparationTest, NoParticleIsFixedToABoneThatIsNeitherTheOriginNorTheInsertion) {
  const md::ScenePreparation scene = md::prepareScene(request({goodMuscle()}));
  const md::MuscleBuildSummary& attachments = scene.muscles.at(0).attachments;
  ASSERT_GT(attachments.fixed_particles, 0);
  for (const auto& [bone, count] : attachments.fixed_by_bone)
    EXPECT_TRUE(bone == "pelvis" || bone == "femur_r") << count << " particles fixed to " << bone;
  EXPECT_GT(attachments.fixed_by_bone.count("pelvis") + attachments.fixed_by_bone.count("femur_r"), 0u);
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "Attachments the node makes with its defaults");
}

TEST_F(ScenePreparationTest, AMuscleThatCannotBePreparedIsReportedWithTheReasonAndTheOthersArePrepared) {
  fs::copy_file(std::string(MD_TEST_DATA_DIR) + "/nonmanifold.obj", raw_ / "broken.obj");
  const md::ScenePreparation scene = md::prepareScene(request(
      {{"broken", (raw_ / "broken.obj").string(), "pelvis", "femur_r"},
       goodMuscle(),
       {"lost", (raw_ / "muscle_mm.stl").string(), "pelvis", "tibia_r"},
       {"floating", (raw_ / "muscle_mm.stl").string(), "pelvis", "no_bone"},
       {"missing", (raw_ / "nowhere.stl").string(), "pelvis", "femur_r"}}));
  ASSERT_EQ(scene.muscles.size(), 5u);
  EXPECT_EQ(scene.preparedCount(), 1);
  EXPECT_TRUE(scene.muscles[1].prepared()) << scene.muscles[1].refusal;
  EXPECT_CONTAINS(scene.muscles[0].refusal, "enclose no volume");
  EXPECT_CONTAINS(scene.muscles[2].refusal, "insertion link 'tibia_r' is not a link of the URDF");
  EXPECT_CONTAINS(scene.muscles[3].refusal, "'no_bone' has no <collision> mesh");
  EXPECT_CONTAINS(scene.muscles[4].refusal, "nowhere.stl");

  const md::SceneDescription description = md::loadSceneDescription((out_ / md::kSceneFileName).string());
  ASSERT_EQ(description.muscles.size(), 1u);
  EXPECT_EQ(description.muscles[0].name, "spindle");
  const std::string report = readText(out_ / md::kReportFileName);
  EXPECT_CONTAINS(report, "1 of 5 muscles prepared");
  EXPECT_CONTAINS(report, "**Not prepared**: insertion link 'tibia_r'");
}

TEST_F(ScenePreparationTest, FibresThatFailTheirChecksAreMarkedInTheirFileAndTheSceneWarnsWhenItLoads) {
  md::ScenePreparationRequest asked = request({goodMuscle()});
  asked.fibres.min_separation = 0.006;  // fibres kept 6 mm apart: the 24 mm wide muscle cannot hold 16 of them
  const md::ScenePreparation scene = md::prepareScene(asked);
  ASSERT_TRUE(scene.muscles.at(0).prepared()) << scene.muscles[0].refusal;
  ASSERT_FALSE(scene.muscles[0].fibres.checks.passed());
  const std::string recorded = md::recordedFibreCheckFailures((out_ / "fibres" / "spindle.vtk").string());
  EXPECT_CONTAINS(recorded, "fibres instead of 16");

  const md::Scene loaded = md::loadScene(md::loadSceneDescription((out_ / md::kSceneFileName).string()),
                                         md::Skeleton::fromUrdfFile(kSmallHip.string()), packageResolver());
  ASSERT_EQ(loaded.warnings.size(), 1u);
  EXPECT_CONTAINS(loaded.warnings[0], "muscle 'spindle': its fibres failed their checks");
  EXPECT_CONTAINS(loaded.warnings[0], "fibres instead of 16");
}

TEST_F(ScenePreparationTest, TheViewFramesTheSceneInItsFrameAndShowsTheBonesMarkers) {
  md::prepareScene(request({goodMuscle()}));
  const std::string view = readText(out_ / md::kRvizFileName);
  EXPECT_CONTAINS(view, "Fixed Frame: pelvis");
  EXPECT_CONTAINS(view, "Marker Topic: /muscle_deformation/bones");
  // Focal point: the centre of the muscle and its two bones (x, y 0; z from -0.03 to 0.13).
  EXPECT_CONTAINS(view, "Focal Point:\n        X: 0.000\n        Y: 0.000\n        Z: 0.050");
}

// ---------------------------------------------------------------------------------------------------------------
// Attachment sites: from the command line (LINK@x,y,z) and from an OpenSim model of the same skeleton (--osim)

namespace {

const fs::path kGait2392 = fs::path(MD_PACKAGE_DIR) / "data" / "opensim" / "gait2392_millard2012muscle.osim";

}  // namespace

TEST(ScenePreparationCommandLine, EitherLinkMayCarryItsSiteInMetresInTheLinksFrame) {
  const md::MuscleSource source = md::parseMuscleSource("st:/data/st.stl:pelvis@0.1,-0.2,3e-2:tibia_r");
  EXPECT_EQ(source.origin_link, "pelvis");
  ASSERT_TRUE(source.origin_site.has_value());
  EXPECT_TRUE(source.origin_site->isApprox(Eigen::Vector3d(0.1, -0.2, 0.03)));
  EXPECT_EQ(source.insertion_link, "tibia_r");
  EXPECT_FALSE(source.insertion_site.has_value());
  EXPECT_TRUE(md::parseMuscleSource("st:st.stl:pelvis:tibia_r@0,0,-0.5").insertion_site->isApprox(
      Eigen::Vector3d(0, 0, -0.5)));

  using md::testing::errorMessageOf;
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([] { md::parseMuscleSource("st:st.stl:pelvis@1,2:tibia_r"); }),
                  "LINK@x,y,z");
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([] { md::parseMuscleSource("st:st.stl:pelvis@1,2,3,4:tibia_r"); }),
                  "LINK@x,y,z");
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([] { md::parseMuscleSource("st:st.stl:pelvis@1,2,3mm:tibia_r"); }),
                  "'3mm' is not a number");
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([] { md::parseMuscleSource("st:st.stl:pelvis@nan,0,0:tibia_r"); }),
                  "finite");
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([] { md::parseMuscleSource("st:st.stl:@1,2,3:tibia_r"); }),
                  "the link is empty");
}

// A straight belly along z from 0 to 0.1 m and a path along it from below to above: the points before the belly's
// origin end go to the origin's tendon, those past its insertion end to the insertion's, those it covers (inside it,
// or beside it within its extent) are left out and said so.
TEST(AttachmentSites, ViaPointsGoToTheTendonOnTheirSideOfTheBellyAndThoseTheBellyCoversAreLeftOut) {
  const md::Muscle belly = md::makeSpindleMuscle("belly", {0, 0, 0.0}, {0, 0, 0.1}, 0.012, 1.0, 2, 10, 24, 30);
  const std::map<std::string, Eigen::Isometry3d> rest = {{"lower", Eigen::Isometry3d::Identity()},
                                                         {"upper", Eigen::Isometry3d(Eigen::Translation3d(0, 0, 0.2))}};
  using Role = md::PathCandidate::Role;
  const std::vector<md::PathCandidate> path = {
      {"O", {"lower", {0, 0, -0.05}}, Role::origin_site},
      {"V1", {"lower", {0.01, 0, -0.02}}, Role::via},
      {"V2", {"lower", {0, 0, 0.05}}, Role::via},       // inside the belly
      {"V3", {"lower", {0.03, 0, 0.06}}, Role::via},    // beside it, within its extent
      {"V4", {"upper", {0.0, 0.01, -0.07}}, Role::via},  // z = 0.13, past its insertion end
      {"I", {"upper", {0, 0, -0.04}}, Role::insertion_site}};
  const md::TendonPaths paths = md::placeAgainstBelly(path, belly.surface, belly.fibres, rest, {});
  ASSERT_EQ(paths.origin_path.size(), 2u);
  EXPECT_EQ(paths.origin_path[0].label, "O");
  EXPECT_EQ(paths.origin_path[1].label, "V1");
  ASSERT_EQ(paths.insertion_path.size(), 2u);
  EXPECT_EQ(paths.insertion_path[0].label, "V4");
  EXPECT_EQ(paths.insertion_path[1].label, "I");
  EXPECT_EQ(paths.insertion_path[1].site.link, "upper");
  EXPECT_TRUE(paths.insertion_path[1].site.point.isApprox(Eigen::Vector3d(0, 0, -0.04)));  // in its link's frame
  EXPECT_CONTAINS(paths.source(), "V2 left out: inside the belly (on the belly's path)");
  EXPECT_CONTAINS(paths.source(), "V3 left out: within the belly's extent along the path (on the belly's path)");
  // Those the belly covers are the line its fibres follow, in path order.
  ASSERT_EQ(paths.belly_path.size(), 2u);
  EXPECT_EQ(paths.belly_path[0].label, "V2");
  EXPECT_EQ(paths.belly_path[1].label, "V3");
  EXPECT_TRUE(paths.belly_path[1].site.point.isApprox(Eigen::Vector3d(0.03, 0, 0.06)));

  // A site inside the belly: its side gets no tendon path (the fibre ends there lie on the bone).
  std::vector<md::PathCandidate> inside = path;
  inside.front().site.point = {0, 0, 0.01};
  const md::TendonPaths without_origin = md::placeAgainstBelly(inside, belly.surface, belly.fibres, rest, {});
  EXPECT_TRUE(without_origin.origin_path.empty());
  EXPECT_EQ(without_origin.insertion_path.size(), 2u);
  EXPECT_CONTAINS(without_origin.source(), "O lies inside the belly");
}

TEST_F(ScenePreparationTest, SitesGivenWithTheMuscleGoIntoTheSceneAndTheNodeReadsThemInTheSceneFrame) {
  md::MuscleSource muscle = goodMuscle();
  muscle.origin_site = Eigen::Vector3d(0, 0.04, 0.115);     // on the pelvis box's side
  muscle.insertion_site = Eigen::Vector3d(0.04, 0, -0.015);  // on the femur box's side
  const md::ScenePreparation scene = md::prepareScene(request({muscle}));
  ASSERT_TRUE(scene.muscles.at(0).prepared()) << scene.muscles[0].refusal;
  const md::TendonPaths& sites = scene.muscles[0].sites;
  ASSERT_EQ(sites.origin_path.size(), 1u);
  ASSERT_EQ(sites.insertion_path.size(), 1u);
  EXPECT_NEAR(sites.origin_path[0].bone_distance_m, 0.0, 1e-9);  // on the bone's surface
  EXPECT_NEAR(sites.insertion_path[0].bone_distance_m, 0.0, 1e-9);

  const md::SceneDescription description = md::loadSceneDescription((out_ / md::kSceneFileName).string());
  ASSERT_EQ(description.muscles.size(), 1u);
  ASSERT_EQ(description.muscles[0].origin_path.size(), 1u);
  EXPECT_EQ(description.muscles[0].origin_path[0].link, "pelvis");
  EXPECT_TRUE(description.muscles[0].origin_path[0].point.isApprox(Eigen::Vector3d(0, 0.04, 0.115)));
  ASSERT_EQ(description.muscles[0].insertion_path.size(), 1u);
  EXPECT_EQ(description.muscles[0].insertion_path[0].link, "femur_r");
  const md::Scene loaded = md::loadScene(description, md::Skeleton::fromUrdfFile(kSmallHip.string()), packageResolver());
  ASSERT_EQ(loaded.muscles.at(0).insertion_path.size(), 1u);
  EXPECT_TRUE(loaded.muscles[0].insertion_path[0].point.isApprox(Eigen::Vector3d(0.04, 0, -0.015)));

  const std::string report = readText(out_ / md::kReportFileName);
  EXPECT_CONTAINS(report, "insertion: insertion site (command line) on `femur_r` at (0.0400, 0.0000, -0.0150) m, ");
}

TEST_F(ScenePreparationTest, SitesWithoutAnyAreSaidToHangFromTheNearestPoint) {
  md::prepareScene(request({goodMuscle()}));
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "Attachment sites: none given");
  EXPECT_EQ(readText(out_ / md::kSceneFileName).find("origin_path"), std::string::npos);
}

// The bundled gait2392 model, read as a model of the small hip's skeleton (its pelvis and femur_r bodies are the
// hip's links of those names): each point of the mapped OpenSim muscle is a site or a via point in its body's frame,
// or is left out saying why.
TEST_F(ScenePreparationTest, AnOpenSimModelGivesEachMappedMuscleItsPathPointsInTheirBodiesFrames) {
  md::ScenePreparationRequest asked = request({goodMuscle()});
  asked.osim.osim_file = kGait2392.string();
  asked.osim.muscles["spindle"] = "iliacus_r";
  std::string said;
  const md::ScenePreparation scene = md::prepareScene(asked, [&](const std::string& line) { said += line + "\n"; });
  ASSERT_TRUE(scene.muscles.at(0).prepared()) << scene.muscles[0].refusal;
  const md::TendonPaths& sites = scene.muscles[0].sites;
  EXPECT_EQ(sites.reference_muscles, std::vector<std::string>{"iliacus_r"});

  const md::OpenSimModel model = md::OpenSimModel::fromFile(kGait2392.string());
  md::CoordinateValues zero;
  for (const md::OpenSimCoordinate& coordinate : model.coordinates()) zero[coordinate.name] = 0.0;
  const std::vector<md::MusclePathPoint> points = model.activePathPoints("iliacus_r", zero);
  ASSERT_GE(points.size(), 3u);
  ASSERT_FALSE(sites.origin_path.empty());
  EXPECT_EQ(sites.origin_path.front().site.link, points.front().body);
  EXPECT_TRUE(sites.origin_path.front().site.point.isApprox(points.front().location_in_body));
  ASSERT_FALSE(sites.insertion_path.empty());
  EXPECT_EQ(sites.insertion_path.back().site.link, points.back().body);
  EXPECT_TRUE(sites.insertion_path.back().site.point.isApprox(points.back().location_in_body));
  const std::string source = sites.source();
  for (const md::MusclePathPoint& point : points) {
    const auto is_point = [&](const md::PreparedSite& site) { return site.label.rfind(point.name, 0) == 0; };
    const bool kept = std::any_of(sites.origin_path.begin(), sites.origin_path.end(), is_point) ||
                      std::any_of(sites.insertion_path.begin(), sites.insertion_path.end(), is_point);
    EXPECT_TRUE(kept || source.find(point.name + " (iliacus_r) left out") != std::string::npos) << point.name;
  }

  const md::SceneDescription description = md::loadSceneDescription((out_ / md::kSceneFileName).string());
  EXPECT_EQ(description.muscles.at(0).reference_muscles, std::vector<std::string>{"iliacus_r"});
  EXPECT_EQ(description.muscles[0].origin_path.size(), sites.origin_path.size());
  EXPECT_EQ(description.muscles[0].insertion_path.size(), sites.insertion_path.size());
  EXPECT_EQ(fs::weakly_canonical(md::resolveScenePath(description, description.reference_model.osim_file)),
            fs::weakly_canonical(kGait2392));
  // The small hip is not gait2392's skeleton: the report and the tool's output flag sites that lie far from their bone.
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "far from the bone");
  EXPECT_GT(sites.farFromBone(), 0);
  EXPECT_CONTAINS(said, "more than 10 mm from their bone");
}

TEST_F(ScenePreparationTest, AnOpenSimPointOnABodyWithoutABoneRefusesItsMuscleUntilTheBodyIsMapped) {
  md::ScenePreparationRequest asked = request({goodMuscle()});
  asked.osim.osim_file = kGait2392.string();
  asked.osim.muscles["spindle"] = "semiten_r";  // from the pelvis to the tibia, which the small hip lacks
  md::ScenePreparation scene = md::prepareScene(asked);
  EXPECT_FALSE(scene.muscles.at(0).prepared());
  EXPECT_CONTAINS(scene.muscles[0].refusal, "lies on body 'tibia_r'");
  EXPECT_CONTAINS(scene.muscles[0].refusal, "--osim-body tibia_r=LINK");

  asked.osim.bodies["tibia_r"] = "femur_r";
  scene = md::prepareScene(asked);
  ASSERT_TRUE(scene.muscles.at(0).prepared()) << scene.muscles[0].refusal;
  ASSERT_FALSE(scene.muscles[0].sites.insertion_path.empty());
  EXPECT_EQ(scene.muscles[0].sites.insertion_path.back().site.link, "femur_r");
}

TEST_F(ScenePreparationTest, OpenSimMapsThatNameWhatDoesNotExistAreRefusedBeforeAnyWork) {
  using md::testing::errorMessageOf;
  md::ScenePreparationRequest asked = request({goodMuscle()});
  asked.osim.osim_file = kGait2392.string();
  asked.osim.muscles["spindle"] = "no_such_muscle_r";
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::prepareScene(asked); }),
                  "has no muscle 'no_such_muscle_r'");
  asked.osim.muscles = {{"nobody", "iliacus_r"}};
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::prepareScene(asked); }),
                  "no muscle 'nobody' is given with --muscle");
  asked.osim.muscles.clear();
  asked.osim.bodies = {{"humerus", "pelvis"}};
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::prepareScene(asked); }), "has no body 'humerus'");
  asked.osim.bodies = {{"tibia_r", "shin"}};
  EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>([&] { md::prepareScene(asked); }),
                  "'shin' is not a link of the URDF");
  asked.osim.bodies.clear();
  asked.osim.osim_file = (raw_ / "missing.osim").string();
  EXPECT_CONTAINS(errorMessageOf<md::SceneError>([&] { md::prepareScene(asked); }), "missing.osim");
}

// The spindle pushed 6 mm up into the pelvis box: reported as given, and with the carve the node's pelvis is a copy
// the muscle no longer enters, while the file the URDF names stays as it was.
TEST_F(ScenePreparationTest, ARestOverlapIsCarvedOutOfTheBonesCopyWhenAskedAndTheMuscleStartsOutsideIt) {
  md::TriangleMesh raised = md::loadTriangleMesh((raw_ / "muscle_mm.stl").string());
  raised.vertices.row(2).array() += 6.0;  // millimetres
  md::saveTriangleMeshStl((raw_ / "raised_mm.stl").string(), raised);
  const md::MuscleSource muscle{"raised", (raw_ / "raised_mm.stl").string(), "pelvis", "femur_r"};
  const md::ScenePreparation reported = md::prepareScene(request({muscle}));
  ASSERT_TRUE(reported.muscles.at(0).prepared()) << reported.muscles[0].refusal;
  ASSERT_FALSE(reported.muscles[0].overlaps.empty());
  EXPECT_EQ(reported.muscles[0].overlaps[0].bone, "pelvis");
  EXPECT_NEAR(reported.muscles[0].overlaps[0].max_depth_m, 0.006, 0.001);
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "--rest-overlaps carve-bones");
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kSmallHip.string());
  md::PipelineSettings settings = md::nodeDefaultSettings().pipeline;
  settings.simulation.model.particles_per_fibre = 8;
  {
    // The node's startup line says how deep the deepest particle starts inside a bone.
    const md::Scene loaded =
        md::loadScene(md::loadSceneDescription((out_ / md::kSceneFileName).string()), skeleton, packageResolver());
    md::DeformationPipeline pipeline(loaded.muscle_descriptions, loaded.muscles, loaded.bones, settings);
    ASSERT_TRUE(pipeline.restPenetration().has_value());
    EXPECT_GT(pipeline.restPenetration()->depth_m, 0.003);
    EXPECT_EQ(pipeline.restPenetration()->bone, "pelvis");
    EXPECT_EQ(pipeline.restPenetration()->muscle, "raised");
    EXPECT_CONTAINS(pipeline.describe(), "mm inside bone 'pelvis' at rest (muscle 'raised')");
  }

  md::ScenePreparationRequest carve = request({muscle});
  carve.rest_overlaps = md::RestOverlapRule::carve_bones;
  const md::ScenePreparation carved = md::prepareScene(carve);
  ASSERT_TRUE(carved.muscles.at(0).prepared()) << carved.muscles[0].refusal;
  EXPECT_TRUE(carved.muscles[0].overlaps.empty()) << carved.muscles[0].overlaps[0].max_depth_m;
  ASSERT_EQ(carved.muscles[0].overlaps_before_carving.size(), 2u);  // the pelvis, and the marker its side touches
  const auto pelvis = std::find_if(carved.bone_meshes.begin(), carved.bone_meshes.end(),
                                   [](const md::BoneMeshCheck& b) { return b.link == "pelvis"; });
  ASSERT_NE(pelvis, carved.bone_meshes.end());
  EXPECT_EQ(pelvis->carved_by, "raised");
  EXPECT_EQ(pelvis->stand_in, "meshes/bones/pelvis_pelvis_mm_carved.stl");
  EXPECT_GT(pelvis->carve.max_distance_to_input_m, 0.006);  // the deepest carve: the overlap and the clearance
  EXPECT_LT(pelvis->carve.max_distance_to_input_m, 0.006 + md::kCarveClearanceM + 0.001);
  // The femur, which the muscle only touches, is the repaired copy of before, not carved.
  const auto femur = std::find_if(carved.bone_meshes.begin(), carved.bone_meshes.end(),
                                  [](const md::BoneMeshCheck& b) { return b.link == "femur_r"; });
  EXPECT_TRUE(femur->carved_by.empty());

  // The node's own path: the scene loads the carved copy, and no particle starts inside a bone.
  const md::Scene loaded =
      md::loadScene(md::loadSceneDescription((out_ / md::kSceneFileName).string()), skeleton, packageResolver());
  md::DeformationPipeline pipeline(loaded.muscle_descriptions, loaded.muscles, loaded.bones, settings);
  ASSERT_TRUE(pipeline.restPenetration().has_value());
  EXPECT_EQ(pipeline.restPenetration()->depth_m, 0.0) << pipeline.describe();
  EXPECT_CONTAINS(pipeline.describe(), "no particle centre inside a bone at rest");
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "copy carved by raised");
}

// ---------------------------------------------------------------------------------------------------------------
// Resolution per muscle for a surface error target

namespace {

// A small study: 4 and 8 particles per fibre against 16, at the small hip's hip flexion +/-0.5 rad.
md::ResolutionChoiceRequest smallStudy(double target_m) {
  md::ResolutionChoiceRequest study;
  study.surface_error_m = target_m;
  study.candidates = {4, 8};
  study.finest = 16;
  return study;
}

}  // namespace

TEST_F(ScenePreparationTest, EachMuscleGetsTheCoarsestResolutionWithinTheTargetAndTheSceneSaysIt) {
  md::ScenePreparationRequest asked = request({goodMuscle()});
  asked.resolution = smallStudy(0.5);  // half a metre: the coarsest candidate meets it
  const md::ScenePreparation generous = md::prepareScene(asked);
  ASSERT_TRUE(generous.resolution.has_value()) << generous.resolution_problem;
  EXPECT_EQ(generous.resolution->poses, (std::vector<std::string>{"hip_flexion_r +0.50 rad", "hip_flexion_r -0.50 rad"}));
  ASSERT_EQ(generous.resolution->muscles.size(), 1u);
  const md::MuscleResolution& spindle = generous.resolution->muscles[0];
  EXPECT_TRUE(spindle.met);
  EXPECT_EQ(spindle.chosen, 4);
  ASSERT_EQ(spindle.worst_rms_m.size(), 2u);
  EXPECT_GT(spindle.worst_rms_m[0], 0.0);  // the coarse model's skin differs from the finest one's
  EXPECT_GE(spindle.worst_max_m[0], spindle.worst_rms_m[0]);
  // The node reads the choice back from the scene.
  const md::SceneDescription description = md::loadSceneDescription((out_ / md::kSceneFileName).string());
  EXPECT_EQ(description.muscles.at(0).particles_per_fibre, 4);
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "## Resolution per muscle");

  // A target between the two candidates' errors picks the finer one; a target below both says it is not met.
  const double between = 0.5 * (spindle.worst_rms_m[0] + spindle.worst_rms_m[1]);
  ASSERT_LT(spindle.worst_rms_m[1], spindle.worst_rms_m[0]);  // finer is closer to the finest
  asked.resolution = smallStudy(between);
  const md::ScenePreparation middle = md::prepareScene(asked);
  ASSERT_TRUE(middle.resolution.has_value()) << middle.resolution_problem;
  EXPECT_EQ(middle.resolution->muscles.at(0).chosen, 8);
  EXPECT_TRUE(middle.resolution->muscles[0].met);
  asked.resolution = smallStudy(1e-9);
  const md::ScenePreparation strict = md::prepareScene(asked);
  ASSERT_TRUE(strict.resolution.has_value()) << strict.resolution_problem;
  EXPECT_FALSE(strict.resolution->muscles.at(0).met);
  EXPECT_EQ(strict.resolution->muscles[0].chosen, 8);
  EXPECT_CONTAINS(readText(out_ / md::kReportFileName), "target not met");
}

TEST(ResolutionChoice, RefusesATargetThatIsNotPositiveAndCandidatesThatDoNotIncreaseBelowTheFinest) {
  using md::testing::errorMessageOf;
  const md::Skeleton skeleton = md::Skeleton::fromUrdfFile(kSmallHip.string());
  for (const auto& [target, candidates, finest, expected] :
       std::vector<std::tuple<double, std::vector<int>, int, std::string>>{
           {0.0, {4, 8}, 16, "positive"}, {0.001, {8, 4}, 16, "increase"}, {0.001, {4, 16}, 16, "below the finest"},
           {0.001, {1, 4}, 16, "from 2"}}) {
    md::ResolutionChoiceRequest study;
    study.surface_error_m = target;
    study.candidates = candidates;
    study.finest = finest;
    EXPECT_CONTAINS(errorMessageOf<std::invalid_argument>(
                        [&] { md::chooseResolutions({}, {}, skeleton, "pelvis", md::nodeDefaultSettings(), study); }),
                    expected);
  }
}
