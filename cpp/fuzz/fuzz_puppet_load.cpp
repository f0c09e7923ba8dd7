// Coverage-guided fuzz target for the puppet loader (libFuzzer, with AddressSanitizer and
// UndefinedBehaviorSanitizer): the input is taken as a .vpp file, its checksum made valid so
// that mutations reach the parser and the meaning checks rather than stopping at the CRC, then
// decoded, validated (Puppet's constructor) and, if it loads, animated from a few frames of
// fixed features. Every outcome must be a loaded puppet with a finite animation or a
// std::invalid_argument; any other exception, a crash, a leak or a sanitizer report is a bug.
// Built by -DVOICEPUPPET_FUZZ=ON with clang; run by .ci/fuzz.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>

#include "voicepuppet/puppet.hpp"
#include "voicepuppet/puppet_io.hpp"

namespace {

constexpr std::size_t kHeaderSize = 32, kCrcOffset = 24, kVersionOffset = 8;

// The checksum a writer would have stored (puppet_io.hpp: version 3 covers the header without
// its checksum field and the payload; versions 1 and 2 the payload only).
void make_checksum_valid(std::string& bytes) {
  if (bytes.size() < kHeaderSize) return;
  std::uint32_t version = 0;
  std::memcpy(&version, bytes.data() + kVersionOffset, sizeof version);
  const char* p = bytes.data();
  std::uint32_t crc;
  if (version < 3) {
    crc = voicepuppet::crc32(p + kHeaderSize, bytes.size() - kHeaderSize);
  } else {
    crc = voicepuppet::crc32(p, kCrcOffset);
    crc = voicepuppet::crc32(p + kCrcOffset + 4, kHeaderSize - kCrcOffset - 4, crc);
    crc = voicepuppet::crc32(p + kHeaderSize, bytes.size() - kHeaderSize, crc);
  }
  std::memcpy(&bytes[kCrcOffset], &crc, sizeof crc);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string bytes(reinterpret_cast<const char*>(data), size);
  make_checksum_valid(bytes);
  try {
    voicepuppet::Puppet puppet(voicepuppet::decode_puppet(bytes, "fuzz input"));
    // Twelve frames of a smooth pattern in the puppet's own feature space.
    voicepuppet::RowMatrixXd features(12, puppet.n_features());
    for (Eigen::Index t = 0; t < features.rows(); ++t) {
      for (Eigen::Index j = 0; j < features.cols(); ++j) features(t, j) = std::sin(0.3 * t + j);
    }
    const voicepuppet::AnimateResult out = puppet.animate(features);
    if (!out.points.allFinite()) std::abort();  // animate promised finite landmarks
  } catch (const std::invalid_argument&) {
    // refused, naming what is wrong: the expected outcome for a damaged file
  }
  return 0;
}
