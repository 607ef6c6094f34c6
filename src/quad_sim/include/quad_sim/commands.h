// Commands accepted by the simulated vehicle's onboard attitude controller, as a Kumar-lab vehicle takes
// them.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <string>

namespace quad_sim {

// As kr_mav_msgs/SO3Command: the desired force in the world frame (its projection on the current body z axis
// is the collective thrust), the desired attitude, the desired body angular velocity, and the attitude gains
// used by the onboard controller (kR in N m/rad, kOm in N m s/rad; defaults are kr_mav_control's).
struct So3Command {
  Eigen::Vector3d force_world_N = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_des = Eigen::Quaterniond::Identity();
  Eigen::Vector3d w_body_des_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d kR = Eigen::Vector3d(1.5, 1.5, 1.0);
  Eigen::Vector3d kOm = Eigen::Vector3d(0.13, 0.13, 0.1);
  bool enable_motors = true;
};

// As kr_mav_msgs/TRPYCommand (the mavros-like interface the thesis used): collective thrust along the body z
// axis, desired roll/pitch/yaw (R = Rz(yaw) Ry(pitch) Rx(roll)), desired body rates and attitude gains.
struct TrpyCommand {
  double thrust_N = 0.0;
  double roll_rad = 0.0;
  double pitch_rad = 0.0;
  double yaw_rad = 0.0;
  Eigen::Vector3d w_body_des_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d kR = Eigen::Vector3d(1.5, 1.5, 1.0);
  Eigen::Vector3d kOm = Eigen::Vector3d(0.13, 0.13, 0.1);
  bool enable_motors = true;
};

enum class CommandStatusCode { kAccepted, kNonFinite, kInvalid };

// Result of handing a command to the simulator: kAccepted, or why it was rejected (the state is then
// untouched and the previous command stays in force).
struct CommandStatus {
  CommandStatusCode code = CommandStatusCode::kAccepted;
  std::string reason = "accepted";
  bool ok() const { return code == CommandStatusCode::kAccepted; }
};

const char* ToString(CommandStatusCode code);

// Validation shared by the simulator and the node: NaN/Inf anywhere, a zero quaternion, negative gains or
// negative thrust are rejected with a reason naming the field.
CommandStatus ValidateCommand(const So3Command& cmd);
CommandStatus ValidateCommand(const TrpyCommand& cmd);

}  // namespace quad_sim
