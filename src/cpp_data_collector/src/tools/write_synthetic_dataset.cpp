// write_synthetic_dataset: writes deterministic synthetic plan records through the real DatasetWriter.
// Used by the Python tests (collector and learning stack) and by scripts/bench/collector.sh.
// Usage: write_synthetic_dataset --out DIR [options]   (--help lists them)
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cpp_data_collector/dataset_writer.h"
#include "cpp_data_collector/synthetic.h"

namespace cdc = cpp_data_collector;

namespace {

volatile sig_atomic_t g_stop_signal = 0;  // set by the signal handler only; read by the main loop
void OnSignal(int sig) { g_stop_signal = sig; }

constexpr char kUsage[] =
    "usage: write_synthetic_dataset --out DIR [options]\n"
    "Writes deterministic synthetic plan records (record i depends only on --seed and i) with "
    "DatasetWriter.\n"
    "  --out DIR                 dataset directory (must not hold a dataset)\n"
    "  --seed N                  generator seed (default 1)\n"
    "  --records N               records to submit (default 100; 0 writes an empty dataset)\n"
    "  --until-signal            keep submitting until SIGINT/SIGTERM (ignores --records)\n"
    "  --width W --height H      depth image size (default 96x72)\n"
    "  --records-per-episode N   (default 40)\n"
    "  --boxes N                 boxes per synthetic world (default 30)\n"
    "  --shard-size-mb X         shard rotation size in 10^6 bytes (default 64)\n"
    "  --queue-capacity N        writer queue slots (default 32)\n"
    "  --policy block|drop       full-queue policy (default block)\n"
    "  --max-ctrl-pts N          (default 128)\n"
    "  --max-yaw-pts N           (default 128)\n"
    "  --no-fsync                do not fsync completed shards\n"
    "  --commit TEXT             software commit for the manifest (default unknown)\n"
    "  --rate-hz X               submit at most X records per second of wall time (default 0 = no limit)\n"
    "  --distinct-images N       render only the first N depth images and reuse them (benchmarks; default "
    "0)\n"
    "  --progress-every N        print 'progress submitted=.. written=..' to stdout every N records (default "
    "0)\n"
    "  --timing-json PATH        write per-call Record() timing statistics (microseconds) as JSON\n"
    "  --pause-after N           after N records are written, print 'paused written=N' and wait for a "
    "signal\n"
    "                            without finalising (crash tests kill it there; SIGINT/SIGTERM still "
    "finalise)\n"
    "Exit status: 0 finalised (also after SIGINT/SIGTERM), 1 writer error, 2 bad arguments.\n";

struct Args {
  cdc::WriterConfig writer;
  cdc::SyntheticConfig synth;
  uint64_t records = 100;
  bool until_signal = false;
  double rate_hz = 0.0;
  uint32_t distinct_images = 0;
  uint64_t progress_every = 0;
  std::string timing_json;
  uint64_t pause_after = 0;
};

uint64_t ParseUint(const std::string& flag, const std::string& value) {
  try {
    size_t used = 0;
    if (!value.empty() && value[0] == '-') throw std::invalid_argument("negative");
    const unsigned long long v = std::stoull(value, &used);
    if (used != value.size()) throw std::invalid_argument("trailing");
    return v;
  } catch (const std::exception&) {
    throw std::invalid_argument(flag + " needs a non-negative integer, got '" + value + "'");
  }
}

double ParseDouble(const std::string& flag, const std::string& value) {
  try {
    size_t used = 0;
    const double v = std::stod(value, &used);
    if (used != value.size()) throw std::invalid_argument("trailing");
    return v;
  } catch (const std::exception&) {
    throw std::invalid_argument(flag + " needs a number, got '" + value + "'");
  }
}

Args ParseArgs(int argc, char** argv) {
  Args a;
  a.writer.shard_size_mb = 64.0;
  a.writer.image_width = a.synth.width;
  a.writer.image_height = a.synth.height;
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--help" || flag == "-h") {
      std::cout << kUsage;
      std::exit(0);
    }
    if (flag == "--no-fsync") {
      a.writer.fsync = false;
      continue;
    }
    if (flag == "--until-signal") {
      a.until_signal = true;
      continue;
    }
    if (i + 1 >= argc) throw std::invalid_argument(flag + " needs a value");
    const std::string v = argv[++i];
    if (flag == "--out") {
      a.writer.output_dir = v;
    } else if (flag == "--seed") {
      a.synth.seed = ParseUint(flag, v);
    } else if (flag == "--records") {
      a.records = ParseUint(flag, v);
    } else if (flag == "--width") {
      a.synth.width = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--height") {
      a.synth.height = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--records-per-episode") {
      a.synth.records_per_episode = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--boxes") {
      a.synth.boxes_per_world = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--shard-size-mb") {
      a.writer.shard_size_mb = ParseDouble(flag, v);
    } else if (flag == "--queue-capacity") {
      a.writer.queue_capacity = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--policy") {
      a.writer.full_queue_policy = cdc::ParseFullQueuePolicy(v);
    } else if (flag == "--max-ctrl-pts") {
      a.writer.max_ctrl_pts = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--max-yaw-pts") {
      a.writer.max_yaw_pts = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--commit") {
      a.writer.software_commit = v;
    } else if (flag == "--rate-hz") {
      a.rate_hz = ParseDouble(flag, v);
    } else if (flag == "--distinct-images") {
      a.distinct_images = static_cast<uint32_t>(ParseUint(flag, v));
    } else if (flag == "--progress-every") {
      a.progress_every = ParseUint(flag, v);
    } else if (flag == "--timing-json") {
      a.timing_json = v;
    } else if (flag == "--pause-after") {
      a.pause_after = ParseUint(flag, v);
    } else {
      throw std::invalid_argument("unknown option '" + flag + "'");
    }
  }
  if (a.writer.output_dir.empty()) throw std::invalid_argument("--out DIR is required");
  if (a.rate_hz < 0.0) throw std::invalid_argument("--rate-hz must be >= 0");
  a.writer.image_width = a.synth.width;
  a.writer.image_height = a.synth.height;
  return a;
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5));
  return v[i];
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  try {
    args = ParseArgs(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "write_synthetic_dataset: " << e.what() << "\n" << kUsage;
    return 2;
  }
  struct sigaction sa {};
  sa.sa_handler = OnSignal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);

  try {
    const cdc::SyntheticGenerator gen(args.synth);
    args.writer.camera_fx_px = gen.fx_px();
    args.writer.camera_fy_px = gen.fy_px();
    args.writer.camera_cx_px = gen.cx_px();
    args.writer.camera_cy_px = gen.cy_px();
    // The writer thread inherits a mask blocking SIGINT/SIGTERM, so the handler always runs on this thread
    // (which --pause-after's sigsuspend relies on).
    sigset_t stop_signals;
    sigemptyset(&stop_signals);
    sigaddset(&stop_signals, SIGINT);
    sigaddset(&stop_signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
    cdc::DatasetWriter writer(args.writer);
    pthread_sigmask(SIG_UNBLOCK, &stop_signals, nullptr);
    writer.SetRunInfo("generator", "write_synthetic_dataset");
    writer.SetRunInfo("synthetic_seed", std::to_string(args.synth.seed));
    writer.SetRunInfo("records_per_episode", std::to_string(args.synth.records_per_episode));

    std::vector<std::vector<float>> image_cache;
    for (uint32_t i = 0; i < args.distinct_images; ++i) {
      cdc::SyntheticRecord r;
      gen.Generate(i, &r);
      image_cache.push_back(r.depth_m);
    }
    std::vector<double> call_us;
    call_us.reserve(args.until_signal ? 100000 : std::min<uint64_t>(args.records, 10000000));
    cdc::SyntheticRecord rec;
    const auto start = std::chrono::steady_clock::now();
    uint64_t submitted = 0;
    for (uint64_t i = 0; args.until_signal || i < args.records; ++i) {
      if (g_stop_signal != 0) break;
      if (image_cache.empty()) {
        gen.Generate(i, &rec);
      } else {
        gen.Generate(i, &rec, cdc::DepthMode::kSkip);
        rec.depth_m = image_cache[i % image_cache.size()];
        rec.record.depth.data = rec.depth_m.data();
      }
      if (args.rate_hz > 0.0) {
        std::this_thread::sleep_until(start +
                                      std::chrono::duration<double>(static_cast<double>(i) / args.rate_hz));
      }
      const auto t0 = std::chrono::steady_clock::now();
      const cdc::RecordResult result = writer.Record(rec.record);
      const auto t1 = std::chrono::steady_clock::now();
      call_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
      ++submitted;
      if (result.status == cdc::RecordStatus::kRejectedInvalid) {
        std::cerr << "write_synthetic_dataset: record " << i << " rejected: " << result.reason << "\n";
      } else if (result.status == cdc::RecordStatus::kWriterFailed) {
        std::cerr << "write_synthetic_dataset: writer failed: " << result.reason << "\n";
        break;
      }
      if (args.pause_after > 0 && submitted == args.pause_after) {
        while (writer.stats().written + writer.stats().dropped < submitted && g_stop_signal == 0) {
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
        std::printf("paused written=%llu\n", static_cast<unsigned long long>(writer.stats().written));
        std::fflush(stdout);
        // Block the stop signals while testing the flag, then sigsuspend unblocks and waits atomically, so a
        // signal arriving between the test and the wait is not lost.
        sigset_t previous;
        pthread_sigmask(SIG_BLOCK, &stop_signals, &previous);
        while (g_stop_signal == 0) sigsuspend(&previous);
        pthread_sigmask(SIG_SETMASK, &previous, nullptr);
      }
      if (args.progress_every > 0 && submitted % args.progress_every == 0) {
        const cdc::WriterStats s = writer.stats();
        std::printf("progress submitted=%llu written=%llu dropped=%llu\n",
                    static_cast<unsigned long long>(submitted), static_cast<unsigned long long>(s.written),
                    static_cast<unsigned long long>(s.dropped));
        std::fflush(stdout);
      }
    }
    const cdc::FinalizeResult fin = writer.Finalize();
    const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (g_stop_signal != 0) {
      std::fprintf(stderr, "write_synthetic_dataset: interrupted by signal %d; dataset finalised\n",
                   static_cast<int>(g_stop_signal));
    }
    const cdc::WriterStats& s = fin.stats;
    std::printf(
        "done submitted=%llu written=%llu dropped=%llu rejected=%llu lost=%llu shards=%llu wall_s=%.3f\n",
        static_cast<unsigned long long>(s.submitted), static_cast<unsigned long long>(s.written),
        static_cast<unsigned long long>(s.dropped), static_cast<unsigned long long>(s.rejected),
        static_cast<unsigned long long>(s.lost), static_cast<unsigned long long>(s.shards_completed), wall_s);
    std::fflush(stdout);
    if (!args.timing_json.empty()) {
      std::ofstream out(args.timing_json);
      char buf[512];
      std::snprintf(
          buf, sizeof(buf),
          "{\"calls\": %zu, \"record_us_median\": %.3f, \"record_us_p90\": %.3f, \"record_us_p99\": %.3f, "
          "\"record_us_max\": %.3f, \"written\": %llu, \"dropped\": %llu, \"blocked_calls\": %llu, "
          "\"wall_s\": %.6f}\n",
          call_us.size(), Percentile(call_us, 0.5), Percentile(call_us, 0.9), Percentile(call_us, 0.99),
          call_us.empty() ? 0.0 : *std::max_element(call_us.begin(), call_us.end()),
          static_cast<unsigned long long>(s.written), static_cast<unsigned long long>(s.dropped),
          static_cast<unsigned long long>(s.blocked_calls), wall_s);
      out << buf;
      if (!out) {
        std::cerr << "write_synthetic_dataset: cannot write " << args.timing_json << "\n";
        return 1;
      }
    }
    if (!fin.ok) {
      std::cerr << "write_synthetic_dataset: writer error: " << fin.error << "\n";
      return 1;
    }
  } catch (const std::exception& e) {
    std::cerr << "write_synthetic_dataset: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
