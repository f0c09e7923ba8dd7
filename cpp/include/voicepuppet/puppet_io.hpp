#pragma once
/// @file puppet_io.hpp
/// The puppet file (.vpp): one binary container, implemented once here and used from C++ and
/// Python. Layout (all integers little-endian):
///
///   offset  size  field
///   0       8     magic "VPUPPET\x1a"
///   8       4     format version (uint32): 3. Versions 1 and 2 (2: a file with a guide,
///                 arrays guide/... of puppet.hpp) are read too.
///   12      4     flags (uint32, 0)
///   16      8     payload size in bytes (uint64)
///   24      4     CRC-32 (IEEE 802.3 polynomial, as zlib.crc32) of bytes 0..23, 28..31 and the
///                 payload: the whole file but this field (versions 1 and 2: of the payload only)
///   28      4     reserved (0)
///   32      ...   payload:
///                   uint32 metadata length, metadata (UTF-8 JSON text)
///                   uint32 number of arrays, then per array:
///                     uint16 name length, name (UTF-8)
///                     uint8 dtype (1 = float64, 2 = int64), uint8 ndim, uint64 dims[ndim]
///                     the elements, C order
///
/// Files are written atomically (a temporary file beside the target, then a rename), so a
/// reader never sees a half-written puppet.

#include "voicepuppet/types.hpp"

#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace voicepuppet {

/// The format version this voicepuppet writes, the newest it reads.
constexpr std::uint32_t kPuppetFormatVersion = 3;

/// One named n-dimensional array of float64 or int64.
struct PuppetArray {
  enum class DType : std::uint8_t { Float64 = 1, Int64 = 2 };
  DType dtype = DType::Float64;
  std::vector<std::uint64_t> shape;
  std::vector<double> f64;        ///< elements when dtype == Float64
  std::vector<std::int64_t> i64;  ///< elements when dtype == Int64

  std::uint64_t size() const;
  /// A 2-D float64 view as a row-major matrix (1-D arrays are one row, 0-D one element).
  RowMatrixXd matrix() const;
  static PuppetArray from_matrix(const MatrixRef& m);
  static PuppetArray from_vector(const VectorRef& v);
  static PuppetArray from_indices(const IndexVectorRef& v);
};

/// The container: JSON metadata and named arrays.
struct PuppetFile {
  std::string metadata;  ///< UTF-8 JSON text
  std::map<std::string, PuppetArray> arrays;

  /// The array called `name`; throws std::invalid_argument naming it if absent.
  const PuppetArray& at(const std::string& name) const;
};

/// CRC-32 (IEEE, reflected, as zlib.crc32) of `n` bytes, continuing from `crc`.
std::uint32_t crc32(const void* data, std::size_t n, std::uint32_t crc = 0);

/// Serialises to bytes (header + payload).
std::string encode_puppet(const PuppetFile& file);

/// Parses bytes; `source` names the origin in error messages.
/// @throws std::invalid_argument for a file that is not a puppet (bad magic), is truncated,
///         comes from a newer format version, fails its checksum, has non-zero flags or
///         reserved field, or is malformed (including metadata or array names that are not
///         UTF-8, metadata nested deeper than kMaxMetadataDepth, limits.hpp, and a version 1
///         header on a file with a guide).
PuppetFile decode_puppet(const std::string& bytes, const std::string& source = "puppet data");

/// Writes atomically: `path + ".tmp-<pid>"`, flushed, then renamed over `path`.
/// @throws std::runtime_error if the file cannot be written.
void write_puppet_file(const std::string& path, const PuppetFile& file);

/// Reads and validates a puppet file.
/// @throws std::invalid_argument as decode_puppet, or if the file cannot be opened.
PuppetFile read_puppet_file(const std::string& path);

}  // namespace voicepuppet
