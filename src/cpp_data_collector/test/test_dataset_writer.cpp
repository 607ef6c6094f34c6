#include <gtest/gtest.h>
#include <sys/resource.h>

#include <atomic>
#include <condition_variable>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <thread>

#include "cpp_data_collector/dataset_reader.h"
#include "cpp_data_collector/dataset_writer.h"
#include "cpp_data_collector/manifest.h"
#include "cpp_data_collector/synthetic.h"
#include "test_util.h"

namespace cdc = cpp_data_collector;
namespace fs = std::filesystem;

namespace {

// A latch the writer thread's before_write hook waits on, so tests control exactly when records are written.
class Gate {
 public:
  void Wait() {
    std::unique_lock<std::mutex> l(mu_);
    ++waiting_;
    cv_.notify_all();
    cv_.wait(l, [this] { return open_; });
  }
  void Open() {
    std::lock_guard<std::mutex> l(mu_);
    open_ = true;
    cv_.notify_all();
  }
  void WaitUntilWriterWaits() {
    std::unique_lock<std::mutex> l(mu_);
    cv_.wait(l, [this] { return waiting_ > 0; });
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool open_ = false;
  int waiting_ = 0;
};

void ExpectRecordEquals(const cdc::PlanRecord& in, const cdc::DecodedRecord& out, uint64_t seq) {
  const cdc::RecordHead& h = out.head;
  EXPECT_EQ(h.magic, cdc::kRecordMagic);
  EXPECT_EQ(h.seq, seq);
  EXPECT_EQ(h.episode_id, in.episode_id);
  EXPECT_EQ(h.world_seed, in.world_seed);
  EXPECT_EQ(h.sim_time_s, in.sim_time_s);
  EXPECT_EQ(h.depth_stamp_s, in.depth_stamp_s);
  EXPECT_EQ(h.odom_stamp_s, in.odom.stamp_s);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(h.p_world_body[k], in.odom.p_world_body[k]);
    EXPECT_EQ(h.v_world[k], in.odom.v_world[k]);
    EXPECT_EQ(h.w_body[k], in.odom.w_body[k]);
    EXPECT_EQ(h.goal_world[k], in.goal_world[k]);
  }
  for (int k = 0; k < 4; ++k) EXPECT_EQ(h.q_world_body[k], in.odom.q_world_body[k]);
  EXPECT_EQ(h.bspline_order, in.bspline.order);
  EXPECT_EQ(h.bspline_traj_id, in.bspline.traj_id);
  EXPECT_EQ(h.bspline_start_time_s, in.bspline.start_time_s);
  EXPECT_EQ(h.bspline_yaw_dt_s, in.bspline.yaw_dt_s);
  EXPECT_EQ(out.knots, in.bspline.knots);
  EXPECT_EQ(out.ctrl_pts_world, in.bspline.ctrl_pts_world);
  EXPECT_EQ(out.yaw_pts, in.bspline.yaw_pts);
  EXPECT_EQ(h.plan_status_code, in.status.code);
  EXPECT_EQ(out.plan_status_text(), std::string(in.status.text));
  EXPECT_EQ(h.t_map_update_ms, in.timings.map_update_ms);
  EXPECT_EQ(h.t_frontend_ms, in.timings.frontend_ms);
  EXPECT_EQ(h.t_optimization_ms, in.timings.optimization_ms);
  EXPECT_EQ(h.t_total_ms, in.timings.total_ms);
  ASSERT_EQ(out.depth_code.size(), static_cast<size_t>(in.depth.width) * in.depth.height);
  for (size_t i = 0; i < out.depth_code.size(); ++i) {
    ASSERT_EQ(out.depth_code[i], cdc::EncodeDepthMetres(in.depth.data[i])) << "pixel " << i;
  }
}

TEST(DatasetWriter, RoundTripsRecordsThroughRotatedShards) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(11));
  const uint64_t n = 23;
  uint32_t record_size = 0;
  {
    cdc::WriterConfig probe = config;
    cdc::LayoutParams p{config.image_width, config.image_height, config.max_ctrl_pts + cdc::kExtraKnotSlots,
                        config.max_ctrl_pts, config.max_yaw_pts};
    record_size = cdc::RecordLayout::Compute(p).record_size;
    // Room for exactly 5 records per shard.
    config.shard_size_mb = (cdc::kHeaderSize + 5.5 * record_size) / 1e6;
  }
  cdc::DatasetWriter writer(config);
  writer.SetRunInfo("sampling_seed", "99");
  cdc::SyntheticRecord rec;
  for (uint64_t i = 0; i < n; ++i) {
    gen.Generate(i, &rec);
    const cdc::RecordResult r = writer.Record(rec.record);
    ASSERT_TRUE(r.ok()) << r.reason;
    EXPECT_EQ(r.seq, i);
  }
  const cdc::FinalizeResult fin = writer.Finalize();
  ASSERT_TRUE(fin.ok) << fin.error;
  EXPECT_EQ(fin.stats.written, n);
  EXPECT_EQ(fin.stats.dropped, 0u);
  EXPECT_EQ(fin.stats.shards_completed, 5u);  // 5+5+5+5+3

  for (const auto& e : fs::directory_iterator(config.output_dir)) {
    EXPECT_EQ(e.path().string().find(".partial"), std::string::npos) << e.path();
  }
  const cdc::DatasetReader reader(config.output_dir);
  ASSERT_EQ(reader.shards().size(), 5u);
  EXPECT_EQ(reader.shards()[0].num_records(), 5u);
  EXPECT_EQ(reader.shards()[4].num_records(), 3u);
  EXPECT_EQ(reader.shards()[0].layout().record_size, record_size);
  EXPECT_EQ(reader.shards()[0].header().camera_fx_px, 0.0);
  uint64_t i = 0;
  for (const cdc::ShardReader& s : reader.shards()) {
    for (uint64_t k = 0; k < s.num_records(); ++k, ++i) {
      gen.Generate(i, &rec);
      ExpectRecordEquals(rec.record, s.Decode(k), i);
    }
  }
  EXPECT_EQ(i, n);
  const cdc::VerifyReport rep = reader.Verify();
  EXPECT_TRUE(rep.clean()) << (rep.errors.empty() ? rep.warnings[0] : rep.errors[0]);

  const cdc::Manifest& m = *reader.manifest();
  EXPECT_EQ(m.status, cdc::DatasetStatus::kComplete);
  EXPECT_EQ(m.counts.written, n);
  EXPECT_EQ(m.counts.submitted, n);
  EXPECT_EQ(m.software_commit, "test-commit");
  ASSERT_EQ(m.shards.size(), 5u);
  EXPECT_EQ(m.shards[1].first_seq, 5u);
  EXPECT_EQ(m.shards[1].last_seq, 9u);
  ASSERT_EQ(m.episodes.size(), 4u);  // 7 records per episode: 7+7+7+2
  EXPECT_EQ(m.episodes[3].records, 2u);
  ASSERT_EQ(m.run_info.size(), 1u);
  EXPECT_EQ(m.run_info[0].second, "99");
}

