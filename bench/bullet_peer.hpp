// The peer a robotics user would pick instead of our solver: Bullet's soft bodies (libbullet, zlib licence; a bench-only
// dependency), given our model's particles, springs and fixed particles, the fixed ones moved with their bones every
// frame, and each bone's surface mesh as a kinematic triangle-mesh collider.
//
// What Bullet is given: one soft body per muscle (our springs never join two muscles) whose nodes are the muscle's
// particles with their masses (0 for a fixed particle: Bullet leaves it where it is put), one link per spring with our
// rest length (tendons over via points get theirs again every pose, as in our model), Bullet's default material
// (linear stiffness 1: a position-based link has no spring constant) and configuration, except three settings our
// scale needs: no gravity (our model has none) and the collision margin of the soft bodies at our particles' median
// collision radius (Bullet's default is 0.25 m, a body the size of a thigh). The sparse distance field's voxel can be
// set at our scale too; measured on the bundled thigh13 muscles (2026-11-26), one frame with a voxel of one particle
// radius (1.5 mm) did not end within 80 s, and 20-26 s with Bullet's 0.25 m. A frame is one Bullet step of the frame interval with `position_iterations`
// link iterations (Bullet's default: 1). Muscle against muscle is left out: Bullet's soft-soft collision needs
// clusters, so the peer does less work per frame than our solver, not more.
#pragma once

#include "muscle_deformation/core/base/bone_transforms.hpp"
#include "muscle_deformation/core/model/mass_spring_system.hpp"
#include "muscle_deformation/core/model/rigid_pretransform.hpp"

#include <BulletSoftBody/btDefaultSoftBodySolver.h>
#include <BulletSoftBody/btSoftBody.h>
#include <BulletSoftBody/btSoftBodyRigidBodyCollisionConfiguration.h>
#include <BulletSoftBody/btSoftRigidDynamicsWorld.h>
#include <btBulletDynamicsCommon.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <memory>
#include <utility>
#include <vector>

