#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "cpp_data_collector/record_format.h"

namespace cdc = cpp_data_collector;

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

TEST(DepthCodec, SpecialValuesFollowRep118) {
  EXPECT_EQ(cdc::EncodeDepthMetres(kNaN), cdc::kDepthCodeInvalid);
  EXPECT_EQ(cdc::EncodeDepthMetres(-kInf), cdc::kDepthCodeTooNear);
  EXPECT_EQ(cdc::EncodeDepthMetres(kInf), cdc::kDepthCodeTooFar);
  EXPECT_EQ(cdc::EncodeDepthMetres(0.0f), cdc::kDepthCodeInvalid);
  EXPECT_EQ(cdc::EncodeDepthMetres(-0.0f), cdc::kDepthCodeInvalid);
  EXPECT_EQ(cdc::EncodeDepthMetres(-2.5f), cdc::kDepthCodeInvalid);
  EXPECT_TRUE(std::isnan(cdc::DecodeDepthCode(0)));
  EXPECT_EQ(cdc::DecodeDepthCode(1), -kInf);
  EXPECT_EQ(cdc::DecodeDepthCode(65535), kInf);
}

TEST(DepthCodec, RoundsHalfUpToMillimetresAndClamps) {
  EXPECT_EQ(cdc::EncodeDepthMetres(1.0f), 1000);
  EXPECT_EQ(cdc::EncodeDepthMetres(3.25f), 3250);
  EXPECT_EQ(cdc::EncodeDepthMetres(0.0004f), 2);     // below the smallest code: clamped to 2 mm
  EXPECT_EQ(cdc::EncodeDepthMetres(0.0015f), 2);     // 1.500000013 mm rounds to 2
  EXPECT_EQ(cdc::EncodeDepthMetres(2.0005f), 2000);  // float(2.0005) = 2.00049996 m: below the half
  EXPECT_EQ(cdc::EncodeDepthMetres(65.534f), 65534);
  EXPECT_EQ(cdc::EncodeDepthMetres(65.5345f), 65535);  // beyond the format's range: +Inf
  EXPECT_EQ(cdc::EncodeDepthMetres(1000.0f), 65535);
  EXPECT_EQ(cdc::DecodeDepthCode(1000), 1.0f);
  EXPECT_EQ(cdc::DecodeDepthCode(2), 0.002f);
}

TEST(DepthCodec, UsesTheExactValueOfTheFloatNotFloat32Arithmetic) {
  // float(0.0025) = 0.00249999994412...: exactly 2.4999999441 mm, which rounds to 2. Float32 arithmetic would
  // round 0.0025f * 1000 to 2.5f first and give 3: the documented conversion is the exact one.
  ASSERT_LT(static_cast<double>(0.0025f), 0.0025);
  EXPECT_EQ(cdc::EncodeDepthMetres(0.0025f), 2);
  // float(1.2345) = 1.23450005054...: 1234.50005 mm rounds up to 1235.
  EXPECT_EQ(cdc::EncodeDepthMetres(1.2345f), 1235);
}

TEST(DepthCodec, DecodeOfEncodeIsWithinHalfAMillimetre) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> dist(0.002f, 65.5f);
  for (int i = 0; i < 100000; ++i) {
    const float d = dist(rng);
    EXPECT_NEAR(cdc::DecodeDepthCode(cdc::EncodeDepthMetres(d)), d, 0.0005 + 1e-6) << d;
  }
}

TEST(DepthCodec, EveryValidCodeRoundTripsThroughMetres) {
  for (uint32_t code = cdc::kDepthCodeMinValid; code <= cdc::kDepthCodeMaxValid; ++code) {
    ASSERT_EQ(cdc::EncodeDepthMetres(cdc::DecodeDepthCode(static_cast<uint16_t>(code))), code);
  }
  for (uint16_t code : {cdc::kDepthCodeInvalid, cdc::kDepthCodeTooNear, cdc::kDepthCodeTooFar}) {
    EXPECT_EQ(cdc::EncodeDepthMetres(cdc::DecodeDepthCode(code)), code);
  }
}

TEST(DepthCodec, VectorisedImageEncodingEqualsPerPixelEncoding) {
  const uint32_t w = 37, h = 11;  // odd width exercises the vector loop's remainder
  const size_t stride = 40 * sizeof(float);
  std::vector<float> img(40 * h, 123.0f);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> dist(-1.0f, 70.0f);
  const float specials[] = {kNaN, kInf, -kInf, 0.0f, -0.0f, 0.0015f, 0.0025f, 65.5345f, 2.0005f};
  for (uint32_t r = 0; r < h; ++r) {
    for (uint32_t c = 0; c < w; ++c) {
      img[r * 40 + c] = (c % 5 == 0) ? specials[(r + c) % 9] : dist(rng);
    }
  }
  std::vector<uint16_t> codes(w * h, 7);
  cdc::EncodeDepthImage(img.data(), w, h, stride, codes.data());
  for (uint32_t r = 0; r < h; ++r) {
    for (uint32_t c = 0; c < w; ++c) {
      ASSERT_EQ(codes[r * w + c], cdc::EncodeDepthMetres(img[r * 40 + c])) << r << "," << c;
    }
  }
}

