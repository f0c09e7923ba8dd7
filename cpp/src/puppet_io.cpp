#include "voicepuppet/puppet_io.hpp"

#include "voicepuppet/limits.hpp"

#include <array>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#if defined(_WIN32)
#include <process.h>
#define VP_GETPID _getpid
#else
#include <unistd.h>
#define VP_GETPID getpid
#endif

namespace voicepuppet {
namespace {

constexpr char kMagic[8] = {'V', 'P', 'U', 'P', 'P', 'E', 'T', '\x1a'};
constexpr std::size_t kHeaderSize = 32;
constexpr std::size_t kCrcOffset = 24;

/// The checksum of a file of format `version` whose header and payload start at `bytes`:
/// versions 1 and 2, the payload's; from 3, the header's (without the checksum field) and the
/// payload's.
std::uint32_t file_crc(const char* bytes, std::uint64_t payload_size, std::uint32_t version) {
  if (version < 3) return crc32(bytes + kHeaderSize, payload_size);
  std::uint32_t crc = crc32(bytes, kCrcOffset);
  crc = crc32(bytes + kCrcOffset + 4, kHeaderSize - kCrcOffset - 4, crc);
  return crc32(bytes + kHeaderSize, payload_size, crc);
}

bool has_guide(const PuppetFile& file) {
  const auto it = file.arrays.lower_bound("guide/");
  return it != file.arrays.end() && it->first.compare(0, 6, "guide/") == 0;
}

static_assert(sizeof(double) == 8, "float64 must be 8 bytes");

bool little_endian() {
  const std::uint16_t one = 1;
  unsigned char b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

template <class T>
void put(std::string& out, T v) {
  char buf[sizeof(T)];
  std::memcpy(buf, &v, sizeof(T));
  out.append(buf, sizeof(T));
}

class Reader {
 public:
  Reader(const std::string& bytes, std::size_t pos, const std::string& source)
      : b_(bytes), pos_(pos), source_(source) {}
  template <class T>
  T get(const char* what) {
    need(sizeof(T), what);
    T v;
    std::memcpy(&v, b_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string bytes(std::size_t n, const char* what) {
    need(n, what);
    std::string s = b_.substr(pos_, n);
    pos_ += n;
    return s;
  }
  void raw(void* dst, std::size_t n, const char* what) {
    need(n, what);
    if (n == 0) return;  // dst may be the null data() of an empty array: memcpy must not see it
    std::memcpy(dst, b_.data() + pos_, n);
    pos_ += n;
  }
  std::size_t pos() const { return pos_; }

 private:
  void need(std::size_t n, const char* what) const {
    if (n > b_.size() - pos_) {
      fail_argument(source_, " is malformed: its payload ends inside ", what, "; the file is damaged");
    }
  }
  const std::string& b_;
  std::size_t pos_;
  const std::string& source_;
};

}  // namespace

std::uint64_t PuppetArray::size() const {
  std::uint64_t n = 1;
  for (auto d : shape) n *= d;
  return n;
}

RowMatrixXd PuppetArray::matrix() const {
  Index rows = 1, cols = 1;
  if (shape.size() == 1) {
    cols = static_cast<Index>(shape[0]);
  } else if (shape.size() >= 2) {
    cols = static_cast<Index>(shape.back());
    rows = static_cast<Index>(size() / std::max<std::uint64_t>(shape.back(), 1));
  }
  RowMatrixXd m(rows, cols);
  for (Index k = 0; k < rows * cols; ++k) {
    m.data()[k] = dtype == DType::Float64 ? f64[static_cast<size_t>(k)] : static_cast<double>(i64[static_cast<size_t>(k)]);
  }
  return m;
}

PuppetArray PuppetArray::from_matrix(const MatrixRef& m) {
  PuppetArray a;
  a.shape = {static_cast<std::uint64_t>(m.rows()), static_cast<std::uint64_t>(m.cols())};
  a.f64.resize(static_cast<size_t>(m.size()));
  Eigen::Map<RowMatrixXd>(a.f64.data(), m.rows(), m.cols()) = m;
  return a;
}

PuppetArray PuppetArray::from_vector(const VectorRef& v) {
  PuppetArray a;
  a.shape = {static_cast<std::uint64_t>(v.size())};
  a.f64.assign(v.data(), v.data() + v.size());
  return a;
}

PuppetArray PuppetArray::from_indices(const IndexVectorRef& v) {
  PuppetArray a;
  a.dtype = DType::Int64;
  a.shape = {static_cast<std::uint64_t>(v.size())};
  a.i64.assign(v.data(), v.data() + v.size());
  return a;
}

const PuppetArray& PuppetFile::at(const std::string& name) const {
  auto it = arrays.find(name);
  if (it == arrays.end()) {
    fail_argument("the puppet has no array '", name, "'; it was written by an incompatible tool");
  }
  return it->second;
}

std::uint32_t crc32(const void* data, std::size_t n, std::uint32_t crc) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  const auto* p = static_cast<const unsigned char*>(data);
  crc = ~crc;
  for (std::size_t i = 0; i < n; ++i) crc = table[(crc ^ p[i]) & 0xFFu] ^ (crc >> 8);
  return ~crc;
}

std::string encode_puppet(const PuppetFile& file) {
  if (!little_endian()) fail_numeric("puppet files are little-endian; big-endian hosts are not supported");
  std::string payload;
  put<std::uint32_t>(payload, static_cast<std::uint32_t>(file.metadata.size()));
  payload += file.metadata;
  put<std::uint32_t>(payload, static_cast<std::uint32_t>(file.arrays.size()));
  for (const auto& [name, a] : file.arrays) {
    if (name.empty() || name.size() > 65535) fail_argument("array names must have 1 to 65535 bytes, got '", name, "'");
    if (a.shape.size() > 255) fail_argument("array '", name, "' has too many dimensions");
    const std::uint64_t n = a.size();
    const bool f = a.dtype == PuppetArray::DType::Float64;
    if ((f ? a.f64.size() : a.i64.size()) != n) {
      fail_argument("array '", name, "' holds ", (f ? a.f64.size() : a.i64.size()), " elements but its shape says ", n);
    }
    put<std::uint16_t>(payload, static_cast<std::uint16_t>(name.size()));
    payload += name;
    put<std::uint8_t>(payload, static_cast<std::uint8_t>(a.dtype));
    put<std::uint8_t>(payload, static_cast<std::uint8_t>(a.shape.size()));
    for (auto d : a.shape) put<std::uint64_t>(payload, d);
    if (f) {
      payload.append(reinterpret_cast<const char*>(a.f64.data()), n * sizeof(double));
    } else {
      payload.append(reinterpret_cast<const char*>(a.i64.data()), n * sizeof(std::int64_t));
    }
  }
  std::string out(kMagic, sizeof(kMagic));
  put<std::uint32_t>(out, kPuppetFormatVersion);
  put<std::uint32_t>(out, 0);
  put<std::uint64_t>(out, payload.size());
  put<std::uint32_t>(out, 0);  // the checksum, filled in below
  put<std::uint32_t>(out, 0);
  out += payload;
  const std::uint32_t crc = file_crc(out.data(), payload.size(), kPuppetFormatVersion);
  std::memcpy(&out[kCrcOffset], &crc, sizeof(crc));
  return out;
}

PuppetFile decode_puppet(const std::string& bytes, const std::string& source) {
  if (!little_endian()) fail_numeric("puppet files are little-endian; big-endian hosts are not supported");
  if (bytes.size() < sizeof(kMagic) || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0) {
    fail_argument(source, " is not a voicepuppet puppet file (wrong magic number); "
                  "make one with `voicepuppet train`");
  }
  if (bytes.size() < kHeaderSize) fail_argument(source, " is truncated (", bytes.size(), " bytes, header is 32)");
  Reader head(bytes, sizeof(kMagic), source);
  const auto version = head.get<std::uint32_t>("the header");
  const auto flags = head.get<std::uint32_t>("the header");
  const auto payload_size = head.get<std::uint64_t>("the header");
  const auto crc = head.get<std::uint32_t>("the header");
  const auto reserved = head.get<std::uint32_t>("the header");
  if (version > kPuppetFormatVersion) {
    fail_argument(source, " has puppet format version ", version, ", newer than this voicepuppet reads (",
                  kPuppetFormatVersion, "); upgrade voicepuppet");
  }
  if (version == 0) fail_argument(source, " has an invalid format version 0; the file is damaged");
  if (bytes.size() - kHeaderSize < payload_size) {
    fail_argument(source, " is truncated: its header announces ", payload_size, " payload bytes but only ",
                  bytes.size() - kHeaderSize, " follow; copy the file again");
  }
  if (bytes.size() - kHeaderSize > payload_size) {
    fail_argument(source, " has ", bytes.size() - kHeaderSize - payload_size, " unexpected trailing bytes; the file is damaged");
  }
  if (file_crc(bytes.data(), payload_size, version) != crc) {
    fail_argument(source, " is corrupted: checksum mismatch; copy the file again or retrain");
  }
  if (flags != 0 || reserved != 0) {
    fail_argument(source, " has header flags ", flags, " and reserved field ", reserved,
                  " where this voicepuppet writes 0 and 0; the file is damaged");
  }
  PuppetFile file;
  Reader r(bytes, kHeaderSize, source);
  const auto meta_len = r.get<std::uint32_t>("the metadata length");
  file.metadata = r.bytes(meta_len, "the metadata");
  check_utf8(file.metadata, source + "'s metadata");
  check_json_depth(file.metadata, source + "'s metadata");
  const auto n_arrays = r.get<std::uint32_t>("the array count");
  for (std::uint32_t k = 0; k < n_arrays; ++k) {
    const auto name_len = r.get<std::uint16_t>("an array name");
    std::string name = r.bytes(name_len, "an array name");
    check_utf8(name, source + "'s array name");
    PuppetArray a;
    const auto dtype = r.get<std::uint8_t>("an array header");
    if (dtype != 1 && dtype != 2) fail_argument(source, " is malformed: array '", name, "' has unknown dtype ", int(dtype));
    a.dtype = static_cast<PuppetArray::DType>(dtype);
    const auto ndim = r.get<std::uint8_t>("an array header");
    std::uint64_t n = 1;
    for (int d = 0; d < ndim; ++d) {
      a.shape.push_back(r.get<std::uint64_t>("an array shape"));
      if (a.shape.back() != 0 && n > (payload_size / 8) / a.shape.back()) {
        fail_argument(source, " is malformed: array '", name, "' is larger than the file");
      }
      n *= a.shape.back();
    }
    if (a.dtype == PuppetArray::DType::Float64) {
      a.f64.resize(n);
      r.raw(a.f64.data(), n * sizeof(double), "array data");
    } else {
      a.i64.resize(n);
      r.raw(a.i64.data(), n * sizeof(std::int64_t), "array data");
    }
    file.arrays.emplace(std::move(name), std::move(a));
  }
  if (r.pos() != bytes.size()) fail_argument(source, " is malformed: bytes left after the last array");
  if (version < 2 && has_guide(file)) {
    fail_argument(source, " has format version ", version, " but holds a guide, which needs version 2 or later; "
                  "the header is damaged");
  }
  return file;
}

void write_puppet_file(const std::string& path, const PuppetFile& file) {
  const std::string bytes = encode_puppet(file);
  const std::string tmp = path + ".tmp-" + std::to_string(VP_GETPID());
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) fail_numeric("cannot write puppet file '", path, "': the folder is missing or not writable");
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.flush();
    if (!out) {
      out.close();
      std::remove(tmp.c_str());
      fail_numeric("writing puppet file '", path, "' failed (disk full?)");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    fail_numeric("cannot move the finished puppet file into place at '", path, "'");
  }
}

PuppetFile read_puppet_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail_argument("cannot open puppet file '", path, "': no such file or not readable");
  std::ostringstream ss;
  ss << in.rdbuf();
  return decode_puppet(ss.str(), "puppet file '" + path + "'");
}

}  // namespace voicepuppet