TEST(DatasetWriter, DropPolicyCountsEveryDropAndLeavesSeqGaps) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  config.queue_capacity = 2;
  config.full_queue_policy = cdc::FullQueuePolicy::kDrop;
  Gate gate;
  std::atomic<int> hook_calls{0};
  cdc::WriterHooks hooks;
  hooks.before_write = [&](uint64_t) {
    if (hook_calls++ == 0) gate.Wait();  // stall on the first record only
  };
  cdc::DatasetWriter writer(config, hooks);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(2));
  cdc::SyntheticRecord rec;
  // Slot A goes to the (stalled) writer thread, slot B waits in the queue: every later call finds no free
  // slot.
  for (uint64_t i = 0; i < 10; ++i) {
    gen.Generate(i, &rec);
    const cdc::RecordResult r = writer.Record(rec.record);
    EXPECT_EQ(r.seq, i);
    EXPECT_EQ(r.status, i < 2 ? cdc::RecordStatus::kQueued : cdc::RecordStatus::kDroppedQueueFull) << i;
    if (i == 0) gate.WaitUntilWriterWaits();
  }
  EXPECT_EQ(writer.stats().dropped, 8u);
  gate.Open();
  const cdc::FinalizeResult fin = writer.Finalize();
  ASSERT_TRUE(fin.ok);
  EXPECT_EQ(fin.stats.written, 2u);
  EXPECT_EQ(fin.stats.dropped, 8u);
  EXPECT_EQ(fin.stats.submitted, 10u);
  EXPECT_EQ(fin.stats.queue_high_water, 2u);
  const cdc::Manifest m = cdc::ReadManifest(tmp / "ds/manifest.yaml");
  EXPECT_EQ(m.counts.dropped, 8u);
  EXPECT_EQ(m.dropped_seqs, (std::vector<uint64_t>{2, 3, 4, 5, 6, 7, 8, 9}));
  const cdc::DatasetReader reader(config.output_dir);
  EXPECT_EQ(reader.num_records(), 2u);
  EXPECT_EQ(reader.shards()[0].Decode(1).head.seq, 1u);
}

