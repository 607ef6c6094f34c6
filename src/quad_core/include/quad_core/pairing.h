// The frame/odometry pairing rule, the one place it is written (Python binds nothing here: its twin is
// quad_il.imitation.pairing, tested against the same cases).
//
// The simulator publishes the odometry of a control period before the depth frame rendered at its end, on
// another connection, so a frame can overtake its odometry. A frame stamped t pairs with the newest odometry
// stamped <= t; the odometry "covers" the frame once the newest one received is within one odometry period
// before t (stamp > t - period). A consumer waits until the frame is covered, so what it decides from does
// not depend on message timing.
#pragma once

namespace quad_core {

// Tolerances of the rule: sim time is an integer number of nanoseconds, stamps travel as doubles.
inline constexpr double kPairingCoverEps = 1e-6;
inline constexpr double kPairingStampEps = 1e-9;

// True once odometry stamped `newest_odom_stamp_s` covers a frame stamped `frame_stamp_s`.
inline bool OdometryCoversFrame(double newest_odom_stamp_s, double frame_stamp_s, double odom_period_s) {
  return newest_odom_stamp_s > frame_stamp_s - odom_period_s + kPairingCoverEps;
}

// True if odometry stamped `odom_stamp_s` may be paired with a frame stamped `frame_stamp_s` (not newer).
inline bool OdometryNotNewerThanFrame(double odom_stamp_s, double frame_stamp_s) {
  return odom_stamp_s <= frame_stamp_s + kPairingStampEps;
}

// The newest element of a time-ordered buffer (oldest first) not newer than the frame, or nullptr.
// `stamp_of(element)` returns its stamp in seconds.
template <typename Buffer, typename StampOf>
const typename Buffer::value_type* PairedOdometry(const Buffer& buffer, double frame_stamp_s,
                                                  StampOf stamp_of) {
  for (auto it = buffer.rbegin(); it != buffer.rend(); ++it) {
    if (OdometryNotNewerThanFrame(stamp_of(*it), frame_stamp_s)) return &*it;
  }
  return nullptr;
}

}  // namespace quad_core