namespace bench {

class BulletPeer {
 public:
  // `bone_colliders`: each bone's surface mesh as a collider (false: the particles pass through bones).
  // `damping`: Bullet's velocity damping kDP in [0, 1] (< 0: its default, 0).
  // `voxel_radii`: the sparse distance field's voxel in median particle radii (<= 0: Bullet's default, 0.25 m).
  BulletPeer(muscle_deformation::MassSpringSystem system, const std::vector<muscle_deformation::Bone>& bones,
             int position_iterations, bool bone_colliders = true, double damping = -1, double voxel_radii = 0.2)
      : system_(std::move(system)), state_(muscle_deformation::restState(system_)) {
    using namespace muscle_deformation;
    configuration_ = std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>();
    dispatcher_ = std::make_unique<btCollisionDispatcher>(configuration_.get());
    broadphase_ = std::make_unique<btDbvtBroadphase>();
    constraints_ = std::make_unique<btSequentialImpulseConstraintSolver>();
    soft_solver_ = std::make_unique<btDefaultSoftBodySolver>();
    world_ = std::make_unique<btSoftRigidDynamicsWorld>(dispatcher_.get(), broadphase_.get(), constraints_.get(),
                                                        configuration_.get(), soft_solver_.get());
    world_->setGravity(btVector3(0, 0, 0));
    btSoftBodyWorldInfo& info = world_->getWorldInfo();
    info.m_gravity.setZero();
    info.m_broadphase = broadphase_.get();
    info.m_dispatcher = dispatcher_.get();
    std::vector<double> radii;
    for (Eigen::Index i = 0; i < system_.radius.size(); ++i)
      if (system_.radius[i] > 0) radii.push_back(system_.radius[i]);
    std::nth_element(radii.begin(), radii.begin() + static_cast<long>(radii.size() / 2), radii.end());
    const double radius = radii.empty() ? 1e-3 : radii[radii.size() / 2];
    // Initialize() (the world's constructor ran it) resets the voxel to Bullet's default: set ours after it.
    info.m_sparsesdf.Initialize();
    if (voxel_radii > 0) {
      info.m_sparsesdf.setDefaultVoxelsz(static_cast<btScalar>(radius * voxel_radii));
      info.m_sparsesdf.Reset();
    }
    radius_ = radius;

    for (const Bone& bone : bone_colliders ? bones : std::vector<Bone>{}) {
      auto mesh = std::make_unique<btTriangleMesh>();
      const TriangleMesh& surface = bone.surface;
      for (Eigen::Index t = 0; t < surface.triangles.cols(); ++t) {
        const auto corner = [&](int k) {
          const Eigen::Vector3d v = surface.vertices.col(surface.triangles(k, t));
          return btVector3(static_cast<btScalar>(v.x()), static_cast<btScalar>(v.y()), static_cast<btScalar>(v.z()));
        };
        mesh->addTriangle(corner(0), corner(1), corner(2));
      }
      auto shape = std::make_unique<btBvhTriangleMeshShape>(mesh.get(), true);
      auto motion = std::make_unique<btDefaultMotionState>();
      btRigidBody::btRigidBodyConstructionInfo construction(0, motion.get(), shape.get());
      auto body = std::make_unique<btRigidBody>(construction);
      body->setCollisionFlags(body->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      body->setActivationState(DISABLE_DEACTIVATION);
      world_->addRigidBody(body.get());
      bone_meshes_.push_back(std::move(mesh));
      bone_shapes_.push_back(std::move(shape));
      bone_motions_.push_back(std::move(motion));
      bone_bodies_.push_back(std::move(body));
    }

    // One soft body per muscle; spring s is link link_of_[s].second of body link_of_[s].first.
    link_of_.assign(system_.springs.size(), {-1, -1});
    for (int m = 0; m < system_.muscleCount(); ++m) {
      const int begin = system_.muscle_begin[static_cast<std::size_t>(m)];
      const int end = system_.muscle_begin[static_cast<std::size_t>(m) + 1];
      std::vector<btVector3> x;
      std::vector<btScalar> mass;
      for (int i = begin; i < end; ++i) {
        x.push_back(toBullet(system_.rest_position.col(i)));
        mass.push_back(system_.is_fixed[static_cast<std::size_t>(i)] ? 0 : static_cast<btScalar>(system_.mass[i]));
      }
      auto body = std::make_unique<btSoftBody>(&info, end - begin, x.data(), mass.data());
      for (std::size_t s = 0; s < system_.springs.size(); ++s) {
        const int a = system_.springs.first[s], b = system_.springs.second[s];
        if (a < begin || a >= end) continue;
        body->appendLink(a - begin, b - begin);
        link_of_[s] = {m, body->m_links.size() - 1};
      }
      // Bullet takes rest lengths from the node positions when its constants are updated; ours are set after that,
      // and the pending update Bullet would otherwise run at its first step is cleared.
      body->updateConstants();
      body->m_cfg.piterations = position_iterations;
      if (damping >= 0) body->m_cfg.kDP = static_cast<btScalar>(damping);
      body->getCollisionShape()->setMargin(static_cast<btScalar>(radius));
      // The nodes' boxes were made with the default margin (0.25 m) and only grow when a node leaves its box: make
      // them our size.
      for (int n = 0; n < body->m_nodes.size(); ++n) {
        btSoftBody::Node& node = body->m_nodes[n];
        btDbvtVolume box = btDbvtVolume::FromCR(node.m_x, static_cast<btScalar>(radius));
        body->m_ndbvt.update(node.m_leaf, box);
      }
      world_->addSoftBody(body.get());
      muscle_bodies_.push_back(std::move(body));
    }
    setRestLengths();
    for (auto& body : muscle_bodies_) body->m_bUpdateRtCst = false;
  }

  BulletPeer(const BulletPeer&) = delete;
  BulletPeer& operator=(const BulletPeer&) = delete;
  // The world forgets its bodies before they go (it would touch them as it ends).
  ~BulletPeer() {
    for (auto& body : muscle_bodies_) world_->removeSoftBody(body.get());
    for (auto& body : bone_bodies_) world_->removeRigidBody(body.get());
  }

  // Places the particles (a converged frame) with the bones at `transforms`, at rest.
  void start(const Eigen::Matrix3Xd& position, const muscle_deformation::BoneTransforms& transforms) {
    placeBones(transforms);
    state_.position = position;
    for (int m = 0; m < system_.muscleCount(); ++m) {
      const int begin = system_.muscle_begin[static_cast<std::size_t>(m)];
      btSoftBody& body = *muscle_bodies_[static_cast<std::size_t>(m)];
      for (int n = 0; n < body.m_nodes.size(); ++n) {
        btSoftBody::Node& node = body.m_nodes[n];
        node.m_x = node.m_q = toBullet(position.col(begin + n));
        node.m_v.setZero();
      }
    }
  }

  // One frame: the bones to `transforms`, the fixed particles with them, one step of `interval_s`. Returns its wall
  // time (ms).
  double step(const muscle_deformation::BoneTransforms& transforms, double interval_s) {
    const auto begin_time = std::chrono::steady_clock::now();
    placeBones(transforms);
    if (muscle_deformation::updateTendonRestLengths(system_, transforms)) setRestLengths();
    muscle_deformation::moveAttachments(system_, transforms, state_);
    for (int m = 0; m < system_.muscleCount(); ++m) {
      const int begin = system_.muscle_begin[static_cast<std::size_t>(m)];
      btSoftBody& body = *muscle_bodies_[static_cast<std::size_t>(m)];
      for (int n = 0; n < body.m_nodes.size(); ++n) {
        if (!system_.is_fixed[static_cast<std::size_t>(begin + n)]) continue;
        // Bullet's step moves every node by its velocity (a node without mass included) before the links act; a
        // fixed node is sent to its bone's place that way.
        btSoftBody::Node& node = body.m_nodes[n];
        node.m_v = (toBullet(state_.position.col(begin + n)) - node.m_x) / static_cast<btScalar>(interval_s);
      }
    }
    world_->stepSimulation(static_cast<btScalar>(interval_s), 0);
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - begin_time).count();
  }