TEST(DatasetWriter, BlockPolicyWaitsForAFreeSlotAndLosesNothing) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  config.queue_capacity = 1;
  Gate gate;
  std::atomic<int> hook_calls{0};
  cdc::WriterHooks hooks;
  hooks.before_write = [&](uint64_t) {
    if (hook_calls++ == 0) gate.Wait();
  };
  cdc::DatasetWriter writer(config, hooks);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(3));
  cdc::SyntheticRecord rec0;
  gen.Generate(0, &rec0);
  ASSERT_TRUE(writer.Record(rec0.record).ok());
  gate.WaitUntilWriterWaits();
  std::atomic<bool> returned{false};
  cdc::RecordResult second;
  std::thread caller([&] {
    cdc::SyntheticRecord rec1;
    gen.Generate(1, &rec1);
    second = writer.Record(rec1.record);
    returned = true;
  });
  // The call is blocked once it has been counted as blocked: it cannot return before the gate opens, because
  // the only slot is held by the stalled writer.
  while (writer.stats().blocked_calls == 0) std::this_thread::yield();
  EXPECT_FALSE(returned.load());
  gate.Open();
  caller.join();
  EXPECT_EQ(second.status, cdc::RecordStatus::kQueued);
  EXPECT_EQ(second.seq, 1u);
  const cdc::FinalizeResult fin = writer.Finalize();
  EXPECT_EQ(fin.stats.written, 2u);
  EXPECT_EQ(fin.stats.dropped, 0u);
  EXPECT_EQ(fin.stats.blocked_calls, 1u);
}

cdc::RecordResult RecordModified(cdc::DatasetWriter* writer,
                                 const std::function<void(cdc::PlanRecord*)>& edit) {
  static const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(4));
  cdc::SyntheticRecord rec;
  gen.Generate(0, &rec);
  edit(&rec.record);
  return writer->Record(rec.record);
}

void ExpectRejected(cdc::DatasetWriter* writer, const std::function<void(cdc::PlanRecord*)>& edit,
                    const std::string& needle) {
  const cdc::RecordResult r = RecordModified(writer, edit);
  EXPECT_EQ(r.status, cdc::RecordStatus::kRejectedInvalid);
  EXPECT_NE(r.reason.find(needle), std::string::npos) << r.reason;
}

TEST(DatasetWriter, RejectsInvalidRecordsWithAReasonAndCountsThem) {
  cdc_test::TempDir tmp;
  cdc::DatasetWriter writer(cdc_test::SmallConfig(tmp / "ds"));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->odom.p_world_body[1] = nan; }, "odometry has a non-finite");
  ExpectRejected(
      &writer,
      [&](cdc::PlanRecord* r) {
        r->odom.q_world_body = {0, 0, 0, 2};
      },
      "quaternion has norm 2");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->depth.width = 31; }, "depth image is 31x24");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->depth.data = nullptr; }, "no data");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->depth.row_stride = 31; },
      "row stride 31 is shorter than a row of 32");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->goal_world[2] = nan; }, "goal");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->bspline.ctrl_pts_world[2][0] = nan; }, "control point");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->bspline.knots.pop_back(); }, "expected control points + order");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { std::swap(r->bspline.knots[4], r->bspline.knots[5]); },
      "knots decrease at index 5");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->bspline.order = 9; }, "order 9 is outside [1, 7]");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->bspline.yaw_dt_s = 0.0; }, "yaw_dt_s");
  ExpectRejected(
      &writer, [&](cdc::PlanRecord* r) { r->timings.total_ms = nan; }, "timings");
  ExpectRejected(
      &writer,
      [&](cdc::PlanRecord* r) {
        r->bspline.ctrl_pts_world.resize(41, {0, 0, 0});
        r->bspline.knots.resize(45);
        for (size_t i = 0; i < 45; ++i) r->bspline.knots[i] = 0.1 * i;
      },
      "41 control points, more than max_ctrl_pts 40");
  // NaN depth pixels are REP 118 "invalid", not an error.
  const cdc::RecordResult ok = RecordModified(&writer, [&](cdc::PlanRecord* r) {
    const_cast<float*>(r->depth.data)[0] = std::numeric_limits<float>::quiet_NaN();
  });
  EXPECT_TRUE(ok.ok()) << ok.reason;
  EXPECT_EQ(ok.seq, 0u);  // rejections take no seq
  const cdc::FinalizeResult fin = writer.Finalize();
  EXPECT_EQ(fin.stats.rejected, 13u);
  EXPECT_EQ(fin.stats.written, 1u);
}

