// quad_sim_node: the ROS plumbing of quad_sim::Simulator (odometry, depth, TF, world, voxel map, commands,
// sim/reset, keyed or not). Time: quad_sim::TimeKeeper; lockstep: quad_core::LockstepGate; messages:
// ros/conversions.h (docs/quad_sim.md). Private parameters, both required: ~config (sim.yaml), ~world_seed
// (int; -1: world.seed of the config). Topics are relative except /clock, /tf, /tf_static (docs/quad_sim.md).
#include "quad_core/lockstep_gate.h"
#include "quad_ros/vocabulary.h"
#include "quad_sim/simulator.h"
#include "quad_sim/time_keeper.h"
#include "ros/conversions.h"
#include "ros/mailbox.h"
#include "ros/params.h"
#include "ros/peer_graph.h"

#include <quad_msgs/FrameAck.h>
#include <ros/ros.h>

#include <condition_variable>
#include <memory>
#include <mutex>
#include <thread>
#include <variant>

namespace {

using quad_core::LockstepGate;
using quad_sim::WallNow;
using quad_sim::WallPoint;

using PendingCommand = std::variant<std::monostate, quad_sim::So3Command, quad_sim::TrpyCommand>;

class QuadSimNode {
 public:
  QuadSimNode(ros::NodeHandle nh, const quad_sim::SimConfig& config, uint64_t world_seed)
      : nh_(nh), config_(config), sim_(config), time_(config, WallNow()), gate_(config.lockstep.Gate()) {
    // The start-up barrier needs to know who is connected to the topics lockstep depends on, by node name.
    clock_pub_ = graph_.Advertise<rosgraph_msgs::Clock>(nh_, "/clock", 10);
    odom_pub_ = graph_.Advertise<nav_msgs::Odometry>(nh_, "odom", 100);
    depth_pub_ = graph_.Advertise<sensor_msgs::Image>(nh_, "camera/depth/image", 10);
    info_pub_ = graph_.Advertise<sensor_msgs::CameraInfo>(nh_, "camera/depth/camera_info", 10);
    // TF as tf2_ros's broadcasters publish it, tracked too: a consumer looking up the camera mount before its
    // /tf_static connection is up waits in sim time, which does not advance while it holds the frame.
    tf_pub_ = graph_.Advertise<tf2_msgs::TFMessage>(nh_, "/tf", 100);
    tf_static_pub_ = graph_.Advertise<tf2_msgs::TFMessage>(nh_, "/tf_static", 1, true);
    status_pub_ = nh_.advertise<quad_msgs::EpisodeStatus>("sim/status", 10, true);
    markers_pub_ = nh_.advertise<visualization_msgs::MarkerArray>("sim/world_markers", 1, true);
    voxel_pub_ = nh_.advertise<sensor_msgs::PointCloud2>("sim/voxel_map", 1, true);
    z_offset_pub_ = nh_.advertise<std_msgs::Float64>("sim/z_offset", 1, true);
    stats_pub_ = nh_.advertise<quad_msgs::SimStats>("sim/stats", 100);
    // Lockstep round trips are latency bound: disable Nagle's algorithm on every input.
    const ros::TransportHints hints = ros::TransportHints().tcpNoDelay();
    so3_sub_ = SubscribeCommand<quad_msgs::SO3Command>("so3_cmd", "SO3Command", hints);
    trpy_sub_ = SubscribeCommand<quad_msgs::TRPYCommand>("trpy_cmd", "TRPYCommand", hints);
    ack_sub_ = nh_.subscribe<quad_msgs::FrameAck>(
        "sim/frame_ack", 100,
        [this](const quad_msgs::FrameAck::ConstPtr& m) {
          std::lock_guard<std::mutex> lock(mu_);
          gate_.OnAck(m->consumer, m->stamp.toNSec());
          cv_.notify_all();
        },
        ros::VoidConstPtr(), hints);
    reset_srv_ = nh_.advertiseService("sim/reset", &QuadSimNode::OnReset, this);

    tf_static_pub_.publish(quad_sim_ros::CameraMountTf(config_.camera, Now()));
    quad_msgs::ResetEpisode::Request first;
    first.seed = world_seed;
    const quad_msgs::ResetEpisode::Response r = DoReset(first);
    if (!r.success) throw std::runtime_error("initial episode: " + r.message);
    // set_z_offset (thesis section 3.3): used for every position the node publishes.
    z_offset_m_ = sim_.MeasureZOffset();
    z_offset_pub_.publish(quad_sim_ros::ToFloat64(z_offset_m_));
    ROS_INFO(
        "quad_sim set_z_offset: spawn frame origin is %.4f m above the world ground (unit scale %.3g per m)",
        z_offset_m_, config_.spawn_frame.units_per_m);
  }

