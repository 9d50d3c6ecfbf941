// SinglePoseSession: single poses as the node's ~deform_pose service solves them, on the small scene of the node tests
// (test/data/node: three spindles around a cylinder femur, with its URDF). The reply says whether the solve converged
// by the residual and why a warm start was refused; a request that cannot be served names what is wrong.
#include "muscle_deformation/core/pipeline/single_pose_session.hpp"
#include "muscle_deformation/core/scene/scene.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <string>

namespace md = muscle_deformation;

#ifndef MD_TEST_DATA_DIR
#define MD_TEST_DATA_DIR "test/data"
#endif
#ifndef MD_PACKAGE_DIR
#define MD_PACKAGE_DIR "."
#endif

namespace {

// The scene loaded once for every test of the file (a few hundred milliseconds).
struct NodeScene {
  md::SceneDescription description;
  md::Scene scene;
};

const NodeScene& nodeScene() {
  static const NodeScene loaded = [] {
    NodeScene node;
    node.description = md::loadSceneDescription(std::string(MD_TEST_DATA_DIR) + "/node/thigh.yaml");
    const md::Skeleton skeleton =
        md::Skeleton::fromUrdfFile(md::resolveScenePath(node.description, node.description.urdf_file));
    const md::UriResolver resolve =
        md::makeUriResolver({{"muscle_deformation", MD_PACKAGE_DIR}}, node.description.folder);
    node.scene = md::loadScene(node.description, skeleton, resolve);
    return node;
  }();
  return loaded;
}

md::PipelineSettings smallPipeline() {
  md::PipelineSettings settings;
  settings.simulation.model.particles_per_fibre = 8;
  settings.simulation.block_descent.tissue_relaxation_s = 0.0005;
  settings.skin_surfaces = false;
  settings.measure_fidelity = false;
  settings.threads = 1;
  return settings;
}

std::unique_ptr<md::SinglePoseSession> sessionOf(const md::SinglePoseSettings& settings) {
  const NodeScene& node = nodeScene();
  return std::make_unique<md::SinglePoseSession>(node.description, node.scene, std::vector<std::string>{"muscle_0"},
                                                 smallPipeline(), settings);
}

md::SinglePoseRequest requestAt(double hip_rad, const std::string& caller) {
  md::SinglePoseRequest request;
  request.link_poses = nodeScene().scene.skeleton.linkPoses({{"hip_flexion_r", hip_rad}});
  request.caller = caller;
  request.wants = {false, false};
  return request;
}

}  // namespace

TEST(SinglePoseSession, AColdSolveThatConvergesByTheResidualSaysSo) {
  md::SinglePoseSettings settings;  // block descent
  settings.rule = md::StoppingRule::force_residual;
  settings.max_iterations = 2000;
  settings.residual_tolerance = 1e-3;
  const auto session = sessionOf(settings);
  const md::SinglePoseReply reply = session->solve(requestAt(0.3, "a"));
  ASSERT_TRUE(reply.success) << reply.message;
  ASSERT_NE(reply.frame, nullptr);
  const md::SolveStats& solve = reply.frame->stats.solver;
  EXPECT_TRUE(solve.converged) << reply.message;
  EXPECT_GE(solve.residual, 0);
  EXPECT_LT(solve.residual, settings.residual_tolerance);
  EXPECT_FALSE(reply.frame->stats.warm_started);
  EXPECT_CONTAINS(reply.message, "cold start");
  EXPECT_CONTAINS(reply.message, "; converged: force residual ");
  EXPECT_CONTAINS(reply.message, " below 0.001");
  EXPECT_EQ(reply.message.find("not converged"), std::string::npos) << reply.message;
}