TEST(DatasetWriter, TruncatesStatusTextAtAUtf8Boundary) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  std::string text(45, 'a');
  text += "\xC3\xA9\xC3\xA9";  // two 2-byte characters: the second does not fit in 47 bytes
  {
    cdc::DatasetWriter writer(config);
    ASSERT_TRUE(RecordModified(&writer, [&](cdc::PlanRecord* r) { r->status.text = text; }).ok());
  }  // the destructor finalises
  const cdc::DatasetReader reader(config.output_dir);
  EXPECT_EQ(reader.manifest()->status, cdc::DatasetStatus::kComplete);
  EXPECT_EQ(reader.shards()[0].Decode(0).plan_status_text(), text.substr(0, 47));
}

TEST(DatasetWriter, CopiesStridedDepthRows) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds", 5, 3);
  std::vector<float> padded(8 * 3, -7.0f);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 5; ++c) padded[r * 8 + c] = 1.0f + r + 0.001f * c;
  }
  cdc::DatasetWriter writer(config);
  const cdc::RecordResult res = RecordModified(&writer, [&](cdc::PlanRecord* r) {
    r->depth.data = padded.data();
    r->depth.width = 5;
    r->depth.height = 3;
    r->depth.row_stride = 8;
  });
  ASSERT_TRUE(res.ok()) << res.reason;
  writer.Finalize();
  const cdc::DecodedRecord d = cdc::DatasetReader(config.output_dir).shards()[0].Decode(0);
  EXPECT_EQ(d.depth_code, (std::vector<uint16_t>{1000, 1001, 1002, 1003, 1004, 2000, 2001, 2002, 2003, 2004,
                                                 3000, 3001, 3002, 3003, 3004}));
}

TEST(DatasetWriter, RefusesADirectoryThatHoldsADataset) {
  cdc_test::TempDir tmp;
  { cdc::DatasetWriter writer(cdc_test::SmallConfig(tmp / "ds")); }
  try {
    cdc::DatasetWriter again(cdc_test::SmallConfig(tmp / "ds"));
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("already holds a dataset (found manifest.yaml)"), std::string::npos)
        << e.what();
  }
}

TEST(DatasetWriter, AnEmptyRunLeavesACompleteManifestAndNoShards) {
  cdc_test::TempDir tmp;
  cdc::DatasetWriter writer(cdc_test::SmallConfig(tmp / "ds"));
  EXPECT_TRUE(writer.Finalize().ok);
  EXPECT_EQ(writer.Record(cdc::PlanRecord{}).status, cdc::RecordStatus::kRejectedInvalid);
  const cdc::DatasetReader reader(tmp / "ds");
  EXPECT_TRUE(reader.shards().empty());
  EXPECT_EQ(reader.manifest()->status, cdc::DatasetStatus::kComplete);
  const cdc::VerifyReport rep = reader.Verify();
  ASSERT_EQ(rep.warnings.size(), 1u);
  EXPECT_EQ(rep.warnings[0], "dataset holds no records");
}

TEST(DatasetWriter, RecordAfterFinalizeIsRefused) {
  cdc_test::TempDir tmp;
  cdc::DatasetWriter writer(cdc_test::SmallConfig(tmp / "ds"));
  writer.Finalize();
  EXPECT_TRUE(writer.Finalize().ok);  // idempotent
  EXPECT_EQ(RecordModified(&writer, [](cdc::PlanRecord*) {}).status, cdc::RecordStatus::kWriterClosed);
}

TEST(DatasetWriter, ConstructorRejectsBadConfigAndUnusableDirectories) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig bad = cdc_test::SmallConfig(tmp / "ds");
  bad.queue_capacity = 0;
  EXPECT_THROW(cdc::DatasetWriter w(bad), std::invalid_argument);
  cdc_test::WriteBytes(tmp / "file", {1, 2, 3});
  try {
    cdc::DatasetWriter w(cdc_test::SmallConfig(tmp / "file/ds"));
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot create output directory"), std::string::npos) << e.what();
  }
}

