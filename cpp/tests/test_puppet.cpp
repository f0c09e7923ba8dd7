// Tests of puppet_io.hpp (the container: CRC-32 check value, round trip, every corruption named)
// and puppet.hpp (analysis and synthesis against the kernels it composes, computed by hand).
#include <doctest/doctest.h>

#include "puppet_arrays.hpp"
#include "throws_with.hpp"

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/puppet.hpp"
#include "voicepuppet/puppet_io.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <stdexcept>
#include <string>

using namespace voicepuppet;

namespace {

using voicepuppet::testing::arr;
using voicepuppet::testing::tiny_puppet;
using voicepuppet::testing::throws_with;

}  // namespace

TEST_CASE("crc32 matches the standard check value and continues across chunks") {
  const std::string s = "123456789";
  CHECK(crc32(s.data(), s.size()) == 0xCBF43926u);
  CHECK(crc32(s.data() + 4, 5, crc32(s.data(), 4)) == 0xCBF43926u);
}

TEST_CASE("puppet container round trip keeps metadata, names, shapes, dtypes and values") {
  const PuppetFile f = tiny_puppet();
  const PuppetFile g = decode_puppet(encode_puppet(f));
  CHECK(g.metadata == f.metadata);
  REQUIRE(g.arrays.size() == f.arrays.size());
  for (const auto& [name, a] : f.arrays) {
    const PuppetArray& b = g.at(name);
    CHECK(b.shape == a.shape);
    CHECK(b.dtype == a.dtype);
    CHECK(b.f64 == a.f64);
    CHECK(b.i64 == a.i64);
  }
  const std::string path = "test_puppet_roundtrip.vpp";
  write_puppet_file(path, f);
  CHECK(read_puppet_file(path).metadata == f.metadata);
  std::remove(path.c_str());
}

TEST_CASE("every kind of damaged puppet data is named") {
  const std::string bytes = encode_puppet(tiny_puppet());
  CHECK(throws_with([&] { decode_puppet("GIF89a" + bytes.substr(6)); }, "not a voicepuppet puppet file"));
  CHECK(throws_with([&] { decode_puppet(bytes.substr(0, 20)); }, "truncated"));
  CHECK(throws_with([&] { decode_puppet(bytes.substr(0, bytes.size() - 3)); }, "truncated"));
  std::string flipped = bytes;
  flipped[bytes.size() - 5] ^= 0x40;
  CHECK(throws_with([&] { decode_puppet(flipped); }, "checksum"));
  std::string newer = bytes;
  newer[8] = static_cast<char>(kPuppetFormatVersion + 1);
  CHECK(throws_with([&] { decode_puppet(newer); }, "newer"));
  CHECK(throws_with([&] { decode_puppet(bytes + "xx"); }, "trailing"));
  CHECK(throws_with([&] { read_puppet_file("/nonexistent/dir/p.vpp"); }, "cannot open"));
  CHECK(throws_with([&] { write_puppet_file("/nonexistent/dir/p.vpp", tiny_puppet()); }, "not writable"));
}

TEST_CASE("a puppet with missing or inconsistent arrays is refused with the array's name") {
  PuppetFile f = tiny_puppet();
  f.arrays.erase("hmm/part0/vocal_means");
  CHECK(throws_with([&] { Puppet p(f); }, "vocal_means"));
  f = tiny_puppet();
  f.arrays["hmm/part0/transmat"] = arr({2, 2}, {0.5, 0.1, 0, 1});
  CHECK(throws_with([&] { Puppet p(f); }, "transmat"));
  f = tiny_puppet();
  f.arrays["face/part0/basis"] = arr({1, 4}, {0, 0, 0, 1});
  CHECK(throws_with([&] { Puppet p(f); }, "face/part0/basis"));
}