TEST(SinglePoseSession, ASolveTheIterationCapCutsShortSaysItHasNotConvergedByTheResidual) {
  md::SinglePoseSettings settings;
  settings.rule = md::StoppingRule::iterations;
  settings.residual_tolerance = 1e-6;
  const auto session = sessionOf(settings);
  md::SinglePoseRequest request = requestAt(0.3, "a");
  request.max_iterations = 1;  // a request's cap wins
  const md::SinglePoseReply reply = session->solve(request);
  ASSERT_TRUE(reply.success) << reply.message;
  const md::SolveStats& solve = reply.frame->stats.solver;
  EXPECT_EQ(solve.iterations, 1);
  EXPECT_FALSE(solve.converged);
  EXPECT_GT(solve.residual, settings.residual_tolerance);
  EXPECT_CONTAINS(reply.message, "in 1 iterations");
  EXPECT_CONTAINS(reply.message, "; not converged: force residual ");
  EXPECT_CONTAINS(reply.message, " above 1e-06");
}

TEST(SinglePoseSession, AWarmRequestFromAnotherCallerIsSolvedColdAndTheMessageSaysWhy) {
  const auto session = sessionOf(md::SinglePoseSettings{});
  ASSERT_TRUE(session->solve(requestAt(0.3, "first_client")).success);

  md::SinglePoseRequest other = requestAt(0.31, "second_client");
  other.warm_start = true;
  const md::SinglePoseReply refused = session->solve(other);
  ASSERT_TRUE(refused.success) << refused.message;
  EXPECT_FALSE(refused.frame->stats.warm_started);
  EXPECT_CONTAINS(refused.message, "cold start; warm start refused: ");
  EXPECT_CONTAINS(refused.message, "the previous call came from another client (first_client)");

  // The same caller's next warm request continues its own previous answer.
  md::SinglePoseRequest again = requestAt(0.32, "second_client");
  again.warm_start = true;
  const md::SinglePoseReply warm = session->solve(again);
  ASSERT_TRUE(warm.success) << warm.message;
  EXPECT_TRUE(warm.frame->stats.warm_started);
  EXPECT_CONTAINS(warm.message, "warm start from this client's previous call");
  EXPECT_EQ(warm.message.find("refused"), std::string::npos) << warm.message;
}

TEST(SinglePoseSession, AWarmRequestFromTooFarAwayIsSolvedColdAndTheMessageSaysHowFar) {
  md::SinglePoseSettings settings;
  settings.warm_max_rotation_rad = 0.5;
  const auto session = sessionOf(settings);
  ASSERT_TRUE(session->solve(requestAt(0.0, "a")).success);
  md::SinglePoseRequest far = requestAt(1.0, "a");
  far.warm_start = true;
  const md::SinglePoseReply reply = session->solve(far);
  ASSERT_TRUE(reply.success) << reply.message;
  EXPECT_FALSE(reply.frame->stats.warm_started);
  EXPECT_CONTAINS(reply.message, "warm start refused: a bone moved ");
  EXPECT_CONTAINS(reply.message, "service_warm_max_rotation_rad 0.5");
}

TEST(SinglePoseSession, AnUnknownMuscleIsRefusedNamingIt) {
  const auto session = sessionOf(md::SinglePoseSettings{});
  md::SinglePoseRequest request = requestAt(0.3, "a");
  request.muscles = {"muscle_1", "no_such_muscle"};
  const std::string message =
      md::testing::errorMessageOf<std::invalid_argument>([&] { session->solve(request); });
  EXPECT_CONTAINS(message, "no_such_muscle");
}

TEST(SinglePoseSession, ANegativeLimitInARequestIsRefusedNamingTheField) {
  const auto session = sessionOf(md::SinglePoseSettings{});
  md::SinglePoseRequest request = requestAt(0.3, "a");
  request.max_iterations = -1;
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>([&] { session->solve(request); }),
                  "max_iterations");
  request.max_iterations = 0;
  request.time_budget_ms = -5;
  EXPECT_CONTAINS(md::testing::errorMessageOf<std::invalid_argument>([&] { session->solve(request); }),
                  "time_budget_ms");
}
