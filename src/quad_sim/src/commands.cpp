#include "quad_sim/commands.h"

#include <cmath>

namespace quad_sim {

namespace {

CommandStatus Reject(CommandStatusCode code, const std::string& why) {
  CommandStatus s;
  s.code = code;
  s.reason = why;
  return s;
}

CommandStatus CheckGains(const Eigen::Vector3d& kR, const Eigen::Vector3d& kOm) {
  if (!kR.allFinite()) return Reject(CommandStatusCode::kNonFinite, "kR has a NaN/Inf element");
  if (!kOm.allFinite()) return Reject(CommandStatusCode::kNonFinite, "kOm has a NaN/Inf element");
  if ((kR.array() < 0.0).any()) return Reject(CommandStatusCode::kInvalid, "kR has a negative gain");
  if ((kOm.array() < 0.0).any()) return Reject(CommandStatusCode::kInvalid, "kOm has a negative gain");
  return CommandStatus();
}

}  // namespace

const char* ToString(CommandStatusCode code) {
  switch (code) {
    case CommandStatusCode::kAccepted:
      return "accepted";
    case CommandStatusCode::kNonFinite:
      return "rejected: non-finite value";
    case CommandStatusCode::kInvalid:
      return "rejected: invalid value";
  }
  return "unknown";
}

CommandStatus ValidateCommand(const So3Command& cmd) {
  if (!cmd.force_world_N.allFinite())
    return Reject(CommandStatusCode::kNonFinite, "force has a NaN/Inf element");
  if (!cmd.q_world_des.coeffs().allFinite()) {
    return Reject(CommandStatusCode::kNonFinite, "orientation has a NaN/Inf element");
  }
  if (!cmd.w_body_des_radps.allFinite()) {
    return Reject(CommandStatusCode::kNonFinite, "angular_velocity has a NaN/Inf element");
  }
  if (cmd.q_world_des.norm() < 1e-6) {
    return Reject(CommandStatusCode::kInvalid, "orientation is a zero quaternion");
  }
  return CheckGains(cmd.kR, cmd.kOm);
}

CommandStatus ValidateCommand(const TrpyCommand& cmd) {
  if (!std::isfinite(cmd.thrust_N)) return Reject(CommandStatusCode::kNonFinite, "thrust is NaN/Inf");
  if (!std::isfinite(cmd.roll_rad) || !std::isfinite(cmd.pitch_rad) || !std::isfinite(cmd.yaw_rad)) {
    return Reject(CommandStatusCode::kNonFinite, "roll/pitch/yaw has a NaN/Inf value");
  }
  if (!cmd.w_body_des_radps.allFinite()) {
    return Reject(CommandStatusCode::kNonFinite, "angular_velocity has a NaN/Inf element");
  }
  if (cmd.thrust_N < 0.0) return Reject(CommandStatusCode::kInvalid, "thrust is negative");
  return CheckGains(cmd.kR, cmd.kOm);
}

}  // namespace quad_sim
