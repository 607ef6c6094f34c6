// Start-up helper for lockstep peers (header only, no ROS dependency: works with any publisher that has
// getNumSubscribers(), e.g. ros::Publisher).
#pragma once

#include <chrono>
#include <thread>

namespace quad_core {

// Waits (wall time, at most timeout_s, polling every 10 ms) until `pub` has a connected subscriber; true if
// it has. A lockstep consumer calls this for its FrameAck publisher before subscribing to depth frames: the
// simulator steps on once any consumer is connected, and an acknowledgement sent before the simulator has
// connected to this publisher is lost, which stalls the simulator until its lockstep timeout.
template <typename Publisher>
bool WaitForSubscriber(const Publisher& pub, double timeout_s) {
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                             std::chrono::duration<double>(timeout_s));
  while (pub.getNumSubscribers() == 0) {
    if (std::chrono::steady_clock::now() >= deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return true;
}

}  // namespace quad_core
