// kr_tracker_node: manages the hover, line and B-spline trackers and runs the SO(3) controller (thin ROS
// adapter over kr_tracker_core; topics and the lockstep protocol in docs/CONVENTIONS.md, behaviour in
// docs/kr_tracker.md).
//
// One SO3Command (and PositionCommand) per odometry message, stamped with the odometry's stamp, so the
// simulator's lockstep can wait for exactly that command. If odometry goes stale (older than
// node.odom_timeout_s in ROS time) a watchdog keeps publishing the safe hover command (weight-compensating
// thrust, level attitude, last yaw). The logic (trackers, controller, episode resets) is
// kr_tracker::TrackerManager; this file converts messages and maps goal events onto the action's goal
// handles; message conversion is src/ros/conversions.h. Both parameters are required (no defaults).
#include <actionlib/server/action_server.h>
#include <nav_msgs/Odometry.h>
#include <quad_core/vehicle_params.h>
#include <quad_msgs/EpisodeStatus.h>
#include <quad_msgs/Goto.h>
#include <quad_msgs/PositionCommand.h>
#include <quad_msgs/SO3Command.h>
#include <quad_msgs/SwitchTracker.h>
#include <quad_msgs/TrackBsplineAction.h>
#include <quad_ros/vocabulary.h>
#include <ros/ros.h>

#include <algorithm>
#include <map>
#include <stdexcept>
#include <string>

#include "../ros/conversions.h"
#include "kr_tracker/config.h"
#include "kr_tracker/tracker_manager.h"

namespace kr_tracker {
namespace {

using TrackServer = actionlib::ActionServer<quad_msgs::TrackBsplineAction>;
using GoalHandle = TrackServer::GoalHandle;

class TrackerNode {
 public:
  TrackerNode(ros::NodeHandle nh, ros::NodeHandle pnh)
      : nh_(nh),
        config_(LoadTrackerConfig(RequiredParam(pnh, "tracker_config"))),
        vehicle_(quad_core::LoadVehicleParams(RequiredParam(pnh, "vehicle_config"))),
        manager_(config_, vehicle_.mass_kg, vehicle_.gravity_mps2, vehicle_.MaxThrustN()),
        server_(nh, "tracker/track_bspline", false) {
    so3_pub_ = nh_.advertise<quad_msgs::SO3Command>("so3_cmd", 10);
    pos_pub_ = nh_.advertise<quad_msgs::PositionCommand>("position_cmd", 10);
    odom_sub_ = nh_.subscribe("odom", 10, &TrackerNode::OnOdom, this, ros::TransportHints().tcpNoDelay());
    // Episode resets (docs/kr_tracker.md): a new episode_id re-anchors the trackers on the new start pose.
    status_sub_ =
        nh_.subscribe("sim/status", 10, &TrackerNode::OnStatus, this, ros::TransportHints().tcpNoDelay());
    switch_srv_ = nh_.advertiseService("tracker/switch", &TrackerNode::OnSwitch, this);
    goto_srv_ = nh_.advertiseService("tracker/goto", &TrackerNode::OnGoto, this);
    server_.registerGoalCallback([this](GoalHandle gh) { OnGoal(gh); });
    server_.registerCancelCallback([this](GoalHandle gh) { OnCancel(gh); });
    server_.start();
    watchdog_ = nh_.createTimer(ros::Duration(1.0 / config_.watchdog_rate_hz),
                                [this](const ros::TimerEvent&) { OnWatchdog(); });
    ROS_INFO(
        "kr_tracker: mass %.3f kg, g %.3f m/s^2 (vehicle config), kx [%.2f %.2f %.2f], kv [%.2f %.2f %.2f], "
        "odometry jump limit %.2f m",
        vehicle_.mass_kg, vehicle_.gravity_mps2, config_.gains.kx.x(), config_.gains.kx.y(),
        config_.gains.kx.z(), config_.gains.kv.x(), config_.gains.kv.y(), config_.gains.kv.z(),
        config_.max_odom_jump_m);
  }

 private:
  static std::string RequiredParam(const ros::NodeHandle& pnh, const std::string& name) {
    std::string value;
    if (!pnh.getParam(name, value) || value.empty()) {
      throw std::runtime_error("kr_tracker_node: required parameter ~" + name + " (a YAML path) is not set");
    }
    return value;
  }