  double medianRadius() const { return radius_; }

  Eigen::Matrix3Xd positions() const {
    Eigen::Matrix3Xd out(3, system_.particleCount());
    for (int m = 0; m < system_.muscleCount(); ++m) {
      const int begin = system_.muscle_begin[static_cast<std::size_t>(m)];
      const btSoftBody& body = *muscle_bodies_[static_cast<std::size_t>(m)];
      for (int n = 0; n < body.m_nodes.size(); ++n) {
        const btVector3& x = body.m_nodes[n].m_x;
        out.col(begin + n) = Eigen::Vector3d(x.x(), x.y(), x.z());
      }
    }
    return out;
  }

 private:
  static btVector3 toBullet(const Eigen::Vector3d& v) {
    return btVector3(static_cast<btScalar>(v.x()), static_cast<btScalar>(v.y()), static_cast<btScalar>(v.z()));
  }

  void setRestLengths() {
    for (std::size_t s = 0; s < link_of_.size(); ++s) {
      btSoftBody::Link& link = muscle_bodies_[static_cast<std::size_t>(link_of_[s].first)]->m_links[link_of_[s].second];
      link.m_rl = static_cast<btScalar>(system_.springs.rest_length[static_cast<Eigen::Index>(s)]);
      link.m_c1 = link.m_rl * link.m_rl;
    }
  }

  void placeBones(const muscle_deformation::BoneTransforms& transforms) {
    for (std::size_t b = 0; b < bone_bodies_.size() && b < transforms.size(); ++b) {
      const Eigen::Isometry3d& t = transforms[b];
      const Eigen::Quaterniond q(t.rotation());
      btTransform placed(btQuaternion(static_cast<btScalar>(q.x()), static_cast<btScalar>(q.y()),
                                      static_cast<btScalar>(q.z()), static_cast<btScalar>(q.w())),
                         toBullet(t.translation()));
      bone_motions_[b]->setWorldTransform(placed);
      bone_bodies_[b]->setWorldTransform(placed);
    }
  }

  muscle_deformation::MassSpringSystem system_;
  muscle_deformation::ParticleState state_;
  double radius_ = 0;
  std::unique_ptr<btSoftBodyRigidBodyCollisionConfiguration> configuration_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<btDbvtBroadphase> broadphase_;
  std::unique_ptr<btSequentialImpulseConstraintSolver> constraints_;
  std::unique_ptr<btDefaultSoftBodySolver> soft_solver_;
  std::unique_ptr<btSoftRigidDynamicsWorld> world_;
  std::vector<std::unique_ptr<btTriangleMesh>> bone_meshes_;
  std::vector<std::unique_ptr<btBvhTriangleMeshShape>> bone_shapes_;
  std::vector<std::unique_ptr<btDefaultMotionState>> bone_motions_;
  std::vector<std::unique_ptr<btRigidBody>> bone_bodies_;
  std::vector<std::unique_ptr<btSoftBody>> muscle_bodies_;
  std::vector<std::pair<int, int>> link_of_;
};

}  // namespace bench
