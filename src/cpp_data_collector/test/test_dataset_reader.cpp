#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <thread>

#include "cpp_data_collector/dataset_reader.h"
#include "cpp_data_collector/dataset_writer.h"
#include "cpp_data_collector/synthetic.h"
#include "test_util.h"

namespace cdc = cpp_data_collector;
namespace fs = std::filesystem;

namespace {

bool Contains(const std::vector<std::string>& lines, const std::string& needle) {
  for (const auto& l : lines) {
    if (l.find(needle) != std::string::npos) return true;
  }
  return false;
}

std::string Joined(const std::vector<std::string>& lines) {
  std::string s;
  for (const auto& l : lines) s += l + "\n";
  return s;
}

// Writes `n` records with shards of `per_shard` records and finalises.
cdc::WriterConfig WriteDataset(const std::string& dir, uint64_t n, double per_shard) {
  cdc::WriterConfig config = cdc_test::SmallConfig(dir);
  const cdc::RecordLayout l = cdc::RecordLayout::Compute({config.image_width, config.image_height,
                                                          config.max_ctrl_pts + cdc::kExtraKnotSlots,
                                                          config.max_ctrl_pts, config.max_yaw_pts});
  config.shard_size_mb = (cdc::kHeaderSize + per_shard * l.record_size) / 1e6;
  cdc::DatasetWriter writer(config);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(21));
  cdc::SyntheticRecord rec;
  for (uint64_t i = 0; i < n; ++i) {
    gen.Generate(i, &rec);
    EXPECT_TRUE(writer.Record(rec.record).ok());
  }
  EXPECT_TRUE(writer.Finalize().ok);
  return config;
}

// Runs a writer in a child process and kills it with SIGKILL once `n` records are written: no Finalize, no
// destructor, exactly as a crashed planner.
void WriteAndKill(const cdc::WriterConfig& config, uint64_t n) {
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    cdc::DatasetWriter writer(config);
    const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(21));
    cdc::SyntheticRecord rec;
    for (uint64_t i = 0; i < n; ++i) {
      gen.Generate(i, &rec);
      writer.Record(rec.record);
    }
    while (writer.stats().written < n) std::this_thread::yield();
    raise(SIGKILL);
    _exit(3);  // not reached
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFSIGNALED(status));
  ASSERT_EQ(WTERMSIG(status), SIGKILL);
}

TEST(DatasetReader, AKilledWriterLeavesEveryCompletedRecordReadable) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  const cdc::RecordLayout l = cdc::RecordLayout::Compute({32, 24, 48, 40, 40});
  config.shard_size_mb = (cdc::kHeaderSize + 4.5 * l.record_size) / 1e6;  // 4 records per shard
  WriteAndKill(config, 10);

  EXPECT_TRUE(fs::exists(tmp / "ds/shard_000000.qdr"));
  EXPECT_TRUE(fs::exists(tmp / "ds/shard_000001.qdr"));
  ASSERT_TRUE(fs::exists(tmp / "ds/shard_000002.qdr.partial"));
  const cdc::DatasetReader reader(config.output_dir);
  EXPECT_EQ(reader.manifest()->status, cdc::DatasetStatus::kIncomplete);
  EXPECT_EQ(reader.manifest()->shards.size(), 2u);  // the manifest of the last completed shard
  EXPECT_EQ(reader.num_records(), 10u);
  const cdc::VerifyReport rep = reader.Verify();
  EXPECT_TRUE(rep.errors.empty()) << Joined(rep.errors);
  EXPECT_EQ(rep.valid_records, 10u);
  EXPECT_TRUE(Contains(rep.warnings, "dataset is incomplete")) << Joined(rep.warnings);
  const cdc::SyntheticGenerator gen(cdc_test::SmallSynthetic(21));
  cdc::SyntheticRecord rec;
  gen.Generate(9, &rec);
  const cdc::DecodedRecord last = reader.shards()[2].Decode(1);
  EXPECT_EQ(last.head.seq, 9u);
  EXPECT_EQ(last.ctrl_pts_world, rec.record.bspline.ctrl_pts_world);
}

TEST(DatasetReader, ReportsATornTailAndRecoverCutsIt) {
  cdc_test::TempDir tmp;
  cdc::WriterConfig config = cdc_test::SmallConfig(tmp / "ds");
  config.shard_size_mb = 100;
  WriteAndKill(config, 5);
  // A writer killed in the middle of a record leaves part of it: simulate with the first 1000 bytes of a
  // record.
  const std::string partial = tmp / "ds/shard_000000.qdr.partial";
  std::vector<uint8_t> bytes = cdc_test::ReadBytes(partial);
  const size_t record_size = (bytes.size() - cdc::kHeaderSize) / 5;
  bytes.insert(bytes.end(), bytes.begin() + cdc::kHeaderSize, bytes.begin() + cdc::kHeaderSize + 1000);
  cdc_test::WriteBytes(partial, bytes);

  {
    const cdc::DatasetReader reader(config.output_dir);
    EXPECT_EQ(reader.shards()[0].num_records(), 5u);
    EXPECT_EQ(reader.shards()[0].torn_tail_bytes(), 1000u);
    const cdc::VerifyReport rep = reader.Verify();
    EXPECT_TRUE(rep.errors.empty()) << Joined(rep.errors);
    EXPECT_TRUE(
        Contains(rep.warnings, "shard_000000.qdr.partial: torn tail of 1000 bytes after record 5 (skipped)"))
        << Joined(rep.warnings);
  }
  const cdc::RecoverResult rec = cdc::RecoverDataset(config.output_dir);
  EXPECT_EQ(rec.records, 5u);
  EXPECT_TRUE(Contains(rec.actions, "cut 1000 bytes after record 5")) << Joined(rec.actions);
  EXPECT_FALSE(fs::exists(partial));
  EXPECT_EQ(fs::file_size(tmp / "ds/shard_000000.qdr"), cdc::kHeaderSize + 5 * record_size);
  const cdc::DatasetReader reader(config.output_dir);
  EXPECT_EQ(reader.manifest()->status, cdc::DatasetStatus::kRecovered);
  EXPECT_EQ(reader.manifest()->counts.written, 5u);
  ASSERT_EQ(reader.manifest()->episodes.size(), 1u);
  EXPECT_EQ(reader.manifest()->episodes[0].records, 5u);
  const cdc::VerifyReport rep = reader.Verify();
  EXPECT_TRUE(rep.clean()) << Joined(rep.errors) << Joined(rep.warnings);
  EXPECT_THROW(cdc::RecoverDataset(WriteDataset(tmp / "done", 2, 10).output_dir), cdc::FormatError);
}

