// The on-disk record format of cpp_data_collector, version 1 (specification: docs/data_format.md).
//
// A dataset is a directory of shards plus a manifest. A shard is a 4096-byte header followed by fixed-size
// records; every record ends with the zlib CRC32 of its other bytes. The layout of a record depends only on
// the format version and on five numbers stored in the header (image width/height, maximum knots, control
// points and yaw points), so a reader can memory-map a shard as an array of records. Everything is
// little-endian.
//
// We write our own format rather than use HDF5/Arrow/rosbag because none of them gives the three properties
// the collector needs together with zero copies: append-only crash safety (a killed writer leaves every
// completed record valid), per-record integrity (CRC per record, reported by shard and index), and a fixed
// layout that numpy memory-maps directly.
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace cpp_data_collector {

static_assert(
    __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__,
    "the record format is little-endian; a big-endian host needs byte swapping in writer and reader");

inline constexpr uint32_t kFormatVersion = 1;
inline constexpr char kShardMagic[8] = {'Q', 'I', 'L', 'S', 'H', 'A', 'R', 'D'};
inline constexpr uint32_t kHeaderSize = 4096;
// The first four bytes of every record: "QREC".
inline constexpr uint32_t kRecordMagic = 0x43455251u;
inline constexpr uint32_t kDepthEncodingUint16Millimetres = 1;
inline constexpr size_t kStatusTextBytes = 48;
inline constexpr int kMaxSplineOrder = 7;
// knots = control points + order + 1, so this many extra knot slots cover every order up to kMaxSplineOrder.
inline constexpr uint32_t kExtraKnotSlots = kMaxSplineOrder + 1;

inline constexpr char kShardPrefix[] = "shard_";
inline constexpr char kShardSuffix[] = ".qdr";
inline constexpr char kPartialSuffix[] = ".partial";
inline constexpr char kManifestName[] = "manifest.yaml";

// Depth codes (uint16). REP 118's special float values keep their meaning:
//   0      NaN   invalid measurement
//   1      -Inf  closer than the sensor's minimum range
//   65535  +Inf  no return within range (too far); also any finite depth >= 65.5345 m
//   2..65534     round-half-up of the depth in millimetres; finite depths below 1.5 mm are stored as 2
// Finite depths <= 0 m are stored as 0 (invalid): a pinhole camera cannot measure them.
inline constexpr uint16_t kDepthCodeInvalid = 0;
inline constexpr uint16_t kDepthCodeTooNear = 1;
inline constexpr uint16_t kDepthCodeTooFar = 65535;
inline constexpr uint16_t kDepthCodeMinValid = 2;
inline constexpr uint16_t kDepthCodeMaxValid = 65534;

// Thrown by readers for files that are not shards, other format versions, inconsistent headers or datasets.
class FormatError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// One depth value in metres (REP 118 float semantics) -> its uint16 code. Exact: the float is widened to
// double, where d * 1000 + 0.5 is computed without rounding for every depth that is not clamped, then
// truncated.
uint16_t EncodeDepthMetres(float depth_m);
// Code -> metres as float32: NaN, -Inf, +Inf for the special codes, else float(code / 1000.0).
float DecodeDepthCode(uint16_t code);
// Encodes a whole image (rows of `width` floats, `row_stride_bytes` apart) into width*height codes,
// row-major. Vectorised (AVX2 when the CPU has it); bit-identical to EncodeDepthMetres per pixel.
void EncodeDepthImage(const float* depth_m, uint32_t width, uint32_t height, size_t row_stride_bytes,
                      uint16_t* codes);

// zlib's CRC-32 (the same value as Python's zlib.crc32).
uint32_t Crc32(const void* data, size_t size);

// The first 312 bytes of every record, in this exact order (offsets are part of the format: see the
// static_asserts in record_format.cpp and docs/data_format.md).
struct RecordHead {
  uint32_t magic;
  uint32_t flags;  // reserved, 0 in version 1
  uint64_t seq;    // 0-based call index of DatasetWriter::Record over the whole dataset (drops leave gaps)
  int64_t episode_id;
  uint64_t world_seed;
  double sim_time_s;     // sim time at which the plan was recorded
  double depth_stamp_s;  // stamp of the depth image the plan used
  double odom_stamp_s;   // stamp of the odometry the plan used
  double p_world_body[3];
  double v_world[3];
  double q_world_body[4];  // x, y, z, w
  double w_body[3];        // rad/s in body axes
  double goal_world[3];
  double bspline_start_time_s;  // time at which the spline parameter u = knots[order] is flown
  double bspline_yaw_dt_s;
  int64_t bspline_traj_id;
  int32_t bspline_order;  // degree p (3 = cubic)
  uint32_t num_knots;     // = num_ctrl_pts + order + 1
  uint32_t num_ctrl_pts;
  uint32_t num_yaw_pts;
  int32_t plan_status_code;
  uint32_t reserved;  // 0 in version 1
  double t_map_update_ms;
  double t_frontend_ms;
  double t_optimization_ms;
  double t_total_ms;
  char plan_status_text[kStatusTextBytes];  // UTF-8, NUL-padded, at most 47 bytes of text
};

// The numbers a record layout depends on (all stored in the shard header).
struct LayoutParams {
  uint32_t image_width = 0;
  uint32_t image_height = 0;
  uint32_t max_knots = 0;
  uint32_t max_ctrl_pts = 0;
  uint32_t max_yaw_pts = 0;
};

// One field of the layout description stored in the header (numpy dtype string, shape, byte offset).
struct FieldSpec {
  std::string name;
  std::string dtype;
  std::vector<uint32_t> shape;
  uint32_t offset = 0;
};

// Byte offsets of the variable-size parts of a record of format version 1.
struct RecordLayout {
  LayoutParams params;
  uint32_t knots_offset = 0;    // float64[max_knots]
  uint32_t ctrl_offset = 0;     // float64[max_ctrl_pts][3], world frame
  uint32_t yaw_offset = 0;      // float64[max_yaw_pts]
  uint32_t depth_offset = 0;    // uint16[height][width] depth codes
  uint32_t padding_offset = 0;  // zero bytes up to the CRC
  uint32_t crc_offset = 0;      // uint32, zlib crc32 of bytes [0, crc_offset)
  uint32_t record_size = 0;     // multiple of 8

  // Throws std::invalid_argument for zero image sizes, max_ctrl_pts < 2, or records beyond 2 GiB.
  static RecordLayout Compute(const LayoutParams& params);
  std::vector<FieldSpec> Fields() const;
  // Compact JSON: {"record_size":N,"fields":[["name","<f8",[3],56],...]} (stored in the header).
  std::string ToJson() const;
};

// The fixed part of a shard header (the first 88 bytes), followed by the layout JSON and zero padding.
struct ShardHeader {
  uint32_t format_version = kFormatVersion;
  uint32_t header_size = kHeaderSize;
  uint32_t record_size = 0;
  uint32_t image_width = 0;
  uint32_t image_height = 0;
  uint32_t depth_encoding = kDepthEncodingUint16Millimetres;
  uint32_t max_knots = 0;
  uint32_t max_ctrl_pts = 0;
  uint32_t max_yaw_pts = 0;
  uint32_t shard_index = 0;
  double camera_fx_px = 0.0;  // 0 when unknown
  double camera_fy_px = 0.0;
  double camera_cx_px = 0.0;
  double camera_cy_px = 0.0;
  std::string layout_json;

  LayoutParams layout_params() const;
};

// Header -> exactly kHeaderSize bytes, CRC included.
std::vector<uint8_t> SerializeShardHeader(const ShardHeader& header);
// Parses and validates a header: magic, version, header size, CRC, depth encoding, and that the stored layout
// JSON and record size equal what version 1 computes from the stored dimensions. `source` names the file in
// error messages. Throws FormatError.
ShardHeader ParseShardHeader(const uint8_t* data, size_t size, const std::string& source);

// "shard_000012.qdr" for index 12.
std::string ShardFileName(uint32_t shard_index);

}  // namespace cpp_data_collector