TEST_CASE("animate equals standardise, Viterbi, trajectory and the pose, composed by hand") {
  const double ls = std::log(2.0), th = 0.5, tx = 10, ty = -3;
  const Puppet puppet(tiny_puppet(ls, th, tx, ty));
  // Audio: 6 frames near state 0's vocal mean, then 6 near state 1's (after standardisation).
  RowMatrixXd raw(12, 2);
  for (Index t = 0; t < 12; ++t) {
    const double z0 = t < 6 ? -1.0 : 1.0;
    raw(t, 0) = 1 + 2 * z0;          // mean + std·z
    raw(t, 1) = -1 + 0.5 * 0.1 * t;  // small, uninformative
  }
  const AnimateResult r = puppet.animate(raw);
  for (Index t = 0; t < 12; ++t) CHECK(r.states(t, 0) == (t < 6 ? 0 : 1));

  const RowMatrixXd z = puppet.standardize(raw);
  const VectorXi no_lengths;
  const auto& part = puppet.part(0);
  const ViterbiResult vit = viterbi(puppet.vocal_log_density(z), part.startprob, part.transmat, no_lengths);
  CHECK(r.log_likelihood == doctest::Approx(vit.log_probability));
  const RowMatrixXd y = solve_trajectory(puppet.trajectory_model(), vit.path);
  REQUIRE(r.face.rows() == 12);
  for (Index t = 0; t < 12; ++t) {
    CHECK(r.face(t, 0) == doctest::Approx(y(t, 0)));
    // Point 2 is (0, 1 + y) in the shape frame; the pose scales by 2, rotates by θ, translates.
    const double sx = 0, sy = 1 + y(t, 0);
    CHECK(r.points(t, 4) == doctest::Approx(2 * (std::cos(th) * sx - std::sin(th) * sy) + tx));
    CHECK(r.points(t, 5) == doctest::Approx(2 * (std::sin(th) * sx + std::cos(th) * sy) + ty));
    // Point 0 does not move.
    CHECK(r.points(t, 0) == doctest::Approx(2 * std::cos(th) * -1 + tx));
  }
  // The face moves from state 0's mean towards state 1's.
  CHECK(r.face(0, 0) < 0.5);
  CHECK(r.face(11, 0) > 3.0);

  // Edited states: the same sequence gives the same animation; twice the rate gives twice the frames.
  const AnimateResult again = puppet.animate_states(r.states, puppet.fps());
  CHECK((again.points - r.points).cwiseAbs().maxCoeff() < 1e-12);
  CHECK(puppet.animate_states(r.states, puppet.fps(), 60).points.rows() == 24);
  CHECK(puppet.animate(raw, {60, false}).points.rows() == 24);
  CHECK(puppet.animate(raw, {0, true}).points.rows() == 12);

  CHECK(throws_with([&] { puppet.animate(raw.leftCols(1)); }, "feature set"));
  IndexMatrix bad = r.states;
  bad(3, 0) = 7;
  CHECK(throws_with([&] { puppet.animate_states(bad, 30); }, "[0, 2)"));
}

TEST_CASE("regression deltas: a ramp has unit slope inside, edges repeat the end frames") {
  RowMatrixXd x(8, 2);
  for (Index t = 0; t < 8; ++t) {
    x(t, 0) = static_cast<double>(t);
    x(t, 1) = 5.0;
  }
  const RowMatrixXd d = append_deltas(x, 2);
  REQUIRE(d.cols() == 4);
  CHECK((d.leftCols(2) - x).cwiseAbs().maxCoeff() == 0.0);
  for (Index t = 2; t < 6; ++t) CHECK(d(t, 2) == doctest::Approx(1.0));
  // t = 0: (1·(1 − 0) + 2·(2 − 0)) / 10 = 0.5
  CHECK(d(0, 2) == doctest::Approx(0.5));
  CHECK(d.col(3).cwiseAbs().maxCoeff() == 0.0);
  CHECK(append_deltas(x, 0).cols() == 2);
  // A puppet with deltas takes raw features and standardises [x, Δx].
  PuppetFile f = tiny_puppet();
  PuppetArray w;
  w.dtype = PuppetArray::DType::Int64;
  w.shape = {1};
  w.i64 = {1};
  f.arrays["audio/delta_width"] = w;
  f.arrays["audio/mean"] = arr({4}, {1, -1, 0, 0});
  f.arrays["audio/std"] = arr({4}, {2, 0.5, 1, 1});
  f.arrays["hmm/part0/vocal_means"] = arr({2, 4}, {-1, 0, 0, 0, 1, 0, 0, 0});
  f.arrays["hmm/part0/vocal_covars"] = arr({2, 4}, {0.2, 1, 1, 1, 0.2, 1, 1, 1});
  const Puppet p(f);
  CHECK(p.n_features() == 2);
  CHECK(p.standardize(x).cols() == 4);
  CHECK(p.standardize(x)(4, 2) == doctest::Approx(1.0));
}