TEST(DatasetReader, AFlippedByteIsReportedWithShardAndRecordIndex) {
  cdc_test::TempDir tmp;
  const cdc::WriterConfig config = WriteDataset(tmp / "ds", 9, 4);
  const std::string path = tmp / "ds/shard_000001.qdr";
  std::vector<uint8_t> bytes = cdc_test::ReadBytes(path);
  const size_t record_size = (bytes.size() - cdc::kHeaderSize) / 4;
  bytes[cdc::kHeaderSize + 2 * record_size + record_size - 100] ^= 0x10;  // inside record 2's depth image
  cdc_test::WriteBytes(path, bytes);

  const cdc::DatasetReader reader(config.output_dir);
  const cdc::VerifyReport rep = reader.Verify();
  ASSERT_EQ(rep.errors.size(), 1u) << Joined(rep.errors);
  EXPECT_NE(rep.errors[0].find("shard_000001.qdr record 2: CRC mismatch"), std::string::npos)
      << rep.errors[0];
  EXPECT_EQ(rep.valid_records, 8u);
  EXPECT_EQ(rep.shards[1].bad_records, std::vector<uint64_t>{2});
  try {
    reader.shards()[1].Decode(2);
    FAIL();
  } catch (const cdc::FormatError& e) {
    EXPECT_NE(std::string(e.what()).find("shard_000001.qdr: record 2: CRC mismatch"), std::string::npos)
        << e.what();
  }
  EXPECT_NO_THROW(reader.shards()[1].Decode(3));
}

TEST(DatasetReader, ATruncatedCompletedShardIsAnError) {
  cdc_test::TempDir tmp;
  const cdc::WriterConfig config = WriteDataset(tmp / "ds", 6, 3);
  const std::string path = tmp / "ds/shard_000000.qdr";
  std::vector<uint8_t> bytes = cdc_test::ReadBytes(path);
  bytes.resize(bytes.size() - 100);
  cdc_test::WriteBytes(path, bytes);
  const cdc::VerifyReport rep = cdc::DatasetReader(config.output_dir).Verify();
  EXPECT_TRUE(Contains(rep.errors, "in a completed shard")) << Joined(rep.errors);
  EXPECT_TRUE(Contains(rep.errors, "shard_000000.qdr: holds 2 records, the manifest says 3"))
      << Joined(rep.errors);
}

void ExpectOpenError(const std::string& dir, const std::string& needle) {
  try {
    cdc::DatasetReader reader(dir);
    FAIL() << "no error, expected " << needle;
  } catch (const cdc::FormatError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(DatasetReader, BadPathsEmptyAndForeignDirectoriesGiveClearErrors) {
  cdc_test::TempDir tmp;
  ExpectOpenError(tmp / "nope", "nope: no such dataset directory");
  fs::create_directories(tmp / "empty");
  ExpectOpenError(tmp / "empty", "empty: empty directory, not a quad_il dataset");
  fs::create_directories(tmp / "foreign");
  cdc_test::WriteBytes(tmp / "foreign/data.csv", {'a', ',', 'b'});
  ExpectOpenError(tmp / "foreign", "not a quad_il dataset (no manifest.yaml and no shard_*.qdr files)");
  cdc_test::WriteBytes(tmp / "file.bin", {1});
  ExpectOpenError(tmp / "file.bin", "not a directory");
  fs::create_directories(tmp / "fake");
  cdc_test::WriteBytes(tmp / "fake/shard_000000.qdr", std::vector<uint8_t>(5000, 'x'));
  ExpectOpenError(tmp / "fake", "shard_000000.qdr: not a quad_il record shard");
  fs::create_directories(tmp / "badmanifest");
  cdc_test::WriteBytes(tmp / "badmanifest/manifest.yaml", {'a', ':', ' ', '1'});
  ExpectOpenError(tmp / "badmanifest", "not a quad_il cpp_data_collector manifest");
}

TEST(DatasetReader, AMissingShardInTheMiddleIsAnError) {
  cdc_test::TempDir tmp;
  WriteDataset(tmp / "ds", 7, 2);
  fs::remove(tmp / "ds/shard_000001.qdr");
  ExpectOpenError(tmp / "ds", "shard_000001.qdr is missing (next shard found: shard_000002.qdr)");
}

TEST(DatasetReader, AShardOfAnotherFormatVersionIsRefused) {
  cdc_test::TempDir tmp;
  WriteDataset(tmp / "ds", 2, 10);
  std::vector<uint8_t> bytes = cdc_test::ReadBytes(tmp / "ds/shard_000000.qdr");
  bytes[8] = 9;
  cdc_test::WriteBytes(tmp / "ds/shard_000000.qdr", bytes);
  ExpectOpenError(tmp / "ds", "record format version 9 is not supported");
}

}  // namespace