  // The simulation loop (runs in its own thread until shutdown).
  void Run() {
    WaitForLockstepPeers();
    time_.Anchor(WallNow());
    while (ros::ok()) {
      if (HandleReset()) continue;
      const ros::Time now = Now();
      const bool odom_due = sim_.OdometryDue();
      const bool depth_due = sim_.DepthDue();
      if (time_.ClockDue(odom_due, depth_due)) clock_pub_.publish(quad_sim_ros::ToClock(now));
      if (odom_due) {
        last_odom_ = quad_ros::ToOdometryMsg(sim_.Odometry(z_offset_m_, now.toSec()), now);
        odom_pub_.publish(last_odom_);
        ++odometry_count_;
        tf_pub_.publish(quad_sim_ros::ToTf(last_odom_));
        if (time_.WaitsForCommand()) AwaitGate(true, now);
      }
      if (depth_due) {
        // In lockstep the run statistics go out before every frame: a consumer holding a frame has the
        // timeout counts up to it (the evaluation's runner counts each episode's timeouts this way).
        if (time_.WaitsForFrames()) PublishStats();
        const sensor_msgs::Image img = quad_ros::ToImageMsg(sim_.RenderDepth(), now, ++frame_seq_);
        ++depth_frame_count_;
        depth_pub_.publish(img);
        info_pub_.publish(quad_ros::ToCameraInfo(sim_.camera_intrinsics(), img.header));
        if (time_.WaitsForFrames()) AwaitGate(false, now);
      }
      if (resets_.pending()) continue;  // a reset arrived during a wait: start the new episode instead
      ApplyPendingCommand();
      sim_.Step();
      time_.Stepped();
      PublishStatus(false);
      if (time_.StatsDue(WallNow())) {
        PublishStats();
        time_.MarkStats(WallNow());  // the next real-time factor is measured from here
      }
      if (const auto until = time_.PaceUntil(WallNow())) std::this_thread::sleep_until(WallPoint(*until));
    }
  }

 private:
  ros::Time Now() const { return quad_sim_ros::StampOf(time_.now_ns()); }

  template <typename Msg>
  ros::Subscriber SubscribeCommand(const std::string& topic, const char* type,
                                   const ros::TransportHints& hints) {
    const auto on_msg = [this, type](const typename Msg::ConstPtr& m) {
      const auto c = quad_sim_ros::FromMsg(*m);
      Accept(PendingCommand(c), quad_sim::ValidateCommand(c), m->header.stamp, type);
    };
    return nh_.subscribe<Msg>(topic, 10, on_msg, ros::VoidConstPtr(), hints);
  }

  void Accept(const PendingCommand& cmd, const quad_sim::CommandStatus& status, const ros::Time& stamp,
              const char* type) {
    std::lock_guard<std::mutex> lock(mu_);
    // Any current answer (even a rejected one) releases the lockstep wait for its control period.
    if (gate_.OnCommand(stamp.toNSec()) == LockstepGate::CommandVerdict::kStale) return;
    if (!status.ok()) {
      ++rejected_commands_;
      ROS_WARN_THROTTLE(1.0,
                        "quad_sim: rejected %s stamped %.3f: %s (state untouched, previous command kept)",
                        type, stamp.toSec(), status.reason.c_str());
    } else {
      pending_ = cmd;
    }
    cv_.notify_all();
  }

  void ApplyPendingCommand() {
    PendingCommand p;
    {
      std::lock_guard<std::mutex> lock(mu_);
      std::swap(p, pending_);
    }
    if (const auto* c = std::get_if<quad_sim::So3Command>(&p)) sim_.SetSo3Command(*c);
    if (const auto* c = std::get_if<quad_sim::TrpyCommand>(&p)) sim_.SetTrpyCommand(*c);
  }