TEST(DatasetWriter, AnIoErrorStopsWritingAndIsReportedNotHidden) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  config.shard_size_mb = 1e-6;  // one record per shard: the second record opens a new shard file
  cdc::WriterHooks hooks;
  hooks.before_write = [&](uint64_t seq) {
    if (seq == 1) fs::remove_all(config.output_dir);  // the disk "goes away" under the writer
  };
  cdc::DatasetWriter writer(config, hooks);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(6));
  cdc::SyntheticRecord rec;
  gen.Generate(0, &rec);
  ASSERT_TRUE(writer.Record(rec.record).ok());
  ASSERT_TRUE(writer.Record(rec.record).ok());
  while (!writer.stats().failed) std::this_thread::yield();
  const cdc::RecordResult after = writer.Record(rec.record);
  EXPECT_EQ(after.status, cdc::RecordStatus::kWriterFailed);
  EXPECT_NE(after.reason.find("cannot create"), std::string::npos) << after.reason;
  const cdc::FinalizeResult fin = writer.Finalize();
  EXPECT_FALSE(fin.ok);
  EXPECT_NE(fin.error.find("shard_000001.qdr.partial"), std::string::npos) << fin.error;
  EXPECT_EQ(fin.stats.written, 1u);
  EXPECT_EQ(fin.stats.lost, 2u);  // the record being written and the one refused afterwards
}

TEST(DatasetWriter, SeveralCallerThreadsGetUniqueSeqsAndEverythingIsWritten) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  config.queue_capacity = 3;
  cdc::DatasetWriter writer(config);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(5));
  std::vector<std::thread> threads;
  for (int t = 0; t < 3; ++t) {
    threads.emplace_back([&, t] {
      cdc::SyntheticRecord rec;
      for (int i = 0; i < 20; ++i) {
        gen.Generate(static_cast<uint64_t>(t * 20 + i), &rec);
        EXPECT_TRUE(writer.Record(rec.record).ok());
      }
    });
  }
  for (auto& th : threads) th.join();
  EXPECT_EQ(writer.Finalize().stats.written, 60u);
  const cdc::DatasetReader reader(config.output_dir);
  std::vector<bool> seen(60, false);
  for (uint64_t k = 0; k < reader.shards()[0].num_records(); ++k) {
    const uint64_t seq = reader.shards()[0].Decode(k).head.seq;
    ASSERT_LT(seq, 60u);
    EXPECT_FALSE(seen[seq]);
    seen[seq] = true;
  }
  EXPECT_EQ(std::count(seen.begin(), seen.end(), true), 60);
}

}  // namespace

