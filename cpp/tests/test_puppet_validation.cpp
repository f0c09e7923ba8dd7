// Tests of the puppet's validation (puppet.hpp) and of the checksum over the whole file
// (puppet_io.hpp): each wrong field refused with its name, its value and what was expected.
#include <doctest/doctest.h>

#include "puppet_arrays.hpp"
#include "throws_with.hpp"

#include "voicepuppet/limits.hpp"
#include "voicepuppet/puppet.hpp"
#include "voicepuppet/puppet_io.hpp"

#include <cmath>
#include <cstring>
#include <functional>
#include <stdexcept>
#include <string>

using namespace voicepuppet;
using voicepuppet::testing::arr;
using voicepuppet::testing::tiny_puppet;
using voicepuppet::testing::throws_with;

namespace {

void refused(const PuppetFile& f, const std::string& what) {
  CAPTURE(what);
  CHECK(throws_with<std::invalid_argument>([&] { Puppet p(f); }, what));
}

/// `bytes` with the version 3 checksum (bytes 0..23, 28..31 and the payload) recomputed.
std::string with_crc(std::string bytes) {
  std::uint32_t crc = crc32(bytes.data(), 24);
  crc = crc32(bytes.data() + 28, 4, crc);
  crc = crc32(bytes.data() + 32, bytes.size() - 32, crc);
  std::memcpy(&bytes[24], &crc, 4);
  return bytes;
}

}  // namespace

TEST_CASE("validation: rates, sizes and the pose outside their ranges are refused with the value") {
  PuppetFile f = tiny_puppet();
  f.arrays["fps"] = arr({1}, {1e9});
  refused(f, "puppet fps = 1e+09 is outside [1, 1000]");
  f.arrays["fps"] = arr({1}, {0.5});
  refused(f, "puppet fps = 0.5 is outside [1, 1000]");
  refused(tiny_puppet(40), "face/mean_pose[0] (log scale) = 40 is outside [-14, 14]");
  refused(tiny_puppet(0, 0, 1e9), "face/mean_pose[2] (x translation, px) = 1e+09 is outside");
  f = tiny_puppet();
  f.arrays["hmm/part0/face_means"] = arr({2, 2}, {0, 0, 4e7, 0});
  refused(f, "puppet part 0 state 1 puts point 2 at 4e+07 px, outside [-1e+06, 1e+06]");
  f = tiny_puppet();
  f.arrays["face/part0/basis"] = arr({1, 6}, {0, 0, 0, 0, 0, 2});
  refused(f, "'face/part0/basis' must have orthonormal rows");
  f = tiny_puppet();
  f.arrays["hmm/part0/vocal_means"] = arr({2, 2}, {-1, 0, 1e7, 0});
  refused(f, "vocal_means' largest |value| = 1e+07 is outside [0, 1e+06]");
  f = tiny_puppet();
  f.arrays["audio/mean"] = arr({kMaxDims + 1}, std::vector<double>(kMaxDims + 1, 0.0));
  f.arrays["audio/std"] = arr({kMaxDims + 1}, std::vector<double>(kMaxDims + 1, 1.0));
  refused(f, "audio columns (audio/mean without deltas) = 1001 is outside [1, 1000]");
  f = tiny_puppet();
  f.metadata = std::string(100, '[');
  refused(f, "nests arrays and objects deeper than 64");
  f.metadata = "{\"a\": \"\xff\"}";
  refused(f, "metadata is not valid UTF-8");
}

