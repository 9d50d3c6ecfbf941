// Specifications of scene preparation: from segmented surfaces with defects (in millimetres) and a URDF whose bone
// meshes are not all closed, to a scene directory the node loads as it is.
#include "muscle_deformation/preprocessing/scene_directory.hpp"
#include "muscle_deformation/preprocessing/scene_preparation.hpp"

#include "muscle_deformation/core/io/mesh_io.hpp"
#include "muscle_deformation/core/pipeline/deformation_pipeline.hpp"
#include "muscle_deformation/support/synthetic_scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

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