  // Holds sim time until the gate releases the odometry (command) or frame (acks) stamped `stamp`, it times
  // out, a reset is requested or the node shuts down (waking at least every 100 ms to notice a shutdown).
  void AwaitGate(bool command, const ros::Time& stamp) {
    std::unique_lock<std::mutex> lock(mu_);
    command ? gate_.AwaitCommand(stamp.toNSec(), WallNow()) : gate_.AwaitFrame(stamp.toNSec(), WallNow());
    while (ros::ok() && !resets_.pending()) {
      const LockstepGate::Decision d = gate_.Poll(WallNow());
      if (d.action == LockstepGate::Action::kRelease) return;
      if (d.action == LockstepGate::Action::kTimeout) {
        ROS_WARN("quad_sim lockstep: %s", d.message.c_str());
        return;
      }
      if (d.action == LockstepGate::Action::kResend) {  // the episode's first odometry, unanswered
        odom_pub_.publish(last_odom_);
        ROS_INFO_THROTTLE(5.0,
                          "quad_sim lockstep: odometry %.3f, the episode's first, not answered yet: sent "
                          "again (%lu resent so far)",
                          stamp.toSec(), static_cast<unsigned long>(gate_.resends()));
        continue;
      }
      cv_.wait_until(lock, std::min(WallPoint(d.wake_at_s), WallPoint(WallNow() + 0.1)));
    }
    gate_.Abandon();  // a reset or a shutdown is not a timeout
  }

  // In lockstep, the first step of an episode waits until every lockstep participant is connected, so that
  // no message of the episode is lost to a connection still being set up (quad_core::CheckLockstepPeers).
  void WaitForLockstepPeers() {
    if (!time_.lockstep() || !gate_.needs_peers()) return;
    graph_.WaitUntilReady(
        gate_.Needs(odom_pub_.getTopic(), depth_pub_.getTopic(), info_pub_.getTopic()), ack_sub_.getTopic(),
        {so3_sub_.getTopic(), trpy_sub_.getTopic()},
        [this] { return static_cast<int>(so3_sub_.getNumPublishers() + trpy_sub_.getNumPublishers()); },
        [this] { return !resets_.pending(); });
  }

  void PublishStatus(bool force) {
    const quad_sim_ros::SimCounts n = Counts();
    if (!status_.Due(sim_.episode(), n.command_timeouts + n.ack_timeouts, sim_.step_count(), steps_per_s_,
                     force))
      return;
    status_pub_.publish(
        quad_sim_ros::ToEpisodeStatus(sim_, Now(), episode_start_, n.command_timeouts, n.ack_timeouts));
    if (sim_.episode().collision.collided && !collision_logged_) {
      collision_logged_ = true;
      ROS_WARN("quad_sim: %s", sim_.episode().reason.c_str());
    }
  }

  quad_sim_ros::SimCounts Counts() {
    quad_sim_ros::SimCounts n;
    n.real_time_factor = time_.RealTimeFactor(WallNow());
    n.odometry = odometry_count_;
    n.depth_frames = depth_frame_count_;
    std::lock_guard<std::mutex> lock(mu_);
    n.command_timeouts = gate_.command_timeouts();
    n.ack_timeouts = gate_.ack_timeouts();
    n.rejected_commands = rejected_commands_;
    return n;
  }

  // SimStats stamped now (sim time); the real-time factor since the last periodic one.
  void PublishStats() { stats_pub_.publish(quad_sim_ros::ToSimStats(sim_, Now(), Counts())); }

  void PublishWorld() {
    markers_pub_.publish(quad_sim_ros::WorldMarkers(sim_, Now()));
    const quad_sim::VoxelMap map = sim_.ComputeVoxelMap();
    voxel_pub_.publish(quad_sim_ros::ToCloud(map.OccupiedCenters(), Now()));
    if (!config_.octomap_file.empty()) {
      try {
        map.WriteOctomap(config_.octomap_file);
      } catch (const std::exception& e) {
        ROS_ERROR("quad_sim: %s", e.what());
      }
    }
    ROS_INFO("quad_sim: world with %zu boxes (seed %lu), voxel map %zu occupied voxels at %.2f m",
             sim_.world().boxes.size(), static_cast<unsigned long>(sim_.world().seed), map.NumOccupied(),
             map.resolution_m());
  }

  // ---- episode reset: the service thread hands the request to the simulation thread and waits ----
  bool OnReset(quad_msgs::ResetEpisode::Request& req, quad_msgs::ResetEpisode::Response& res) {
    const auto outcome = resets_.Post(
        req, [] { return ros::ok(); }, &res);
    if (outcome == Resets::Outcome::kBusy) {
      res.success = false;
      res.message = "another reset is in progress";
    }
    return outcome != Resets::Outcome::kStopped;
  }