// Issue 30, fault table "disk full while a shard is written". RLIMIT_FSIZE stands in for a full disk: once
// the current file would grow past the limit, write(2) writes what fits and then fails with EFBIG (SIGXFSZ is
// ignored, as a process without a handler for it would otherwise be killed). The limit is lowered by the
// writer thread itself just before a record of the second shard, so that the first shard completes and the
// second one fails half-way through a record.
class FileSizeLimit {
 public:
  FileSizeLimit() {
    old_handler_ = std::signal(SIGXFSZ, SIG_IGN);
    getrlimit(RLIMIT_FSIZE, &old_);
  }
  ~FileSizeLimit() {
    setrlimit(RLIMIT_FSIZE, &old_);
    std::signal(SIGXFSZ, old_handler_);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;
  bool Lower(uint64_t bytes) const {
    rlimit lim = old_;
    lim.rlim_cur = static_cast<rlim_t>(bytes);
    return setrlimit(RLIMIT_FSIZE, &lim) == 0;
  }
  void Restore() const { setrlimit(RLIMIT_FSIZE, &old_); }

 private:
  rlimit old_{};
  void (*old_handler_)(int) = SIG_DFL;
};

TEST(DatasetWriter, DiskFullKeepsCompletedShardsAndNeverCompletesThePartialOne) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  const cdc::LayoutParams p{config.image_width, config.image_height,
                            config.max_ctrl_pts + cdc::kExtraKnotSlots, config.max_ctrl_pts,
                            config.max_yaw_pts};
  const uint64_t rs = cdc::RecordLayout::Compute(p).record_size;
  config.shard_size_mb = (cdc::kHeaderSize + 4.5 * rs) / 1e6;  // 4 records per shard
  // Record 6 is the third of shard 1: the disk is full half-way through it.
  const uint64_t limit = cdc::kHeaderSize + 2 * rs + rs / 2;
  FileSizeLimit fsize;
  std::atomic<bool> lowered{false};
  cdc::WriterHooks hooks;
  hooks.before_write = [&](uint64_t seq) {
    if (seq == 6) lowered = fsize.Lower(limit);
  };
  cdc::DatasetWriter writer(config, hooks);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(8));
  cdc::SyntheticRecord rec;
  for (uint64_t i = 0; i < 7; ++i) {
    gen.Generate(i, &rec);
    ASSERT_TRUE(writer.Record(rec.record).ok()) << i;
  }
  while (!writer.stats().failed) std::this_thread::yield();
  const std::string partial = config.output_dir + "/shard_000001.qdr.partial";
  gen.Generate(7, &rec);
  const cdc::RecordResult after = writer.Record(rec.record);
  EXPECT_EQ(after.status, cdc::RecordStatus::kWriterFailed);
  const cdc::FinalizeResult fin = writer.Finalize();
  fsize.Restore();
  ASSERT_TRUE(lowered.load());
  EXPECT_FALSE(fin.ok);
  // A clear error naming the file and the reason.
  EXPECT_NE(fin.error.find("cannot write " + partial + ": File too large"), std::string::npos) << fin.error;
  EXPECT_EQ(after.reason, fin.error);
  EXPECT_EQ(fin.stats.written, 6u);
  EXPECT_EQ(fin.stats.lost, 2u);  // the record being written and the one refused afterwards
  EXPECT_EQ(fin.stats.shards_completed, 1u);

  // The partial shard keeps its .partial name, holds its two complete records and a torn tail of exactly
  // what fitted of the third; no *.tmp manifest is left behind.
  EXPECT_TRUE(fs::exists(partial));
  EXPECT_FALSE(fs::exists(config.output_dir + "/shard_000001.qdr"));
  EXPECT_EQ(fs::file_size(partial), limit);
  EXPECT_FALSE(fs::exists(config.output_dir + "/manifest.yaml.tmp"));

  const cdc::DatasetReader reader(config.output_dir);
  const cdc::Manifest& m = *reader.manifest();
  EXPECT_EQ(m.status, cdc::DatasetStatus::kIncomplete);
  EXPECT_EQ(m.writer_error, fin.error);
  ASSERT_EQ(m.shards.size(), 1u);  // the manifest lists the completed shard only
  EXPECT_EQ(m.shards[0].file, "shard_000000.qdr");
  EXPECT_EQ(m.shards[0].records, 4u);
  ASSERT_EQ(reader.shards().size(), 2u);
  const cdc::ShardReader& done = reader.shards()[0];
  const cdc::ShardReader& torn = reader.shards()[1];
  EXPECT_FALSE(done.partial());
  EXPECT_TRUE(torn.partial());
  EXPECT_EQ(torn.num_records(), 2u);
  EXPECT_EQ(torn.torn_tail_bytes(), rs / 2);
  uint64_t i = 0;
  for (const cdc::ShardReader& s : reader.shards()) {
    for (uint64_t k = 0; k < s.num_records(); ++k, ++i) {
      gen.Generate(i, &rec);
      ExpectRecordEquals(rec.record, s.Decode(k), i);
    }
  }
  const cdc::VerifyReport rep = reader.Verify();
  EXPECT_TRUE(rep.errors.empty()) << rep.errors[0];
  ASSERT_EQ(rep.warnings.size(), 2u);
  EXPECT_EQ(rep.warnings[0], "dataset is incomplete: the writer failed: " + fin.error);
  EXPECT_EQ(rep.warnings[1], "shard_000001.qdr.partial: torn tail of " + std::to_string(rs / 2) +
                                 " bytes after record 2 (skipped)");
  // Recovery cuts the torn record and completes the dataset with the 6 whole records.
  const cdc::RecoverResult rr = cdc::RecoverDataset(config.output_dir);
  EXPECT_EQ(rr.records, 6u);
  const cdc::DatasetReader recovered(config.output_dir);
  EXPECT_TRUE(recovered.Verify().clean());
  EXPECT_EQ(recovered.num_records(), 6u);
}

