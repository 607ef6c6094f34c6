// Small SO(3) helpers used by the dynamics, the onboard attitude controller and the world generator.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cmath>

namespace quad_sim {

// Skew-symmetric matrix: Hat(a) * b = a x b.
inline Eigen::Matrix3d Hat(const Eigen::Vector3d& a) {
  Eigen::Matrix3d m;
  m << 0.0, -a.z(), a.y(), a.z(), 0.0, -a.x(), -a.y(), a.x(), 0.0;
  return m;
}

// Inverse of Hat for a skew-symmetric matrix.
inline Eigen::Vector3d Vee(const Eigen::Matrix3d& m) { return Eigen::Vector3d(m(2, 1), m(0, 2), m(1, 0)); }

// Rotation R = Rz(yaw) * Ry(pitch) * Rx(roll) (intrinsic Z-Y-X, as ROS's tf RPY).
inline Eigen::Quaterniond QuatFromRpy(double roll_rad, double pitch_rad, double yaw_rad) {
  return Eigen::Quaterniond(Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()) *
                            Eigen::AngleAxisd(pitch_rad, Eigen::Vector3d::UnitY()) *
                            Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitX()));
}

// Yaw of a rotation (heading of the body x axis projected on the world xy plane), in (-pi, pi].
inline double YawOf(const Eigen::Quaterniond& q) {
  const Eigen::Vector3d x = q * Eigen::Vector3d::UnitX();
  return std::atan2(x.y(), x.x());
}

// Angle between the body z axis and the world z axis (0 when level), radians.
inline double TiltOf(const Eigen::Quaterniond& q) {
  const double c = (q * Eigen::Vector3d::UnitZ()).z();
  return std::acos(std::max(-1.0, std::min(1.0, c)));
}

}  // namespace quad_sim