  void OnOdom(const nav_msgs::Odometry::ConstPtr& msg) {
    const quad_core::VehicleState state = quad_ros::ToVehicleState(*msg);
    const bool first = !manager_.have_odom();
    if (state.AllFinite() && !first && state.t_s <= manager_.last_state().t_s) {
      ROS_WARN_THROTTLE(1.0, "kr_tracker: odometry stamp did not advance (%.4f after %.4f)", state.t_s,
                        manager_.last_state().t_s);
    }
    const ControlStep step = manager_.OnOdometry(state);
    if (step.odometry_skipped) {
      ROS_WARN_THROTTLE(1.0, "kr_tracker: non-finite odometry skipped; holding the safe command");
      // Still answer this odometry stamp, so a lockstepped simulator does not stall.
      Publish(step.command, step.ref, msg->header.stamp);
      return;
    }
    // Receipt time, but never before the message's own stamp. Under sim time now() follows /clock, which
    // arrives on its own connection: before the first /clock it is zero, and on a loaded machine it can lag
    // the odometry by more than odom_timeout_s. Either would let the next watchdog tick (once /clock catches
    // up) call fresh odometry stale and publish a hold command stamped like the odometry, which a lockstepped
    // simulator could take instead of this one: a run that depends on the machine's load.
    last_odom_rx_ = std::max(ros::Time::now(), msg->header.stamp);
    if (stale_) ROS_INFO("kr_tracker: odometry is back");
    stale_ = false;
    if (first) {
      ROS_INFO("kr_tracker: first odometry at (%.2f, %.2f, %.2f); tracker '%s' active",
               state.p_world_body.x(), state.p_world_body.y(), state.p_world_body.z(),
               manager_.active_tracker().c_str());
    }
    if (!step.reanchored.empty()) {
      ROS_WARN("kr_tracker: %s: re-anchored at (%.2f, %.2f, %.2f), yaw %.2f; tracker '%s' active",
               step.reanchored.c_str(), state.p_world_body.x(), state.p_world_body.y(),
               state.p_world_body.z(), state.Yaw(), manager_.active_tracker().c_str());
    }
    if (step.status != ControlStatus::kOk) ROS_WARN_THROTTLE(1.0, "kr_tracker: %s", ToString(step.status));
    Publish(step.command, step.ref, msg->header.stamp);
    ProcessEvents();
    if (const auto id = manager_.bspline().running_goal(); id && state.t_s >= next_feedback_s_) {
      next_feedback_s_ = state.t_s + 1.0 / config_.feedback_rate_hz;
      const auto it = goals_.find(*id);
      if (it != goals_.end()) {
        quad_msgs::TrackBsplineFeedback fb;
        fb.remaining_time_s = manager_.bspline().RemainingTime(state.t_s);
        it->second.publishFeedback(fb);
      }
    }
  }

  void OnStatus(const quad_msgs::EpisodeStatus::ConstPtr& msg) {
    const ros::Time start = msg->sim_time.isZero() ? msg->header.stamp : msg->sim_time;
    // A keyed episode starts up to 1000 s of sim time after the previous one's last odometry (issue 32): its
    // odometry is due from its start, not late, so /clock's jump must not make the watchdog answer the new
    // episode's first odometry stamp with a hold command before this node has seen that odometry.
    if (manager_.episode_id() != msg->episode_id) last_odom_rx_ = std::max(last_odom_rx_, start);
    const std::string what = manager_.OnEpisodeStatus(msg->episode_id, start.toSec());
    if (!what.empty()) ROS_INFO("kr_tracker: %s", what.c_str());
    ProcessEvents();
  }

  void OnWatchdog() {
    if (!manager_.have_odom()) return;
    const ros::Time now = ros::Time::now();
    if (now.isZero()) return;  // no clock yet (sim time): nothing can be judged stale
    if ((now - last_odom_rx_).toSec() <= config_.odom_timeout_s) return;
    if (!stale_) {
      ROS_WARN("kr_tracker: odometry stale (%.3f s > %.3f s): holding the safe hover command",
               (now - last_odom_rx_).toSec(), config_.odom_timeout_s);
    }
    stale_ = true;
    const PositionReference& last = manager_.last_ref();
    Publish(manager_.safe_command(), PositionReference::Hold(last.p_world, last.yaw_rad), now);
  }

  void Publish(const So3Command& c, const PositionReference& ref, const ros::Time& stamp) {
    const quad_msgs::SO3Command m = ros_conv::ToSo3Command(c, stamp, manager_.last_state().Yaw());
    so3_pub_.publish(m);
    pos_pub_.publish(ros_conv::ToPositionCommand(ref, m.header, config_.gains));
  }

  bool OnSwitch(quad_msgs::SwitchTracker::Request& req, quad_msgs::SwitchTracker::Response& res) {
    const std::string before = manager_.active_tracker();
    bool deferred = false;
    const std::string why = manager_.Switch(req.tracker, &deferred);
    res.success = why.empty();
    if (!res.success) {
      res.message = why;
      ROS_WARN("kr_tracker: switch refused: %s", why.c_str());
    } else if (deferred) {
      res.message = "switch to " + req.tracker + " queued until the new episode's first odometry";
      ROS_INFO("kr_tracker: %s", res.message.c_str());
    } else {
      res.message = "active tracker: " + req.tracker;
      if (before != req.tracker)
        ROS_INFO("kr_tracker: switched from '%s' to '%s'", before.c_str(), req.tracker.c_str());
    }
    ProcessEvents();
    return true;
  }