TEST(DatasetWriter, DiskFullWhileWritingTheManifestLeavesTheOldOneAndNoTemporaryFile) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  FileSizeLimit fsize;
  cdc::DatasetWriter writer(config);
  const std::string before = [&] {
    std::ifstream in(config.output_dir + "/manifest.yaml");
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }();
  ASSERT_TRUE(fsize.Lower(100));  // smaller than any manifest
  const cdc::FinalizeResult fin = writer.Finalize();
  fsize.Restore();
  EXPECT_FALSE(fin.ok);
  EXPECT_NE(
      fin.error.find("manifest: cannot write " + config.output_dir + "/manifest.yaml.tmp: File too large"),
      std::string::npos)
      << fin.error;
  EXPECT_FALSE(fs::exists(config.output_dir + "/manifest.yaml.tmp"));
  std::ifstream in(config.output_dir + "/manifest.yaml");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()), before);
  EXPECT_EQ(cdc::ReadManifest(config.output_dir + "/manifest.yaml").status, cdc::DatasetStatus::kIncomplete);
}

// A resumed collection run (docs/collect.md, "Resuming"): the unfinished episode's records are cut, then a
// second writer appends to the same dataset. The result reads as one dataset: shard indices, seqs and counts
// continue, the first run's records are untouched, and the appended records keep their (keyed) episode ids,
// so the resumed dataset equals a straight run's; a record of an episode the dataset already held is refused.
TEST(DatasetWriter, AppendContinuesATruncatedDatasetWithoutTouchingItsRecords) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  const cdc::LayoutParams p{config.image_width, config.image_height,
                            config.max_ctrl_pts + cdc::kExtraKnotSlots, config.max_ctrl_pts,
                            config.max_yaw_pts};
  const uint64_t rs = cdc::RecordLayout::Compute(p).record_size;
  config.shard_size_mb = (cdc::kHeaderSize + 4.5 * rs) / 1e6;      // 4 records per shard
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(5));  // 7 records per episode, ids 0, 1, ...
  cdc::SyntheticRecord rec;
  {
    cdc::DatasetWriter first(config);
    first.SetRunInfo("seeds", "1,2");
    for (uint64_t i = 0; i < 10; ++i) {  // episode 0 (7 records) and 3 records of episode 1
      gen.Generate(i, &rec);
      ASSERT_TRUE(first.Record(rec.record).ok());
    }
    ASSERT_TRUE(first.Finalize().ok);
  }
  const std::vector<uint8_t> shard0 = cdc_test::ReadBytes(tmp / "ds/shard_000000.qdr");
  EXPECT_THROW(cdc::TruncateDataset(config.output_dir, 11), cdc::FormatError);
  const cdc::RecoverResult cut = cdc::TruncateDataset(config.output_dir, 7);  // episode 1 did not finish
  EXPECT_EQ(cut.records, 7u);
  EXPECT_FALSE(fs::exists(tmp / "ds/shard_000002.qdr"));
  EXPECT_EQ(fs::file_size(tmp / "ds/shard_000001.qdr"), cdc::kHeaderSize + 3 * rs);
  {
    const cdc::DatasetReader r(config.output_dir);
    EXPECT_TRUE(r.Verify().clean());
    EXPECT_EQ(r.manifest()->status, cdc::DatasetStatus::kRecovered);
    EXPECT_EQ(r.manifest()->counts.submitted, 7u);
    ASSERT_EQ(r.manifest()->episodes.size(), 1u);
  }
  // A plain writer still refuses the directory; an appending one continues it.
  EXPECT_THROW(cdc::DatasetWriter refused(config), std::runtime_error);
  {
    cdc::DatasetWriter second(config, {}, cdc::OpenMode::kAppend);
    second.SetRunInfo("seeds", "1,2");
    gen.Generate(0, &rec);  // a record of episode 0, which the dataset holds: refused, no seq used
    const cdc::RecordResult refused = second.Record(rec.record);
    EXPECT_EQ(refused.status, cdc::RecordStatus::kRejectedInvalid);
    EXPECT_EQ(refused.reason,
              "episode id 0 names an episode the dataset held before this append (appended records keep "
              "their ids: a resumed run must fly keyed episodes, docs/collect.md)");
    for (uint64_t i = 7; i < 14; ++i) {  // episode 1 flown again: the same (keyed) id as in a straight run
      gen.Generate(i, &rec);
      const cdc::RecordResult r = second.Record(rec.record);
      ASSERT_TRUE(r.ok()) << r.reason;
      EXPECT_EQ(r.seq, i);
    }
    ASSERT_TRUE(second.Finalize().ok);
  }
  EXPECT_EQ(cdc_test::ReadBytes(tmp / "ds/shard_000000.qdr"), shard0);  // finished data untouched
  const cdc::DatasetReader reader(config.output_dir);
  EXPECT_TRUE(reader.Verify().clean());
  EXPECT_EQ(reader.num_records(), 14u);
  ASSERT_EQ(reader.shards().size(), 4u);  // 4 + 3 (cut) + 4 + 3
  const cdc::Manifest& m = *reader.manifest();
  EXPECT_EQ(m.status, cdc::DatasetStatus::kComplete);
  EXPECT_EQ(m.counts.submitted, 14u);
  EXPECT_EQ(m.counts.written, 14u);
  EXPECT_EQ(m.counts.rejected, 1u);
  ASSERT_EQ(m.episodes.size(), 2u);
  EXPECT_EQ(m.episodes[0].episode_id, 0);
  EXPECT_EQ(m.episodes[0].records, 7u);
  EXPECT_EQ(m.episodes[1].episode_id, 1);  // kept: the id a straight run gives this episode
  EXPECT_EQ(m.episodes[1].records, 7u);
  EXPECT_TRUE(std::none_of(m.run_info.begin(), m.run_info.end(),
                           [](const auto& kv) { return kv.first == "episode_id_offset"; }));
  // Record for record what a straight run writes (but the manifest's counts of the refused record).
  cdc_test::TempDir straight_tmp;
  cdc::WriterConfig straight_config = config;
  straight_config.output_dir = straight_tmp / "ds";
  {
    cdc::DatasetWriter straight(straight_config);
    for (uint64_t i = 0; i < 14; ++i) {
      gen.Generate(i, &rec);
      ASSERT_TRUE(straight.Record(rec.record).ok());
    }
    ASSERT_TRUE(straight.Finalize().ok);
  }
  const cdc::DatasetReader straight_reader(straight_config.output_dir);
  ASSERT_EQ(straight_reader.num_records(), 14u);
  const auto commits = std::find_if(m.run_info.begin(), m.run_info.end(),
                                    [](const auto& kv) { return kv.first == "software_commits"; });
  ASSERT_NE(commits, m.run_info.end());
  EXPECT_EQ(commits->second, "test-commit");  // the same commit wrote both runs
  uint64_t i = 0;
  for (const cdc::ShardReader& s : reader.shards()) {
    for (uint64_t k = 0; k < s.num_records(); ++k, ++i) {
      const cdc::DecodedRecord d = s.Decode(k);
      EXPECT_EQ(d.head.seq, i);
      EXPECT_EQ(d.head.episode_id, i < 7 ? 0 : 1);
    }
  }
  // The records (not their shard files: a resumed dataset's shards are cut where the interruption was) equal
  // the straight run's byte for byte.
  std::vector<std::vector<uint8_t>> appended_bytes, straight_bytes;
  for (const cdc::ShardReader& s : reader.shards()) {
    for (uint64_t k = 0; k < s.num_records(); ++k) {
      appended_bytes.emplace_back(s.RecordBytes(k), s.RecordBytes(k) + s.layout().record_size);
    }
  }
  for (const cdc::ShardReader& s : straight_reader.shards()) {
    for (uint64_t k = 0; k < s.num_records(); ++k) {
      straight_bytes.emplace_back(s.RecordBytes(k), s.RecordBytes(k) + s.layout().record_size);
    }
  }
  EXPECT_EQ(appended_bytes, straight_bytes);
}

TEST(DatasetWriter, AppendRefusesADatasetItCannotContinueNamingWhy) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  {
    cdc::DatasetWriter first(config);
    ASSERT_TRUE(first.Finalize().ok);
  }
  cdc::WriterConfig other = config;
  other.image_width = 64;
  try {
    cdc::DatasetWriter w(other, {}, cdc::OpenMode::kAppend);
    FAIL() << "appended to a dataset of another image size";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("its image_width is 32, this writer's is 64"), std::string::npos)
        << e.what();
  }
  { cdc::DatasetWriter unfinished(config, {}, cdc::OpenMode::kAppend); }  // finalised by its destructor
  cdc_test::WriteBytes(tmp / "ds/shard_000000.qdr.partial", {1, 2, 3});
  try {
    cdc::DatasetWriter w(config, {}, cdc::OpenMode::kAppend);
    FAIL() << "appended beside a partial shard";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("partial shard shard_000000.qdr.partial"), std::string::npos)
        << e.what();
  }
}
