// Minimal NumPy .npy (format 1.0/2.0, C order, little-endian) reading and writing, for the parity fixtures
// and benchmark frames that the Python side writes with numpy.save and reads with numpy.load. Supported
// dtypes: <f4, <f8, <i4, <i8. Written here because no C++ npy library is packaged on this platform; the
// format is a short text header followed by the raw array (numpy's NEP 1).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace quad_policy {

class NpyError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct NpyArray {
  std::string dtype;               // "<f4", "<f8", "<i4" or "<i8"
  std::vector<std::size_t> shape;  // empty for a scalar
  std::vector<char> bytes;         // C order

  std::size_t size() const;
  std::size_t item_size() const;
  // The elements converted to double / float (any supported dtype).
  std::vector<double> as_double() const;
  std::vector<float> as_float() const;

  static NpyArray FromDouble(const std::vector<double>& values, const std::vector<std::size_t>& shape);
  static NpyArray FromFloat(const std::vector<float>& values, const std::vector<std::size_t>& shape);
  static NpyArray FromInt32(const std::vector<int32_t>& values, const std::vector<std::size_t>& shape);
};

// Throws NpyError naming the file and the problem (unsupported dtype, Fortran order, truncated data, ...).
NpyArray ReadNpy(const std::string& path);
void WriteNpy(const std::string& path, const NpyArray& array);

}  // namespace quad_policy