  bool OnGoto(quad_msgs::Goto::Request& req, quad_msgs::Goto::Response& res) {
    bool deferred = false;
    const std::string why = manager_.Goto(Eigen::Vector3d(req.position.x, req.position.y, req.position.z),
                                          req.yaw, req.max_vel_mps, req.max_acc_mps2, &deferred);
    res.success = why.empty();
    if (!res.success) {
      res.message = why;
      ROS_WARN("kr_tracker: goto refused: %s", why.c_str());
    } else {
      res.message = deferred ? "goto queued until the new episode's first odometry, then flown from there"
                             : "flying to the goal with the line tracker";
    }
    ProcessEvents();
    return true;
  }

  void OnGoal(GoalHandle gh) {
    const auto goal = gh.getGoal();
    const uint64_t id = next_goal_id_++;
    const std::string why =
        manager_.AddGoal(id, ros_conv::ToGoalSpec(goal->bspline), ros::Time::now().toSec());
    if (!why.empty()) {
      quad_msgs::TrackBsplineResult r;
      r.success = false;
      r.reason = "rejected: " + why;
      ROS_WARN("kr_tracker: B-spline goal (traj_id %ld) rejected: %s",
               static_cast<long>(goal->bspline.traj_id), why.c_str());
      gh.setRejected(r, r.reason);
      return;
    }
    gh.setAccepted();
    goals_.emplace(id, gh);
    ProcessEvents();
  }

  void OnCancel(GoalHandle gh) {
    for (const auto& [id, handle] : goals_) {
      if (handle == gh) {
        manager_.Cancel(id);
        break;
      }
    }
    ProcessEvents();
  }

  // Maps the B-spline tracker's goal events onto the action's goal handles.
  void ProcessEvents() {
    for (const GoalEvent& e : manager_.TakeEvents()) {
      const auto it = goals_.find(e.goal_id);
      if (it == goals_.end()) continue;
      if (e.kind == GoalEventKind::kStarted) {
        ROS_DEBUG("kr_tracker: B-spline goal %lu started", static_cast<unsigned long>(e.goal_id));
        continue;
      }
      quad_msgs::TrackBsplineResult r;
      r.success = e.kind == GoalEventKind::kSucceeded;
      r.total_time_s = e.total_time_s;
      r.distance_travelled_m = e.distance_travelled_m;
      r.reason = e.reason;
      // Replacements happen at every replan: debug level; the other outcomes are worth a line.
      const bool routine = e.kind == GoalEventKind::kReplaced;
      ROS_LOG(routine ? ros::console::levels::Debug : ros::console::levels::Info, ROSCONSOLE_DEFAULT_NAME,
              "kr_tracker: B-spline goal %lu %s after %.2f s, %.2f m%s%s",
              static_cast<unsigned long>(e.goal_id), ToString(e.kind), e.total_time_s, e.distance_travelled_m,
              e.reason.empty() ? "" : ": ", e.reason.c_str());
      switch (e.kind) {
        case GoalEventKind::kSucceeded:
          it->second.setSucceeded(r, "");
          break;
        case GoalEventKind::kReplaced:
        case GoalEventKind::kCanceled:
          it->second.setCanceled(r, e.reason);
          break;
        default:
          it->second.setAborted(r, e.reason);
          break;
      }
      goals_.erase(it);
    }
  }

  ros::NodeHandle nh_;
  TrackerConfig config_;
  quad_core::VehicleParams vehicle_;
  TrackerManager manager_;
  TrackServer server_;
  std::map<uint64_t, GoalHandle> goals_;
  uint64_t next_goal_id_ = 1;
  ros::Publisher so3_pub_, pos_pub_;
  ros::Subscriber odom_sub_, status_sub_;
  ros::ServiceServer switch_srv_, goto_srv_;
  ros::Timer watchdog_;
  bool stale_ = false;
  ros::Time last_odom_rx_;
  double next_feedback_s_ = 0.0;
};

}  // namespace
}  // namespace kr_tracker

int main(int argc, char** argv) {
  ros::init(argc, argv, "kr_tracker");
  // The handles outlive the try block: when the last handle goes, roscpp shuts down and rosconsole with it,
  // and a start-up error (a missing parameter) would be printed nowhere.
  ros::NodeHandle nh, pnh("~");
  try {
    kr_tracker::TrackerNode node(nh, pnh);
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("kr_tracker: %s", e.what());
    return 1;
  }
  return 0;
}