  // Runs a pending reset in the simulation thread; true if one ran.
  bool HandleReset() {
    const auto res = resets_.Serve([this](const quad_msgs::ResetEpisode::Request& r) { return DoReset(r); });
    if (!res) return false;
    if (res->success) {
      WaitForLockstepPeers();
      time_.Anchor(WallNow());
    }
    return true;
  }

  quad_msgs::ResetEpisode::Response DoReset(const quad_msgs::ResetEpisode::Request& req) {
    quad_msgs::ResetEpisode::Response res;
    try {
      const quad_sim::EpisodeRequest request = quad_sim_ros::FromMsg(req);
      const quad_sim::EpisodeSetup e = quad_sim::ResolveEpisode(config_, request);
      quad_sim::TimeKeeper next = time_;  // keyed or not (issue 32); kept once the simulator accepts
      const std::optional<uint32_t> id = next.BeginEpisode(request);
      sim_.Reset(e.world, e.start_world_m, e.start_yaw_rad, e.goal_world_m, id);
      time_ = next;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("reset rejected: ") + e.what();
      ROS_ERROR("quad_sim: %s", res.message.c_str());
      return res;
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      episode_start_ = Now();
      pending_ = PendingCommand();
      gate_.BeginEpisode(episode_start_.toNSec());
    }
    odometry_count_ = depth_frame_count_ = 0;
    collision_logged_ = false;
    PublishWorld();
    PublishStatus(true);
    PublishStats();  // the counts at the episode's start (SimStats counts are for the whole run)
    res.success = true;
    res.episode_id = sim_.episode().episode_id;
    res.message = "episode " + std::to_string(res.episode_id) + " started with " +
                  std::to_string(sim_.world().boxes.size()) + " boxes";
    ROS_INFO("quad_sim: %s", res.message.c_str());
    return res;
  }

  ros::NodeHandle nh_;
  quad_sim::SimConfig config_;
  quad_sim::Simulator sim_;
  quad_sim::TimeKeeper time_;  // simulation thread only
  quad_sim_ros::PeerGraph graph_;
  ros::Publisher clock_pub_, odom_pub_, depth_pub_, info_pub_, tf_pub_, tf_static_pub_, status_pub_,
      markers_pub_, voxel_pub_, z_offset_pub_, stats_pub_;
  ros::Subscriber so3_sub_, trpy_sub_, ack_sub_;
  ros::ServiceServer reset_srv_;
  using Resets = quad_sim_ros::Mailbox<quad_msgs::ResetEpisode::Request, quad_msgs::ResetEpisode::Response>;
  Resets resets_{[this] {
    std::lock_guard<std::mutex> lock(mu_);  // no lost wake-up: a waiter holds mu_ from its check to its wait
    cv_.notify_all();
  }};

  // Shared with the subscriber/service threads (guarded by mu_).
  std::mutex mu_;
  std::condition_variable cv_;
  LockstepGate gate_;
  PendingCommand pending_;
  uint64_t rejected_commands_ = 0;

  // Simulation thread only.
  ros::Time episode_start_;  // written under mu_
  double z_offset_m_ = 0.0;
  uint32_t frame_seq_ = 0;
  uint64_t odometry_count_ = 0;
  uint64_t depth_frame_count_ = 0;
  nav_msgs::Odometry last_odom_;  // the last odometry published (resent by AwaitGate)
  bool collision_logged_ = false;
  quad_sim::StatusSchedule status_;
  const uint64_t steps_per_s_ = static_cast<uint64_t>(std::llround(1.0 / config_.physics_dt_s));
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "quad_sim");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  std::unique_ptr<QuadSimNode> node;
  try {
    const std::string config_path = quad_sim_ros::RequireParam<std::string>(pnh, "config");
    const int world_seed = quad_sim_ros::RequireParam<int>(pnh, "world_seed");
    const quad_sim::SimConfig config = quad_sim::LoadSimConfig(config_path);
    const uint64_t seed = world_seed >= 0 ? static_cast<uint64_t>(world_seed) : config.world_seed;
    ROS_INFO("quad_sim: config %s, time mode %s, world seed %lu", config_path.c_str(),
             quad_sim::ToString(config.time.mode), static_cast<unsigned long>(seed));
    node = std::make_unique<QuadSimNode>(nh, config, seed);
  } catch (const std::exception& e) {
    ROS_FATAL("quad_sim: %s", e.what());
    return 1;
  }
  ros::AsyncSpinner spinner(2);
  spinner.start();
  std::thread loop([&node] { node->Run(); });
  ros::waitForShutdown();
  loop.join();
  return 0;
}