TEST(Crc32, MatchesTheStandardCheckValue) {
  const char* text = "123456789";
  EXPECT_EQ(cdc::Crc32(text, std::strlen(text)), 0xCBF43926u);
}

TEST(RecordLayout, HasTheDocumentedOffsetsAt320x240) {
  cdc::LayoutParams p{320, 240, 136, 128, 128};
  const cdc::RecordLayout l = cdc::RecordLayout::Compute(p);
  EXPECT_EQ(l.knots_offset, 312u);
  EXPECT_EQ(l.ctrl_offset, 312u + 136 * 8);
  EXPECT_EQ(l.yaw_offset, 1400u + 128 * 24);
  EXPECT_EQ(l.depth_offset, 4472u + 128 * 8);
  EXPECT_EQ(l.padding_offset, 5496u + 320 * 240 * 2);
  EXPECT_EQ(l.record_size, 159104u);
  EXPECT_EQ(l.crc_offset, 159100u);
  EXPECT_EQ(l.record_size % 8, 0u);
  const std::string json = l.ToJson();
  EXPECT_NE(json.find("[\"depth_code\",\"<u2\",[240,320],5496]"), std::string::npos) << json;
  EXPECT_NE(json.find("[\"crc32\",\"<u4\",[],159100]"), std::string::npos) << json;
}

TEST(RecordLayout, RejectsImpossibleDimensions) {
  EXPECT_THROW(cdc::RecordLayout::Compute({0, 10, 20, 10, 0}), std::invalid_argument);
  EXPECT_THROW(cdc::RecordLayout::Compute({10, 10, 20, 1, 0}), std::invalid_argument);
  EXPECT_THROW(cdc::RecordLayout::Compute({10, 10, 5, 10, 0}), std::invalid_argument);
}

cdc::ShardHeader MakeHeader() {
  cdc::ShardHeader h;
  const cdc::RecordLayout l = cdc::RecordLayout::Compute({64, 48, 40, 32, 32});
  h.record_size = l.record_size;
  h.image_width = 64;
  h.image_height = 48;
  h.max_knots = 40;
  h.max_ctrl_pts = 32;
  h.max_yaw_pts = 32;
  h.shard_index = 5;
  h.camera_fx_px = 38.72;
  h.layout_json = l.ToJson();
  return h;
}

TEST(ShardHeader, RoundTripsThroughBytes) {
  const cdc::ShardHeader h = MakeHeader();
  const std::vector<uint8_t> bytes = cdc::SerializeShardHeader(h);
  ASSERT_EQ(bytes.size(), cdc::kHeaderSize);
  const cdc::ShardHeader back = cdc::ParseShardHeader(bytes.data(), bytes.size(), "x");
  EXPECT_EQ(back.record_size, h.record_size);
  EXPECT_EQ(back.shard_index, 5u);
  EXPECT_EQ(back.camera_fx_px, 38.72);
  EXPECT_EQ(back.layout_json, h.layout_json);
}

void ExpectFormatError(const std::vector<uint8_t>& bytes, const std::string& needle) {
  try {
    cdc::ParseShardHeader(bytes.data(), bytes.size(), "f.qdr");
    FAIL() << "no error, expected: " << needle;
  } catch (const cdc::FormatError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(ShardHeader, RejectsForeignCorruptedAndOtherVersionHeaders) {
  std::vector<uint8_t> bytes = cdc::SerializeShardHeader(MakeHeader());
  std::vector<uint8_t> foreign = bytes;
  std::memcpy(foreign.data(), "\x89PNG\r\n\x1a\n", 8);
  ExpectFormatError(foreign, "f.qdr: not a quad_il record shard");
  std::vector<uint8_t> version = bytes;
  version[8] = 2;
  ExpectFormatError(version, "record format version 2 is not supported (this reader reads version 1)");
  std::vector<uint8_t> flipped = bytes;
  flipped[200] ^= 0x01;
  ExpectFormatError(flipped, "header CRC mismatch");
  ExpectFormatError(std::vector<uint8_t>(bytes.begin(), bytes.begin() + 1000), "truncated header");
}

TEST(ShardHeader, RejectsALayoutThatDiffersFromTheVersionsLayout) {
  cdc::ShardHeader h = MakeHeader();
  h.layout_json.replace(h.layout_json.find("depth_code"), 10, "depth_kode");
  const std::vector<uint8_t> bytes = cdc::SerializeShardHeader(h);
  ExpectFormatError(bytes, "differs from format version 1's layout");
}

TEST(ShardFileName, IsZeroPadded) { EXPECT_EQ(cdc::ShardFileName(12), "shard_000012.qdr"); }

}  // namespace
