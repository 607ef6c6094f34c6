// A one-slot request/answer handoff between a ROS service thread and the simulation thread: the service
// callback posts a request and blocks until the simulation thread has served it between two steps (the
// simulator is never touched from two threads). ROS-free; header only.
#pragma once

#include <chrono>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>

namespace quad_sim_ros {

template <typename Req, typename Res>
class Mailbox {
 public:
  // on_post runs after a request was posted (the simulation thread's waits use it to wake up).
  explicit Mailbox(std::function<void()> on_post) : on_post_(std::move(on_post)) {}

  enum class Outcome { kServed, kBusy, kStopped };
  // Service thread: hands `req` over and waits (polling keep_waiting every 100 ms) for its answer. kBusy when
  // another request is still pending, kStopped when keep_waiting() turned false first.
  Outcome Post(const Req& req, const std::function<bool()>& keep_waiting, Res* answer) {
    auto job = std::make_shared<Job>();
    job->request = req;
    std::future<Res> fut = job->done.get_future();
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (job_) return Outcome::kBusy;
      job_ = job;
    }
    on_post_();
    while (keep_waiting() && fut.wait_for(std::chrono::milliseconds(100)) != std::future_status::ready) {
    }
    if (fut.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return Outcome::kStopped;
    *answer = fut.get();
    return Outcome::kServed;
  }

  bool pending() const {
    std::lock_guard<std::mutex> lock(mu_);
    return job_ != nullptr;
  }

  // Simulation thread: serves the pending request with `handle`, clears the slot, then answers; the answer
  // (nothing if no request was pending).
  std::optional<Res> Serve(const std::function<Res(const Req&)>& handle) {
    std::shared_ptr<Job> job;
    {
      std::lock_guard<std::mutex> lock(mu_);
      job = job_;
    }
    if (!job) return std::nullopt;
    const Res res = handle(job->request);
    {
      std::lock_guard<std::mutex> lock(mu_);
      job_.reset();
    }
    job->done.set_value(res);
    return res;
  }

 private:
  struct Job {
    Req request;
    std::promise<Res> done;
  };
  std::function<void()> on_post_;
  mutable std::mutex mu_;
  std::shared_ptr<Job> job_;
};

}  // namespace quad_sim_ros
