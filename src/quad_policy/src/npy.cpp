#include "quad_policy/npy.h"

#include <cstring>
#include <fstream>
#include <regex>
#include <sstream>

namespace quad_policy {

namespace {

constexpr char kMagic[] = "\x93NUMPY";
constexpr std::size_t kMagicLen = 6;

std::size_t ItemSize(const std::string& dtype) {
  if (dtype == "<f4" || dtype == "<i4") return 4;
  if (dtype == "<f8" || dtype == "<i8") return 8;
  return 0;
}

template <typename T>
std::vector<T> Convert(const NpyArray& a) {
  std::vector<T> out(a.size());
  const char* p = a.bytes.data();
  for (std::size_t i = 0; i < out.size(); ++i) {
    if (a.dtype == "<f4") {
      float v;
      std::memcpy(&v, p + 4 * i, 4);
      out[i] = static_cast<T>(v);
    } else if (a.dtype == "<f8") {
      double v;
      std::memcpy(&v, p + 8 * i, 8);
      out[i] = static_cast<T>(v);
    } else if (a.dtype == "<i4") {
      int32_t v;
      std::memcpy(&v, p + 4 * i, 4);
      out[i] = static_cast<T>(v);
    } else {
      int64_t v;
      std::memcpy(&v, p + 8 * i, 8);
      out[i] = static_cast<T>(v);
    }
  }
  return out;
}

template <typename T>
NpyArray Make(const std::vector<T>& values, const std::vector<std::size_t>& shape, const char* dtype) {
  NpyArray a;
  a.dtype = dtype;
  a.shape = shape;
  if (a.size() != values.size()) {
    throw NpyError("npy: shape holds " + std::to_string(a.size()) + " elements, got " +
                   std::to_string(values.size()));
  }
  a.bytes.resize(values.size() * sizeof(T));
  std::memcpy(a.bytes.data(), values.data(), a.bytes.size());
  return a;
}

}  // namespace

std::size_t NpyArray::size() const {
  std::size_t n = 1;
  for (std::size_t d : shape) n *= d;
  return n;
}

std::size_t NpyArray::item_size() const { return ItemSize(dtype); }

std::vector<double> NpyArray::as_double() const { return Convert<double>(*this); }
std::vector<float> NpyArray::as_float() const { return Convert<float>(*this); }

NpyArray NpyArray::FromDouble(const std::vector<double>& values, const std::vector<std::size_t>& shape) {
  return Make(values, shape, "<f8");
}
NpyArray NpyArray::FromFloat(const std::vector<float>& values, const std::vector<std::size_t>& shape) {
  return Make(values, shape, "<f4");
}
NpyArray NpyArray::FromInt32(const std::vector<int32_t>& values, const std::vector<std::size_t>& shape) {
  return Make(values, shape, "<i4");
}

NpyArray ReadNpy(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw NpyError(path + ": cannot open");
  char head[10];
  if (!f.read(head, 8) || std::memcmp(head, kMagic, kMagicLen) != 0)
    throw NpyError(path + ": not an .npy file");
  const int major = static_cast<unsigned char>(head[6]);
  uint32_t header_len = 0;
  if (major == 1) {
    unsigned char b[2];
    if (!f.read(reinterpret_cast<char*>(b), 2)) throw NpyError(path + ": truncated header");
    header_len = b[0] | (b[1] << 8);
  } else if (major == 2 || major == 3) {
    unsigned char b[4];
    if (!f.read(reinterpret_cast<char*>(b), 4)) throw NpyError(path + ": truncated header");
    header_len = b[0] | (b[1] << 8) | (b[2] << 16) | (static_cast<uint32_t>(b[3]) << 24);
  } else {
    throw NpyError(path + ": unsupported .npy version " + std::to_string(major));
  }
  std::string header(header_len, '\0');
  if (!f.read(header.data(), header_len)) throw NpyError(path + ": truncated header");
  std::smatch m;
  NpyArray a;
  if (!std::regex_search(header, m, std::regex("'descr':\\s*'([^']*)'"))) throw NpyError(path + ": no descr");
  a.dtype = m[1];
  if (ItemSize(a.dtype) == 0) {
    throw NpyError(path + ": unsupported dtype '" + a.dtype + "' (supported: <f4, <f8, <i4, <i8)");
  }
  if (!std::regex_search(header, m, std::regex("'fortran_order':\\s*(True|False)"))) {
    throw NpyError(path + ": no fortran_order");
  }
  if (m[1] == "True") throw NpyError(path + ": Fortran-ordered arrays are not supported");
  if (!std::regex_search(header, m, std::regex("'shape':\\s*\\(([^)]*)\\)")))
    throw NpyError(path + ": no shape");
  std::stringstream dims(m[1].str());
  std::string item;
  while (std::getline(dims, item, ',')) {
    if (item.find_first_not_of(" \t") == std::string::npos) continue;
    a.shape.push_back(static_cast<std::size_t>(std::stoull(item)));
  }
  a.bytes.resize(a.size() * a.item_size());
  if (!f.read(a.bytes.data(), static_cast<std::streamsize>(a.bytes.size()))) {
    throw NpyError(path + ": truncated data (expected " + std::to_string(a.bytes.size()) + " bytes)");
  }
  return a;
}

void WriteNpy(const std::string& path, const NpyArray& array) {
  if (ItemSize(array.dtype) == 0) throw NpyError(path + ": unsupported dtype '" + array.dtype + "'");
  if (array.bytes.size() != array.size() * array.item_size()) throw NpyError(path + ": data size mismatch");
  // Python tuple syntax: "()", "(4,)", "(2, 3)".
  std::string shape;
  for (std::size_t i = 0; i < array.shape.size(); ++i)
    shape += (i ? ", " : "") + std::to_string(array.shape[i]);
  if (array.shape.size() == 1) shape += ",";
  std::string header = "{'descr': '" + array.dtype + "', 'fortran_order': False, 'shape': (" + shape + "), }";
  // Version 1.0: magic (6) + version (2) + length (2) + header, padded with spaces to a multiple of 64, '\n'
  // last.
  const std::size_t unpadded = kMagicLen + 2 + 2 + header.size() + 1;
  header.append((64 - unpadded % 64) % 64, ' ');
  header.push_back('\n');
  if (header.size() > 65535) throw NpyError(path + ": header too long");
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw NpyError(path + ": cannot create");
  f.write(kMagic, kMagicLen);
  const char version[2] = {1, 0};
  f.write(version, 2);
  const unsigned char len[2] = {static_cast<unsigned char>(header.size() & 0xff),
                                static_cast<unsigned char>(header.size() >> 8)};
  f.write(reinterpret_cast<const char*>(len), 2);
  f.write(header.data(), static_cast<std::streamsize>(header.size()));
  f.write(array.bytes.data(), static_cast<std::streamsize>(array.bytes.size()));
  if (!f) throw NpyError(path + ": write failed");
}

}  // namespace quad_policy
