#include "cpp_data_collector/record_format.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <limits>
#include <sstream>
#include <type_traits>

namespace cpp_data_collector {

static_assert(std::is_standard_layout_v<RecordHead> && std::is_trivially_copyable_v<RecordHead>);
// The offsets below are the format (docs/data_format.md); the compiler must not move anything.
static_assert(offsetof(RecordHead, magic) == 0);
static_assert(offsetof(RecordHead, seq) == 8);
static_assert(offsetof(RecordHead, episode_id) == 16);
static_assert(offsetof(RecordHead, world_seed) == 24);
static_assert(offsetof(RecordHead, sim_time_s) == 32);
static_assert(offsetof(RecordHead, depth_stamp_s) == 40);
static_assert(offsetof(RecordHead, odom_stamp_s) == 48);
static_assert(offsetof(RecordHead, p_world_body) == 56);
static_assert(offsetof(RecordHead, v_world) == 80);
static_assert(offsetof(RecordHead, q_world_body) == 104);
static_assert(offsetof(RecordHead, w_body) == 136);
static_assert(offsetof(RecordHead, goal_world) == 160);
static_assert(offsetof(RecordHead, bspline_start_time_s) == 184);
static_assert(offsetof(RecordHead, bspline_yaw_dt_s) == 192);
static_assert(offsetof(RecordHead, bspline_traj_id) == 200);
static_assert(offsetof(RecordHead, bspline_order) == 208);
static_assert(offsetof(RecordHead, num_knots) == 212);
static_assert(offsetof(RecordHead, num_ctrl_pts) == 216);
static_assert(offsetof(RecordHead, num_yaw_pts) == 220);
static_assert(offsetof(RecordHead, plan_status_code) == 224);
static_assert(offsetof(RecordHead, t_map_update_ms) == 232);
static_assert(offsetof(RecordHead, t_total_ms) == 256);
static_assert(offsetof(RecordHead, plan_status_text) == 264);
static_assert(sizeof(RecordHead) == 312);

namespace {

constexpr size_t kHeaderFixedSize = 88;
constexpr size_t kHeaderLayoutSizeOffset = 80;
constexpr size_t kHeaderCrcOffset = 84;

template <typename T>
void Put(std::vector<uint8_t>* out, size_t offset, const T& value) {
  std::memcpy(out->data() + offset, &value, sizeof(T));
}
template <typename T>
T Take(const uint8_t* data, size_t offset) {
  T value;
  std::memcpy(&value, data + offset, sizeof(T));
  return value;
}

uint32_t AlignUp(uint64_t value, uint64_t alignment) {
  return static_cast<uint32_t>((value + alignment - 1) / alignment * alignment);
}

// Encodes one pixel; shared by the scalar and vectorised paths so they cannot disagree.
inline uint16_t EncodeOne(float depth_m) {
  const double d = depth_m;
  // Exact in binary64 for every d that is not clamped (at most 50 significant bits are needed).
  double mm = d * 1000.0 + 0.5;
  // Written so that NaN and -Inf become 2.0 (comparisons with NaN are false) before the integer conversion,
  // which is undefined for NaN and out-of-range values; the special codes are selected afterwards.
  mm = (mm >= kDepthCodeMinValid) ? mm : static_cast<double>(kDepthCodeMinValid);
  mm = (mm <= kDepthCodeTooFar) ? mm : static_cast<double>(kDepthCodeTooFar);
  uint16_t code = static_cast<uint16_t>(static_cast<int32_t>(mm));  // truncation == floor for mm >= 2
  code = (d <= 0.0) ? kDepthCodeInvalid : code;                     // also -0.0 and finite negatives
  code = (d != d) ? kDepthCodeInvalid : code;
  code = (d == -std::numeric_limits<double>::infinity()) ? kDepthCodeTooNear : code;
  return code;
}

// The hot loop of the writer thread; target_clones lets it use AVX2 without requiring it of the CPU.
__attribute__((target_clones("avx2", "default"))) void EncodeRow(const float* in, uint16_t* out, uint32_t n) {
  for (uint32_t i = 0; i < n; ++i) out[i] = EncodeOne(in[i]);
}

}  // namespace

uint16_t EncodeDepthMetres(float depth_m) { return EncodeOne(depth_m); }

float DecodeDepthCode(uint16_t code) {
  if (code == kDepthCodeInvalid) return std::numeric_limits<float>::quiet_NaN();
  if (code == kDepthCodeTooNear) return -std::numeric_limits<float>::infinity();
  if (code == kDepthCodeTooFar) return std::numeric_limits<float>::infinity();
  return static_cast<float>(static_cast<double>(code) / 1000.0);
}

void EncodeDepthImage(const float* depth_m, uint32_t width, uint32_t height, size_t row_stride_bytes,
                      uint16_t* codes) {
  const size_t stride = row_stride_bytes == 0 ? width * sizeof(float) : row_stride_bytes;
  const auto* base = reinterpret_cast<const uint8_t*>(depth_m);
  for (uint32_t r = 0; r < height; ++r) {
    EncodeRow(reinterpret_cast<const float*>(base + r * stride), codes + static_cast<size_t>(r) * width,
              width);
  }
}

uint32_t Crc32(const void* data, size_t size) {
  uLong crc = crc32(0L, Z_NULL, 0);
  const auto* p = static_cast<const Bytef*>(data);
  // zlib takes uInt lengths: feed in chunks so sizes above 4 GiB would also work.
  while (size > 0) {
    const uInt chunk = static_cast<uInt>(std::min<size_t>(size, 1u << 30));
    crc = crc32(crc, p, chunk);
    p += chunk;
    size -= chunk;
  }
  return static_cast<uint32_t>(crc);
}

RecordLayout RecordLayout::Compute(const LayoutParams& params) {
  if (params.image_width == 0 || params.image_height == 0) {
    throw std::invalid_argument("record layout: image size " + std::to_string(params.image_width) + "x" +
                                std::to_string(params.image_height) + " must be positive");
  }
  if (params.max_ctrl_pts < 2) {
    throw std::invalid_argument("record layout: max_ctrl_pts " + std::to_string(params.max_ctrl_pts) +
                                " must be >= 2");
  }
  if (params.max_knots < params.max_ctrl_pts + 2) {
    throw std::invalid_argument("record layout: max_knots " + std::to_string(params.max_knots) +
                                " must be >= max_ctrl_pts + 2");
  }
  RecordLayout l;
  l.params = params;
  uint64_t offset = sizeof(RecordHead);
  l.knots_offset = static_cast<uint32_t>(offset);
  offset += 8ull * params.max_knots;
  l.ctrl_offset = static_cast<uint32_t>(offset);
  offset += 24ull * params.max_ctrl_pts;
  l.yaw_offset = static_cast<uint32_t>(offset);
  offset += 8ull * params.max_yaw_pts;
  l.depth_offset = static_cast<uint32_t>(offset);
  offset += 2ull * params.image_width * params.image_height;
  l.padding_offset = static_cast<uint32_t>(offset);
  const uint64_t size = AlignUp(offset + 4, 8);
  if (size > (1ull << 31)) throw std::invalid_argument("record layout: record larger than 2 GiB");
  l.record_size = static_cast<uint32_t>(size);
  l.crc_offset = l.record_size - 4;
  return l;
}

std::vector<FieldSpec> RecordLayout::Fields() const {
  using V = std::vector<uint32_t>;
  std::vector<FieldSpec> f = {
      {"magic", "<u4", {}, offsetof(RecordHead, magic)},
      {"flags", "<u4", {}, offsetof(RecordHead, flags)},
      {"seq", "<u8", {}, offsetof(RecordHead, seq)},
      {"episode_id", "<i8", {}, offsetof(RecordHead, episode_id)},
      {"world_seed", "<u8", {}, offsetof(RecordHead, world_seed)},
      {"sim_time_s", "<f8", {}, offsetof(RecordHead, sim_time_s)},
      {"depth_stamp_s", "<f8", {}, offsetof(RecordHead, depth_stamp_s)},
      {"odom_stamp_s", "<f8", {}, offsetof(RecordHead, odom_stamp_s)},
      {"p_world_body", "<f8", V{3}, offsetof(RecordHead, p_world_body)},
      {"v_world", "<f8", V{3}, offsetof(RecordHead, v_world)},
      {"q_world_body", "<f8", V{4}, offsetof(RecordHead, q_world_body)},
      {"w_body", "<f8", V{3}, offsetof(RecordHead, w_body)},
      {"goal_world", "<f8", V{3}, offsetof(RecordHead, goal_world)},
      {"bspline_start_time_s", "<f8", {}, offsetof(RecordHead, bspline_start_time_s)},
      {"bspline_yaw_dt_s", "<f8", {}, offsetof(RecordHead, bspline_yaw_dt_s)},
      {"bspline_traj_id", "<i8", {}, offsetof(RecordHead, bspline_traj_id)},
      {"bspline_order", "<i4", {}, offsetof(RecordHead, bspline_order)},
      {"num_knots", "<u4", {}, offsetof(RecordHead, num_knots)},
      {"num_ctrl_pts", "<u4", {}, offsetof(RecordHead, num_ctrl_pts)},
      {"num_yaw_pts", "<u4", {}, offsetof(RecordHead, num_yaw_pts)},
      {"plan_status_code", "<i4", {}, offsetof(RecordHead, plan_status_code)},
      {"reserved", "<u4", {}, offsetof(RecordHead, reserved)},
      {"t_map_update_ms", "<f8", {}, offsetof(RecordHead, t_map_update_ms)},
      {"t_frontend_ms", "<f8", {}, offsetof(RecordHead, t_frontend_ms)},
      {"t_optimization_ms", "<f8", {}, offsetof(RecordHead, t_optimization_ms)},
      {"t_total_ms", "<f8", {}, offsetof(RecordHead, t_total_ms)},
      {"plan_status_text", "|S48", {}, offsetof(RecordHead, plan_status_text)},
      {"knots", "<f8", V{params.max_knots}, knots_offset},
      {"ctrl_pts_world", "<f8", V{params.max_ctrl_pts, 3}, ctrl_offset},
      {"yaw_pts", "<f8", V{params.max_yaw_pts}, yaw_offset},
      {"depth_code", "<u2", V{params.image_height, params.image_width}, depth_offset},
      {"crc32", "<u4", {}, crc_offset},
  };
  if (params.max_yaw_pts == 0) {
    f.erase(std::remove_if(f.begin(), f.end(), [](const FieldSpec& s) { return s.name == "yaw_pts"; }),
            f.end());
  }
  return f;
}

std::string RecordLayout::ToJson() const {
  std::ostringstream s;
  s << "{\"record_size\":" << record_size << ",\"fields\":[";
  const auto fields = Fields();
  for (size_t i = 0; i < fields.size(); ++i) {
    const FieldSpec& f = fields[i];
    s << (i ? "," : "") << "[\"" << f.name << "\",\"" << f.dtype << "\",[";
    for (size_t k = 0; k < f.shape.size(); ++k) s << (k ? "," : "") << f.shape[k];
    s << "]," << f.offset << "]";
  }
  s << "]}";
  return s.str();
}

LayoutParams ShardHeader::layout_params() const {
  LayoutParams p;
  p.image_width = image_width;
  p.image_height = image_height;
  p.max_knots = max_knots;
  p.max_ctrl_pts = max_ctrl_pts;
  p.max_yaw_pts = max_yaw_pts;
  return p;
}

std::vector<uint8_t> SerializeShardHeader(const ShardHeader& h) {
  if (h.layout_json.size() > kHeaderSize - kHeaderFixedSize) {
    throw std::invalid_argument("shard header: layout description of " +
                                std::to_string(h.layout_json.size()) + " bytes does not fit the header");
  }
  std::vector<uint8_t> out(kHeaderSize, 0);
  std::memcpy(out.data(), kShardMagic, sizeof(kShardMagic));
  Put(&out, 8, h.format_version);
  Put(&out, 12, h.header_size);
  Put(&out, 16, h.record_size);
  Put(&out, 20, h.image_width);
  Put(&out, 24, h.image_height);
  Put(&out, 28, h.depth_encoding);
  Put(&out, 32, h.max_knots);
  Put(&out, 36, h.max_ctrl_pts);
  Put(&out, 40, h.max_yaw_pts);
  Put(&out, 44, h.shard_index);
  Put(&out, 48, h.camera_fx_px);
  Put(&out, 56, h.camera_fy_px);
  Put(&out, 64, h.camera_cx_px);
  Put(&out, 72, h.camera_cy_px);
  Put(&out, kHeaderLayoutSizeOffset, static_cast<uint32_t>(h.layout_json.size()));
  std::memcpy(out.data() + kHeaderFixedSize, h.layout_json.data(), h.layout_json.size());
  Put(&out, kHeaderCrcOffset, Crc32(out.data(), out.size()));  // computed with the CRC field still zero
  return out;
}

ShardHeader ParseShardHeader(const uint8_t* data, size_t size, const std::string& source) {
  if (size < kHeaderFixedSize || std::memcmp(data, kShardMagic, sizeof(kShardMagic)) != 0) {
    throw FormatError(source + ": not a quad_il record shard (no 'QILSHARD' magic at the start of the file)");
  }
  ShardHeader h;
  h.format_version = Take<uint32_t>(data, 8);
  if (h.format_version != kFormatVersion) {
    throw FormatError(source + ": record format version " + std::to_string(h.format_version) +
                      " is not supported (this reader reads version " + std::to_string(kFormatVersion) + ")");
  }
  h.header_size = Take<uint32_t>(data, 12);
  if (h.header_size != kHeaderSize) {
    throw FormatError(source + ": header size " + std::to_string(h.header_size) + " is not " +
                      std::to_string(kHeaderSize));
  }
  if (size < kHeaderSize) {
    throw FormatError(source + ": truncated header (" + std::to_string(size) + " of " +
                      std::to_string(kHeaderSize) + " bytes)");
  }
  std::vector<uint8_t> copy(data, data + kHeaderSize);
  const uint32_t stored_crc = Take<uint32_t>(data, kHeaderCrcOffset);
  std::memset(copy.data() + kHeaderCrcOffset, 0, 4);
  const uint32_t crc = Crc32(copy.data(), copy.size());
  if (crc != stored_crc) {
    throw FormatError(source + ": header CRC mismatch (stored " + std::to_string(stored_crc) + ", computed " +
                      std::to_string(crc) + "): corrupted header");
  }
  h.record_size = Take<uint32_t>(data, 16);
  h.image_width = Take<uint32_t>(data, 20);
  h.image_height = Take<uint32_t>(data, 24);
  h.depth_encoding = Take<uint32_t>(data, 28);
  h.max_knots = Take<uint32_t>(data, 32);
  h.max_ctrl_pts = Take<uint32_t>(data, 36);
  h.max_yaw_pts = Take<uint32_t>(data, 40);
  h.shard_index = Take<uint32_t>(data, 44);
  h.camera_fx_px = Take<double>(data, 48);
  h.camera_fy_px = Take<double>(data, 56);
  h.camera_cx_px = Take<double>(data, 64);
  h.camera_cy_px = Take<double>(data, 72);
  const uint32_t json_size = Take<uint32_t>(data, kHeaderLayoutSizeOffset);
  if (json_size > kHeaderSize - kHeaderFixedSize) {
    throw FormatError(source + ": layout description size " + std::to_string(json_size) + " is out of range");
  }
  h.layout_json.assign(reinterpret_cast<const char*>(data) + kHeaderFixedSize, json_size);
  if (h.depth_encoding != kDepthEncodingUint16Millimetres) {
    throw FormatError(source + ": unknown depth encoding " + std::to_string(h.depth_encoding));
  }
  RecordLayout layout;
  try {
    layout = RecordLayout::Compute(h.layout_params());
  } catch (const std::invalid_argument& e) {
    throw FormatError(source + ": " + e.what());
  }
  if (layout.record_size != h.record_size || layout.ToJson() != h.layout_json) {
    throw FormatError(source + ": the record layout stored in the header differs from format version " +
                      std::to_string(kFormatVersion) + "'s layout for these dimensions");
  }
  return h;
}

std::string ShardFileName(uint32_t shard_index) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%s%06u%s", kShardPrefix, shard_index, kShardSuffix);
  return buf;
}

}  // namespace cpp_data_collector
