// Collisions through Bullet, checked against the exact box geometry along simulated flights.
#include "quad_sim/collision.h"
#include "quad_sim/math_utils.h"
#include "quad_sim/simulator.h"

#include "test_util.h"

#include <gtest/gtest.h>

#include <cmath>

using quad_sim::OrientedBox;
using quad_sim::Simulator;
using quad_sim::World;

namespace {

OrientedBox Box(const Eigen::Vector3d& c, const Eigen::Vector3d& size, double yaw = 0.0) {
  OrientedBox b;
  b.center_world_m = c;
  b.size_m = size;
  b.q_world_box = quad_sim::QuatFromRpy(0, 0, yaw);
  return b;
}

// Position PD on the SO(3) interface (a stand-in for the tracker): flies towards p_ref at v_ref, yaw 0.
quad_sim::So3Command Follow(const Simulator& sim, const Eigen::Vector3d& p_ref,
                            const Eigen::Vector3d& v_ref) {
  const quad_core::VehicleParams& p = sim.config().vehicle;
  const quad_sim::DynamicsState& s = sim.state();
  const Eigen::Vector3d a = 6.0 * (p_ref - s.p_world_body) + 4.0 * (v_ref - s.v_world);
  quad_sim::So3Command c;
  c.force_world_N = p.mass_kg * (a + Eigen::Vector3d(0, 0, p.gravity_mps2));
  const Eigen::Vector3d z_b = c.force_world_N.normalized();
  const Eigen::Vector3d y_b = z_b.cross(Eigen::Vector3d::UnitX()).normalized();
  Eigen::Matrix3d R;
  R << y_b.cross(z_b), y_b, z_b;
  c.q_world_des = Eigen::Quaterniond(R);
  return c;
}

// Flies along +x at 2 m/s on the line (x, y0, 1.5) from x = 0 for `seconds`; returns the minimum exact
// clearance.
double FlyAlongX(Simulator* sim, double y0, double seconds, uint64_t* first_overlap_step) {
  double min_clearance = std::numeric_limits<double>::infinity();
  *first_overlap_step = 0;
  while (sim->time_s() < seconds && sim->episode().active) {
    if (sim->OdometryDue()) {
      const double x = std::min(2.0 * sim->time_s(), 12.0);
      sim->SetSo3Command(Follow(*sim, Eigen::Vector3d(x, y0, 1.5), Eigen::Vector3d(2.0, 0, 0)));
    }
    sim->Step();
    for (const OrientedBox& b : sim->world().boxes) {
      if (*first_overlap_step == 0 && quad_sim::BoxesOverlap(sim->VehicleBox(), b))
        *first_overlap_step = sim->step_count();
    }
    min_clearance = std::min(min_clearance, sim->ClearanceToObstacles());
  }
  return min_clearance;
}

}  // namespace

TEST(CollisionChecker, ReportsBoxAndGroundPenetrationOnly) {
  quad_sim::CollisionChecker checker(Eigen::Vector3d(0.25, 0.25, 0.25));
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(2, 0, 1), Eigen::Vector3d(1, 1, 1)));
  checker.SetWorld(world);
  const Eigen::Quaterniond level = Eigen::Quaterniond::Identity();
  EXPECT_TRUE(checker.Check(Eigen::Vector3d(0, 0, 1), level).empty());
  // 1 cm into the box's -x face.
  auto c = checker.Check(Eigen::Vector3d(1.5 - 0.125 + 0.01, 0, 1), level);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].box_index, 0);
  EXPECT_NEAR(c[0].penetration_m, 0.01, 1e-4);
  EXPECT_NEAR(c[0].point_world_m.x(), 1.5, 0.01);
  // 1 mm short of the face: nothing.
  EXPECT_TRUE(checker.Check(Eigen::Vector3d(1.5 - 0.125 - 0.001, 0, 1), level).empty());
  // Sunk 2 mm into the ground.
  c = checker.Check(Eigen::Vector3d(0, 0, 0.123), level);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].box_index, quad_sim::kHitGround);
  EXPECT_NEAR(c[0].penetration_m, 0.002, 1e-4);
}

TEST(Collision, FlyingIntoABoxIsReportedAtTheRightTimeAndPlace) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(1.0, 5.0, 3.0), Eigen::Vector3d(0.5, 0.5, 0.5)));  // off the path
  world.boxes.push_back(
      Box(Eigen::Vector3d(5.0, 0.0, 1.5), Eigen::Vector3d(1.0, 2.0, 3.0)));  // wall, face x = 4.5
  sim.Reset(world, Eigen::Vector3d(0, 0, 1.5), 0.0, Eigen::Vector3d(20, 0, 1.5));
  uint64_t first_overlap = 0;
  FlyAlongX(&sim, 0.0, 6.0, &first_overlap);
  const quad_sim::CollisionInfo& c = sim.collision();
  ASSERT_TRUE(c.collided);
  EXPECT_EQ(c.box_index, 1);
  // Reported at the first physics step whose pose overlaps the wall (exact geometry), i.e. within 1 ms.
  ASSERT_GT(first_overlap, 0u);
  EXPECT_NEAR(c.time_s, first_overlap * sim.config().physics_dt_s, 1e-9);
  // At the wall's face, in front of the vehicle.
  EXPECT_NEAR(c.point_world_m.x(), 4.5, 0.01);
  EXPECT_LT(std::abs(c.point_world_m.y()), 0.2);
  EXPECT_NEAR(c.point_world_m.z(), 1.5, 0.2);
  // Freeze policy: the episode ended and the vehicle stays where it hit.
  EXPECT_FALSE(sim.episode().active);
  EXPECT_EQ(sim.episode().outcome, quad_sim::EpisodeOutcome::kCollided);
  EXPECT_NE(sim.episode().reason.find("collision with box 1 at t="), std::string::npos)
      << sim.episode().reason;
  const Eigen::Vector3d frozen = sim.state().p_world_body;
  for (int i = 0; i < 100; ++i) sim.Step();
  EXPECT_EQ(sim.state().p_world_body, frozen);
}