TEST_CASE("a projected puppet's vocal densities are those of the projection of ±k standardised frames") {
  // Projection of the first column (C = 1) over ±1 frames to one vocal feature:
  // v_t = 0.5·z_{t−1} + 1·z_t − 0.25·z_{t+1} + 0.1, edge frames repeated.
  PuppetFile f = tiny_puppet();
  PuppetArray k, c;
  k.dtype = c.dtype = PuppetArray::DType::Int64;
  k.shape = c.shape = {1};
  k.i64 = {1};
  c.i64 = {1};
  f.arrays["audio/projection_context"] = k;
  f.arrays["audio/projection_columns"] = c;
  f.arrays["audio/projection"] = arr({3, 1}, {0.5, 1, -0.25});
  f.arrays["audio/projection_offset"] = arr({1}, {0.1});
  f.arrays["hmm/part0/vocal_means"] = arr({2, 1}, {-1, 1});
  f.arrays["hmm/part0/vocal_covars"] = arr({2, 1, 1}, {0.3, 0.3});
  const Puppet p(f);
  CHECK(p.projected());
  CHECK(p.projection_context() == 1);
  CHECK(p.n_vocal() == 1);
  CHECK(p.n_features() == 2);
  RowMatrixXd raw(4, 2);
  raw << 3, 0, 1, 5, -1, 2, 5, -3;  // standardised first column: 1, 0, -1, 2
  const RowMatrixXd z = p.standardize(raw);
  const RowMatrixXd v = p.project(z);
  REQUIRE(v.rows() == 4);
  REQUIRE(v.cols() == 1);
  const double want[4] = {0.5 * 1 + 1 - 0.25 * 0 + 0.1, 0.5 * 1 + 0 + 0.25 + 0.1, 0 - 1 - 0.5 + 0.1,
                          -0.5 + 2 - 0.5 + 0.1};
  const RowMatrixXd lb = p.vocal_log_density(z);
  for (Index t = 0; t < 4; ++t) {
    CHECK(v(t, 0) == doctest::Approx(want[t]).epsilon(1e-14));
    for (Index n = 0; n < 2; ++n) {
      const double d = want[t] - (n == 0 ? -1.0 : 1.0);
      CHECK(lb(t, n) == doctest::Approx(-0.5 * (std::log(2 * M_PI * 0.3) + d * d / 0.3)).epsilon(1e-12));
    }
  }
  CHECK(p.animate(raw).states.rows() == 4);
  // Unprojected puppets: project is the identity; a wrong width is named.
  const Puppet plain(tiny_puppet());
  CHECK(!plain.projected());
  CHECK((plain.project(plain.standardize(raw)) - plain.standardize(raw)).cwiseAbs().maxCoeff() == 0.0);
  CHECK(throws_with([&] { p.project(z.leftCols(1)); }, "columns"));
  // Inconsistent projection arrays are refused with their names.
  PuppetFile g = f;
  g.arrays["audio/projection"] = arr({2, 1}, {0.5, 1});
  CHECK(throws_with([&] { Puppet q(g); }, "audio/projection"));
  g = f;
  g.arrays["audio/projection_columns"].i64 = {3};
  CHECK(throws_with([&] { Puppet q(g); }, "projection_columns"));
  g = f;
  g.arrays["audio/projection_context"].i64 = {-1};
  CHECK(throws_with([&] { Puppet q(g); }, "projection_context"));
  g = f;
  g.arrays.erase("audio/projection_offset");
  CHECK(throws_with([&] { Puppet q(g); }, "projection_offset"));
  g = f;
  g.arrays["hmm/part0/vocal_means"] = arr({2, 2}, {-1, 0, 1, 0});
  CHECK(throws_with([&] { Puppet q(g); }, "vocal_means"));
}