TEST_CASE("validation: probabilities and covariances are named by their array") {
  PuppetFile f = tiny_puppet();
  f.arrays["hmm/part0/transmat"] = arr({2, 2}, {0.5, 0.1, 0, 1});
  refused(f, "'hmm/part0/startprob and hmm/part0/transmat' is not valid: transmat row 0 must sum to 1");
  f = tiny_puppet();
  f.arrays["hmm/part0/startprob"] = arr({2}, {1.5, -0.5});
  refused(f, "startprob has negative entries");
  f = tiny_puppet();
  f.arrays["hmm/part0/face_covars"] = arr({2, 2, 2}, {1, 0.2, 0.2, 0.5, -1, 0, 0, -1});
  refused(f, "'hmm/part0/face_covars' is not valid: covars for state 1 is not positive definite");
  f = tiny_puppet();
  f.arrays["hmm/part0/face_covars"] = arr({2, 2, 2}, {1, 0.2, 0.3, 0.5, 0.3, 0, 0, 0.1});
  refused(f, "'hmm/part0/face_covars' is not valid: covars for state 0");
  f = tiny_puppet();
  f.arrays["hmm/part0/vocal_covars"] = arr({2, 2, 2}, {1, 2, 2, 1, 1, 0, 0, 1});
  refused(f, "'hmm/part0/vocal_covars' is not valid: covars[0] is not positive definite");
  f = tiny_puppet();
  f.arrays["hmm/part0/vocal_covars"] = arr({2, 2}, {0.2, 1, 0, 1});
  refused(f, "'hmm/part0/vocal_covars' is not valid: diag covars must be positive");
  f = tiny_puppet();
  f.arrays["hmm/part0/vocal_means"] = arr({2, 3}, {-1, 0, 0, 1, 0, 0});
  refused(f, "'hmm/part0/vocal_means' must be float64 of shape (2, 2), got float64 (2, 3)");
}

TEST_CASE("validation: output rates and frame counts are limited before anything is allocated") {
  const Puppet p(tiny_puppet());
  const RowMatrixXd raw = RowMatrixXd::Zero(10, 2);
  AnimateOptions o;
  o.fps = 1e9;
  CHECK(throws_with<std::invalid_argument>([&] { p.animate(raw, o); }, "output fps = 1e+09 is outside [1, 1000]"));
  o.fps = 1000;
  CHECK(p.animate(raw, o).points.rows() > 300);  // 10 frames at 30 fps, at 1000
  const IndexMatrix states = IndexMatrix::Zero(400'000, 1);  // 1.3e7 frames at 1000 fps
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(states, 30, 1000); },
                                           "is outside [1, 10000000]"));
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(states.topRows(10), 1e9, 30); },
                                           "states_fps = 1e+09 is outside [1, 1000]"));
}

TEST_CASE("validation: an animation beyond the pixel range is refused, not returned") {
  PuppetFile f = tiny_puppet();
  f.arrays["hmm/part0/face_means"] = arr({2, 2}, {0, 0, 4, 1e9});  // state 1 moves 1e9 a frame
  const Puppet p(f);
  const IndexMatrix states = IndexMatrix::Ones(10, 1);
  CHECK(throws_with<std::invalid_argument>([&] { p.animate_states(states, 30); }, "the animation puts point 2 of frame"));
  CHECK(Puppet(tiny_puppet()).animate_states(states, 30).points.cwiseAbs().maxCoeff() < 100);
}

TEST_CASE("format 3: the checksum covers the header; versions 1 and 2 keep their payload check") {
  const PuppetFile f = tiny_puppet();
  const std::string bytes = encode_puppet(f);
  CHECK(static_cast<int>(bytes[8]) == 3);
  for (const std::size_t at : {8, 12, 16, 28}) {  // version, flags, payload size, reserved
    std::string changed = bytes;
    changed[at] ^= 1;
    CAPTURE(at);
    CHECK(throws_with<std::invalid_argument>([&] { decode_puppet(changed); }, at == 16 ? "" : "checksum mismatch"));
  }
  std::string flagged = bytes;
  flagged[12] = 1;
  CHECK(throws_with<std::invalid_argument>([&] { decode_puppet(with_crc(flagged)); }, "header flags 1"));
  // a version 1 file: the same payload, its CRC alone in the header
  std::string old = bytes;
  old[8] = 1;
  const std::uint32_t crc = crc32(old.data() + 32, old.size() - 32);
  std::memcpy(&old[24], &crc, 4);
  const PuppetFile g = decode_puppet(old);
  CHECK(g.arrays.size() == f.arrays.size());
  old[12] = 1;  // the flags of an old file are not covered by its checksum, but must be 0
  CHECK(throws_with<std::invalid_argument>([&] { decode_puppet(old); }, "header flags 1"));
  std::string names = bytes;
  const std::size_t at = names.find("audio/mean");
  names[at] = '\xff';
  CHECK(throws_with<std::invalid_argument>([&] { decode_puppet(with_crc(names)); }, "array name is not valid UTF-8"));
}