TEST(Collision, GrazingPastAt5cmIsNotACollision) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  World world;
  // The wall's -y face is at y = 0.175: 5 cm from the vehicle box's side (half width 0.125) on the path y =
  // 0.
  world.boxes.push_back(Box(Eigen::Vector3d(5.0, 0.675, 1.5), Eigen::Vector3d(4.0, 1.0, 3.0)));
  sim.Reset(world, Eigen::Vector3d(0, 0, 1.5), 0.0, Eigen::Vector3d(20, 0, 1.5));
  uint64_t first_overlap = 0;
  const double min_clearance = FlyAlongX(&sim, 0.0, 6.0, &first_overlap);
  EXPECT_GT(sim.state().p_world_body.x(), 8.0);  // flew all the way past
  EXPECT_FALSE(sim.collision().collided) << sim.episode().reason;
  EXPECT_EQ(first_overlap, 0u);
  EXPECT_NEAR(min_clearance, 0.05, 0.005);
}

TEST(Collision, PassingOneCentimetreTooCloseIsACollision) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  World world;
  world.boxes.push_back(
      Box(Eigen::Vector3d(5.0, 0.615, 1.5), Eigen::Vector3d(4.0, 1.0, 3.0)));  // face y = 0.115
  sim.Reset(world, Eigen::Vector3d(0, 0, 1.5), 0.0, Eigen::Vector3d(20, 0, 1.5));
  uint64_t first_overlap = 0;
  FlyAlongX(&sim, 0.0, 6.0, &first_overlap);
  ASSERT_TRUE(sim.collision().collided);
  EXPECT_EQ(sim.collision().time_s, first_overlap * sim.config().physics_dt_s);
  EXPECT_NEAR(sim.collision().point_world_m.x(), 3.0, 0.02);  // the wall's corner edge at x = 3
}

TEST(Collision, ContinuePolicyRecordsAndFliesOn) {
  quad_sim::SimConfig cfg = quad_sim_test::DefaultSimConfig();
  cfg.collision_policy = quad_sim::CollisionPolicy::kContinue;
  Simulator sim(cfg);
  World world;
  world.boxes.push_back(Box(Eigen::Vector3d(3.0, 0.0, 1.5), Eigen::Vector3d(0.3, 2.0, 3.0)));
  world.boxes.push_back(Box(Eigen::Vector3d(6.0, 0.0, 1.5), Eigen::Vector3d(0.3, 2.0, 3.0)));
  sim.Reset(world, Eigen::Vector3d(0, 0, 1.5), 0.0, Eigen::Vector3d(20, 0, 1.5));
  uint64_t first_overlap = 0;
  FlyAlongX(&sim, 0.0, 6.0, &first_overlap);
  EXPECT_TRUE(sim.episode().active);
  EXPECT_EQ(sim.collision().box_index, 0);       // the first one hit
  EXPECT_EQ(sim.collision().num_collisions, 2);  // then the second
  EXPECT_GT(sim.state().p_world_body.x(), 8.0);
}

TEST(Collision, HardImpactOnTheGroundIsACollisionWithTheGround) {
  Simulator sim(quad_sim_test::DefaultSimConfig());
  sim.Reset(World(), Eigen::Vector3d(0, 0, 3.0), 0.0, Eigen::Vector3d(20, 0, 1.5));
  quad_sim::So3Command off;
  off.enable_motors = false;
  while (sim.time_s() < 2.0 && sim.episode().active) {
    if (sim.OdometryDue()) sim.SetSo3Command(off);
    sim.Step();
  }
  ASSERT_TRUE(sim.collision().collided);
  EXPECT_EQ(sim.collision().box_index, quad_sim::kCollisionGround);
  EXPECT_NEAR(sim.collision().point_world_m.z(), 0.0, 0.01);
  EXPECT_NE(sim.episode().reason.find("collision with the ground"), std::string::npos);
  // A 2.875 m drop from rest: about sqrt(2 h / g) = 0.77 s (the rotors spin down over ~50 ms first).
  EXPECT_GT(sim.collision().time_s, 0.76);
  EXPECT_LT(sim.collision().time_s, 0.9);
}
