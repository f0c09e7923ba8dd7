// Fixed-lag decoding against its definition: the decision for frame s after frame s + L is the
// offline Viterbi / forward-backward answer on the prefix 0 .. s + L (hmm.hpp, an independent
// implementation); with L >= T - 1 it is the offline answer on the whole sequence.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <random>

#include "random_hmm.hpp"
#include "voicepuppet/hmm.hpp"
#include "voicepuppet/streaming.hpp"

using namespace voicepuppet;

namespace {

using testing::Model;
using testing::random_model;

struct Collected {
  VectorXi states;
  RowMatrixXd post;
};

/// Pushes log_b in chunks of `chunk` rows (0: one push) and collects every decided frame.
Collected run(FixedLagDecoder& d, const RowMatrixXd& log_b, Index chunk) {
  const Index T = log_b.rows(), n = log_b.cols();
  Collected c;
  c.states.resize(T);
  c.post.resize(T, n);
  Index next = 0;
  auto take = [&](const DecodedFrames& f) {
    REQUIRE(f.first_frame == next);
    for (Index k = 0; k < f.size(); ++k) {
      c.states[next] = f.states[k];
      c.post.row(next) = f.posteriors.row(k);
      ++next;
    }
  };
  if (chunk <= 0) chunk = T;
  for (Index t = 0; t < T; t += chunk) take(d.push(log_b.middleRows(t, std::min(chunk, T - t))));
  take(d.flush());
  REQUIRE(next == T);
  return c;
}

}  // namespace

TEST_CASE("fixed-lag decoder: lag >= T - 1 gives offline Viterbi and forward-backward") {
  for (double sparsity : {0.0, 0.6}) {
    const Model m = random_model(7, 40, 11, sparsity);
    for (Index chunk : {Index(1), Index(3), Index(0)}) {
      FixedLagDecoder d(m.pi, m.A, 39);
      const Collected c = run(d, m.log_b, chunk);
      const auto vit = viterbi(m.log_b, m.pi, m.A, VectorXi());
      const auto fb = forward_backward(m.log_b, m.pi, m.A, VectorXi());
      CHECK(c.states == vit.path);
      CHECK((c.post - fb.posteriors).cwiseAbs().maxCoeff() < 1e-10);
    }
  }
}

TEST_CASE("fixed-lag decoder: a state that cannot be occupied has posterior exactly 0") {
  Model m = random_model(8, 60, 5);  // enough states for whole SIMD packets
  m.log_b.col(3).setConstant(-std::numeric_limits<double>::infinity());
  m.log_b.col(1).setConstant(-1500.0);
  for (Index lag : {Index(0), Index(5), Index(59)}) {
    FixedLagDecoder d(m.pi, m.A, lag);
    const Collected c = run(d, m.log_b, 7);
    CHECK(c.post.col(3).cwiseAbs().maxCoeff() == 0.0);
    CHECK(c.post.col(1).cwiseAbs().maxCoeff() == 0.0);
  }
}

TEST_CASE("fixed-lag decoder: each decision is the offline answer on the prefix s + L") {
  const Model m = random_model(6, 30, 5, 0.5);
  for (Index lag : {Index(0), Index(1), Index(4)}) {
    FixedLagDecoder d(m.pi, m.A, lag);
    Index next = 0;
    double loglik_prefix = 0;
    for (Index t = 0; t < m.log_b.rows(); ++t) {
      const DecodedFrames f = d.push(m.log_b.middleRows(t, 1));
      const RowMatrixXd prefix = m.log_b.topRows(t + 1);
      loglik_prefix = log_likelihood(prefix, m.pi, m.A, VectorXi());
      CHECK(std::abs(d.log_likelihood() - loglik_prefix) < 1e-9 * std::abs(loglik_prefix));
      if (t < lag) {
        CHECK(f.size() == 0);
        continue;
      }
      REQUIRE(f.size() == 1);
      const Index s = t - lag;
      CHECK(f.first_frame == s);
      const auto vit = viterbi(prefix, m.pi, m.A, VectorXi());
      const auto fb = forward_backward(prefix, m.pi, m.A, VectorXi());
      CHECK(f.states[0] == vit.path[s]);
      CHECK((f.posteriors.row(0) - fb.posteriors.row(s)).cwiseAbs().maxCoeff() < 1e-10);
      CHECK(std::abs(f.posteriors.row(0).sum() - 1.0) < 1e-12);
      ++next;
    }
    // flush: the held-back frames from the whole sequence
    const DecodedFrames rest = d.flush();
    CHECK(rest.first_frame == next);
    CHECK(rest.size() == lag);
    const auto vit = viterbi(m.log_b, m.pi, m.A, VectorXi());
    const auto fb = forward_backward(m.log_b, m.pi, m.A, VectorXi());
    for (Index k = 0; k < rest.size(); ++k) {
      CHECK(rest.states[k] == vit.path[next + k]);
      CHECK((rest.posteriors.row(k) - fb.posteriors.row(next + k)).cwiseAbs().maxCoeff() < 1e-10);
    }
    CHECK(d.frames_pushed() == 0);  // reset for a new stream
  }
}

TEST_CASE("fixed-lag decoder: the chunking does not change the decisions; streams restart") {
  const Model m = random_model(9, 120, 3, 0.3);
  FixedLagDecoder d(m.pi, m.A, 5);
  const Collected one = run(d, m.log_b, 1);
  const Collected all = run(d, m.log_b, 0);  // same object, after its flush
  const Collected seven = run(d, m.log_b, 7);
  CHECK(one.states == all.states);
  CHECK(one.states == seven.states);
  CHECK((one.post - all.post).cwiseAbs().maxCoeff() < 1e-12);
  CHECK((one.post - seven.post).cwiseAbs().maxCoeff() < 1e-12);
}

TEST_CASE("fixed-lag decoder: long streams stay finite (log-space recursion)") {
  // Densities ~ -2000 nats per frame would underflow a linear-space recursion at once.
  Model m = random_model(5, 3000, 8, 0.4);
  m.log_b.array() -= 2000.0;
  FixedLagDecoder d(m.pi, m.A, 3);
  const Collected c = run(d, m.log_b, 50);
  CHECK(c.post.allFinite());
  const auto vit = viterbi(m.log_b, m.pi, m.A, VectorXi());
  // frames decided with 3 frames of look-ahead agree with the offline path on most frames
  Index same = 0;
  for (Index t = 0; t < c.states.size(); ++t) same += c.states[t] == vit.path[t];
  CHECK(same > Index(0.7 * c.states.size()));
}

TEST_CASE("fixed-lag decoder: bad input") {
  const Model m = random_model(3, 5, 1, 0.0);
  CHECK_THROWS_WITH_AS(FixedLagDecoder(m.pi, m.A, -1), doctest::Contains("lag must be >= 0"),
                       std::invalid_argument);
  FixedLagDecoder d(m.pi, m.A, 1);
  CHECK_THROWS_WITH_AS(d.push(RowMatrixXd::Zero(2, 4)), doctest::Contains("3 columns"),
                       std::invalid_argument);
  RowMatrixXd nan = RowMatrixXd::Zero(1, 3);
  nan(0, 1) = std::numeric_limits<double>::quiet_NaN();
  CHECK_THROWS_WITH_AS(d.push(nan), doctest::Contains("finite or -inf"), std::invalid_argument);
  // a frame every state of which is impossible
  RowMatrixXd dead = RowMatrixXd::Constant(1, 3, -std::numeric_limits<double>::infinity());
  d.push(RowMatrixXd::Zero(2, 3));
  CHECK_THROWS_WITH_AS(d.push(dead), doctest::Contains("zero probability"), std::runtime_error);
  d.reset();
  CHECK(d.push(RowMatrixXd::Zero(3, 3)).size() == 2);
  CHECK(d.flush().size() == 1);
  CHECK(d.flush().size() == 0);  // nothing pushed
}

// ------------------------------------------------------------------ StreamingPuppet
namespace {

PuppetArray f64(std::vector<std::uint64_t> shape, std::vector<double> v) {
  PuppetArray a;
  a.shape = std::move(shape);
  a.f64 = std::move(v);
  return a;
}

/// A one-element int64 array (the files' scalar options).
PuppetArray int1(Index v) {
  PuppetArray a;
  a.dtype = PuppetArray::DType::Int64;
  a.shape = {1};
  a.i64 = {v};
  return a;
}

/// A random two-part puppet: 6 points (parts {0,2,4} and {1,3,5}), N states, A audio columns,
/// K face coordinates per part; sticky transitions, random SPD covariances.
PuppetFile random_puppet(Index N, Index A, Index K, unsigned seed, double fps = 30.0,
                         Index delta_width = 0, bool diag_vocal = false) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.05, 1.0);
  auto spd = [&](Index d, double scale) {
    Eigen::MatrixXd M(d, d);
    for (Index i = 0; i < d; ++i)
      for (Index j = 0; j < d; ++j) M(i, j) = g(rng);
    Eigen::MatrixXd S = M * M.transpose() / static_cast<double>(d) + Eigen::MatrixXd::Identity(d, d);
    return Eigen::MatrixXd(S * scale);
  };
  PuppetFile f;
  f.metadata = R"({"kind": "test"})";
  f.arrays["fps"] = f64({1}, {fps});
  std::vector<double> mean, sd;
  const Index A2 = delta_width > 0 ? 2 * A : A;  // standardised columns: [features, deltas]
  for (Index a = 0; a < A2; ++a) {
    mean.push_back(a < A ? g(rng) : 0.1 * g(rng));
    sd.push_back(a < A ? 0.5 + u(rng) : 0.2 + 0.3 * u(rng));
  }
  if (delta_width > 0) f.arrays["audio/delta_width"] = int1(delta_width);
  f.arrays["audio/mean"] = f64({static_cast<std::uint64_t>(A2)}, mean);
  f.arrays["audio/std"] = f64({static_cast<std::uint64_t>(A2)}, sd);
  std::vector<double> shape;
  for (int i = 0; i < 12; ++i) shape.push_back(g(rng));
  f.arrays["face/mean_shape"] = f64({6, 2}, shape);
  f.arrays["face/mean_pose"] = f64({4}, {std::log(50.0), 0.1, 100, 80});
  for (int p = 0; p < 2; ++p) {
    const std::string pre = "part" + std::to_string(p);
    PuppetArray pts;
    pts.dtype = PuppetArray::DType::Int64;
    pts.shape = {3};
    pts.i64 = {p, p + 2, p + 4};
    f.arrays["face/" + pre + "/points"] = pts;
    // orthonormal rows: K unit vectors of the 6 coordinates
    std::vector<double> basis(static_cast<size_t>(K * 6), 0.0);
    for (Index k = 0; k < K; ++k) basis[static_cast<size_t>(k * 6 + (k * 2 + p) % 6)] = 1.0;
    f.arrays["face/" + pre + "/basis"] = f64({static_cast<std::uint64_t>(K), 6}, basis);
    std::vector<double> pi(static_cast<size_t>(N), 1.0 / static_cast<double>(N)), A_(static_cast<size_t>(N * N));
    for (Index i = 0; i < N; ++i) {
      double s = 0;
      for (Index j = 0; j < N; ++j) {
        const double v = (i == j ? 8.0 : 0.0) + (u(rng) < 0.4 ? 0.0 : u(rng));
        A_[static_cast<size_t>(i * N + j)] = v;
        s += v;
      }
      for (Index j = 0; j < N; ++j) A_[static_cast<size_t>(i * N + j)] /= s;
    }
    f.arrays["hmm/" + pre + "/startprob"] = f64({static_cast<std::uint64_t>(N)}, pi);
    f.arrays["hmm/" + pre + "/transmat"] = f64({static_cast<std::uint64_t>(N), static_cast<std::uint64_t>(N)}, A_);
    std::vector<double> fm, fc, vm, vc;
    for (Index n = 0; n < N; ++n) {
      for (Index k = 0; k < K; ++k) fm.push_back(2.0 * g(rng));
      for (Index k = 0; k < K; ++k) fm.push_back(0.0);
      const Eigen::MatrixXd C = spd(2 * K, 0.3);
      for (Index i = 0; i < 2 * K; ++i)
        for (Index j = 0; j < 2 * K; ++j) fc.push_back(C(i, j));
      for (Index a = 0; a < A2; ++a) vm.push_back(1.5 * g(rng));
      const Eigen::MatrixXd V = spd(A2, 0.5);
      for (Index i = 0; i < A2; ++i) {
        if (diag_vocal) {
          vc.push_back(V(i, i));
          continue;
        }
        for (Index j = 0; j < A2; ++j) vc.push_back(V(i, j));
      }
    }
    const auto n_ = static_cast<std::uint64_t>(N), k2 = static_cast<std::uint64_t>(2 * K),
               a_ = static_cast<std::uint64_t>(A2);
    f.arrays["hmm/" + pre + "/face_means"] = f64({n_, k2}, fm);
    f.arrays["hmm/" + pre + "/face_covars"] = f64({n_, k2, k2}, fc);
    f.arrays["hmm/" + pre + "/vocal_means"] = f64({n_, a_}, vm);
    f.arrays["hmm/" + pre + "/vocal_covars"] = diag_vocal ? f64({n_, a_}, vc) : f64({n_, a_, a_}, vc);
  }
  return f;
}

/// Raw features from a sticky walk over the first part's vocal means (in raw units).
RowMatrixXd walk_features(const Puppet& pp, Index T, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 0.7);
  std::uniform_int_distribution<Index> pick(0, pp.part(0).n_states() - 1);
  const PuppetPart& pt = pp.part(0);
  const RowMatrixXd mean = pp.file().at("audio/mean").matrix();
  const RowMatrixXd sd = pp.file().at("audio/std").matrix();
  RowMatrixXd X(T, pp.n_features());
  Index s = pick(rng);
  for (Index t = 0; t < T; ++t) {
    if (t % 6 == 0) s = pick(rng);
    for (Index a = 0; a < X.cols(); ++a) X(t, a) = (pt.vocal_means(s, a) + g(rng)) * sd(0, a) + mean(0, a);
  }
  return X;
}

/// Decoder and trajectory lags longer than the test streams (80 input, 200 output frames).
StreamingOptions covering_lags(double fps, bool posterior) {
  StreamingOptions o;
  o.decode_lag = 80;
  o.trajectory_lag = 200;
  o.fps = fps;
  o.posterior = posterior;
  return o;
}

RowMatrixXd stream_points(StreamingPuppet& sp, const RowMatrixXd& X, Index chunk) {
  std::vector<RowMatrixXd> rows;
  Index next = 0;
  auto take = [&](const StreamedFrames& f) {
    REQUIRE(f.first_frame == next);
    next += f.size();
    rows.push_back(f.points);
  };
  for (Index t = 0; t < X.rows(); t += chunk) take(sp.push(X.middleRows(t, std::min(chunk, X.rows() - t))));
  take(sp.flush());
  RowMatrixXd all(next, 2 * sp.puppet().n_points());
  Index r = 0;
  for (const auto& m : rows) {
    if (m.rows()) all.middleRows(r, m.rows()) = m;
    r += m.rows();
  }
  return all;
}

}  // namespace

TEST_CASE("streaming puppet: lags covering the stream give Puppet::animate exactly") {
  for (Index width : {Index(0), Index(2), Index(-1)}) {
  // width -1: no deltas and diagonal vocal covariances
  const Puppet pp(random_puppet(6, 3, 2, 17, 30.0, std::max<Index>(width, 0), width < 0));
  CHECK(pp.part(0).vocal_type == (width < 0 ? CovarianceType::Diagonal : CovarianceType::Full));
  CHECK(pp.delta_width() == std::max<Index>(width, 0));
  const RowMatrixXd X = walk_features(pp, 70, 4);
  for (bool posterior : {false, true}) {
    for (double fps : {0.0, 60.0, 25.0}) {
      StreamingPuppet sp(pp, covering_lags(fps, posterior));
      AnimateOptions ao;
      ao.fps = fps;
      ao.posterior = posterior;
      const AnimateResult ref = pp.animate(X, ao);
      for (Index chunk : {Index(1), Index(13)}) {
        const RowMatrixXd got = stream_points(sp, X, chunk);
        REQUIRE(got.rows() == ref.points.rows());
        CHECK((got - ref.points).cwiseAbs().maxCoeff() < 1e-8 * (1.0 + ref.points.cwiseAbs().maxCoeff()));
      }
    }
  }
}
}

TEST_CASE("streaming puppet: bounded lags emit frame k after input k + lags; chunking is invisible") {
  const Puppet pp(random_puppet(5, 4, 2, 23, 30.0, 2));
  const RowMatrixXd X = walk_features(pp, 60, 9);
  for (bool posterior : {false, true}) {
    StreamingOptions o;
    o.delta_lag = 1;
    o.decode_lag = 2;
    o.trajectory_lag = 3;
    o.posterior = posterior;
    StreamingPuppet sp(pp, o);
    CHECK(std::abs(sp.latency_seconds() - 6.0 / 30.0) < 1e-12);
    for (Index t = 0; t < X.rows(); ++t) {
      const StreamedFrames f = sp.push(X.middleRows(t, 1));
      // input t gives the deltas of t - 1, decides frame t - 3, completes output frame t - 6
      CHECK(f.size() == (t >= 6 ? 1 : 0));
      if (f.size()) CHECK(f.first_frame == t - 6);
    }
    CHECK(sp.flush().size() == 6);
    const RowMatrixXd one = stream_points(sp, X, 1);
    const RowMatrixXd all = stream_points(sp, X, X.rows());
    CHECK((one - all).cwiseAbs().maxCoeff() < 1e-10);
    // small lags differ from the offline solve, but stay close on a sticky walk
    AnimateOptions ao;
    ao.posterior = posterior;
    const RowMatrixXd ref = pp.animate(X, ao).points;
    CHECK((one - ref).cwiseAbs().maxCoeff() > 0.0);
    CHECK(std::isfinite(one.sum()));
  }
}

TEST_CASE("streaming puppet: bad input") {
  const Puppet pp(random_puppet(4, 3, 1, 5));
  StreamingOptions o;
  o.decode_lag = -1;
  CHECK_THROWS_WITH_AS(StreamingPuppet(pp, o), doctest::Contains("decode_lag"), std::invalid_argument);
  o.decode_lag = 1;
  o.fps = -5;
  CHECK_THROWS_WITH_AS(StreamingPuppet(pp, o), doctest::Contains("fps"), std::invalid_argument);
  o.fps = 0;
  o.delta_lag = 1;  // this puppet has no deltas
  CHECK_THROWS_WITH_AS(StreamingPuppet(pp, o), doctest::Contains("delta_lag"), std::invalid_argument);
  StreamingPuppet sp(pp);
  CHECK_THROWS_WITH_AS(sp.push(RowMatrixXd::Zero(2, 5)), doctest::Contains("3 columns"), std::invalid_argument);
  RowMatrixXd bad = RowMatrixXd::Zero(2, 3);
  bad(1, 1) = std::numeric_limits<double>::infinity();
  CHECK_THROWS_WITH_AS(sp.push(bad), doctest::Contains("NaN or infinite"), std::invalid_argument);
  CHECK(sp.push(RowMatrixXd::Zero(0, 3)).size() == 0);
  CHECK(sp.flush().size() == 0);
}

// ------------------------------------------------------------------ projected puppets
namespace {

/// The puppet of `f` with its vocal features made a projection of ±k standardised frames (the
/// first C columns) to V dimensions: random projection and offset, vocal Gaussians redrawn in
/// V dimensions (full, or one covariance copied to every state: "tied"; or diagonal).
PuppetFile add_projection(PuppetFile f, Index k, Index C, Index V, unsigned seed, bool tied, bool diag) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  const Index M = C * (2 * k + 1);
  std::vector<double> P, c;
  for (Index i = 0; i < M * V; ++i) P.push_back(g(rng) / std::sqrt(static_cast<double>(M)));
  for (Index i = 0; i < V; ++i) c.push_back(0.2 * g(rng));
  const auto v_ = static_cast<std::uint64_t>(V);
  f.arrays["audio/projection"] = f64({static_cast<std::uint64_t>(M), v_}, P);
  f.arrays["audio/projection_offset"] = f64({v_}, c);
  f.arrays["audio/projection_context"] = int1(k);
  f.arrays["audio/projection_columns"] = int1(C);
  for (int p = 0; p < 2; ++p) {
    const std::string pre = "hmm/part" + std::to_string(p);
    const auto n_ = f.arrays.at(pre + "/startprob").shape[0];
    std::vector<double> vm, vc;
    Eigen::MatrixXd S;
    for (std::uint64_t n = 0; n < n_; ++n) {
      for (Index a = 0; a < V; ++a) vm.push_back(0.8 * g(rng));
      if (n == 0 || !tied) {
        Eigen::MatrixXd B(V, V);
        for (Index i = 0; i < V; ++i)
          for (Index j = 0; j < V; ++j) B(i, j) = g(rng);
        S = 0.3 * (B * B.transpose() / static_cast<double>(V) + Eigen::MatrixXd::Identity(V, V));
      }
      for (Index i = 0; i < V; ++i) {
        if (diag) {
          vc.push_back(S(i, i));
          continue;
        }
        for (Index j = 0; j < V; ++j) vc.push_back(S(i, j));
      }
    }
    f.arrays[pre + "/vocal_means"] = f64({n_, v_}, vm);
    f.arrays[pre + "/vocal_covars"] = diag ? f64({n_, v_}, vc) : f64({n_, v_, v_}, vc);
  }
  return f;
}

struct Streamed {
  RowMatrixXd points, vocal;
};

/// Pushes X in chunks (0: one push), collects the points and the vocal features in order.
Streamed stream_all(StreamingPuppet& sp, const RowMatrixXd& X, Index chunk) {
  std::vector<StreamedFrames> got;
  if (chunk <= 0) chunk = X.rows();
  for (Index t = 0; t < X.rows(); t += chunk) got.push_back(sp.push(X.middleRows(t, std::min(chunk, X.rows() - t))));
  got.push_back(sp.flush());
  Index m = 0, j = 0;
  for (const auto& f : got) {
    REQUIRE(f.first_frame == m);
    REQUIRE(f.first_vocal == j);
    REQUIRE(f.vocal.cols() == sp.puppet().n_vocal());
    m += f.size();
    j += f.vocal.rows();
  }
  Streamed s{RowMatrixXd(m, 2 * sp.puppet().n_points()), RowMatrixXd(j, sp.puppet().n_vocal())};
  m = j = 0;
  for (const auto& f : got) {
    if (f.size()) s.points.middleRows(m, f.size()) = f.points;
    if (f.vocal.rows()) s.vocal.middleRows(j, f.vocal.rows()) = f.vocal;
    m += f.size();
    j += f.vocal.rows();
  }
  return s;
}

}  // namespace

TEST_CASE("streaming puppet: a projected puppet streams Puppet::project and Puppet::animate") {
  struct Config {
    Index width, k, C, V;
    bool tied, diag;
  };
  // deltas or none; contexts 1 (shorter than the stream's edges need) and 5 (the default);
  // projected columns fewer than, or all of, the standardised ones; full, tied, diagonal
  for (const Config cf : {Config{2, 5, 3, 4, true, false}, Config{0, 1, 3, 2, false, false},
                          Config{2, 3, 6, 3, false, true}}) {
    const PuppetFile base = random_puppet(5, 3, 2, 31, 30.0, cf.width);
    const RowMatrixXd X = walk_features(Puppet(base), 47, 8);
    const Puppet pp(add_projection(base, cf.k, cf.C, cf.V, 5, cf.tied, cf.diag));
    REQUIRE(pp.projected());
    REQUIRE(pp.projection_context() == cf.k);
    REQUIRE(pp.n_vocal() == cf.V);
    const RowMatrixXd v_ref = pp.project(pp.standardize(X));
    for (bool posterior : {false, true}) {
      for (double fps : {0.0, 25.0}) {
        StreamingPuppet sp(pp, covering_lags(fps, posterior));
        CHECK(sp.options().projection_lag == cf.k);
        AnimateOptions ao;
        ao.fps = fps;
        ao.posterior = posterior;
        const RowMatrixXd ref = pp.animate(X, ao).points;
        for (Index chunk : {Index(1), Index(7), Index(0)}) {
          CAPTURE(cf.k);
          CAPTURE(chunk);
          const Streamed s = stream_all(sp, X, chunk);
          // every frame's vocal features, the first and last k included, are the offline ones
          REQUIRE(s.vocal.rows() == X.rows());
          CHECK((s.vocal - v_ref).cwiseAbs().maxCoeff() < 1e-12 * (1.0 + v_ref.cwiseAbs().maxCoeff()));
          REQUIRE(s.points.rows() == ref.rows());
          CHECK((s.points - ref).cwiseAbs().maxCoeff() < 1e-8 * (1.0 + ref.cwiseAbs().maxCoeff()));
        }
      }
    }
  }
}

TEST_CASE("streaming puppet: the projection's look-ahead delays every frame by projection_lag") {
  const PuppetFile base = random_puppet(5, 4, 2, 23, 30.0, 2);
  const RowMatrixXd X = walk_features(Puppet(base), 60, 9);
  // the projection reads all 8 standardised columns, the deltas too
  const Puppet pp(add_projection(base, 5, 8, 3, 11, true, false));
  const RowMatrixXd Z = pp.standardize(X), v_ref = pp.project(Z);
  CHECK(StreamingPuppet(pp).options().delta_lag == 2);
  for (Index pl : {Index(0), Index(2), Index(5)}) {
    StreamingOptions o;
    o.delta_lag = 1;
    o.projection_lag = pl;
    o.decode_lag = 2;
    o.trajectory_lag = 3;
    StreamingPuppet sp(pp, o);
    CHECK(std::abs(sp.latency_seconds() - static_cast<double>(6 + pl) / 30.0) < 1e-12);
    for (Index t = 0; t < X.rows(); ++t) {
      const StreamedFrames f = sp.push(X.middleRows(t, 1));
      // input t gives the deltas of t - 1, the vocal features of t - 1 - pl, decides frame
      // t - 3 - pl, completes output frame t - 6 - pl
      CHECK(f.vocal.rows() == (t >= 1 + pl ? 1 : 0));
      if (f.vocal.rows()) CHECK(f.first_vocal == t - 1 - pl);
      CHECK(f.size() == (t >= 6 + pl ? 1 : 0));
      if (f.size()) CHECK(f.first_frame == t - 6 - pl);
    }
    CHECK(sp.flush().size() == 6 + pl);
    const Streamed one = stream_all(sp, X, 1), all = stream_all(sp, X, X.rows()), seven = stream_all(sp, X, 7);
    CHECK((one.points - all.points).cwiseAbs().maxCoeff() < 1e-10);
    CHECK((one.points - seven.points).cwiseAbs().maxCoeff() < 1e-10);
    CHECK((one.vocal - seven.vocal).cwiseAbs().maxCoeff() < 1e-12);
    // delta_lag 1 < w: the projected deltas are approximations, so are the vocal features
    CHECK((one.vocal - v_ref).cwiseAbs().maxCoeff() > 1e-6);
    CHECK(one.vocal.allFinite());
  }
  // with exact deltas, projection_lag < k is exactly "the newest standardised frame repeated":
  // frame s's features are Puppet::project of the frames 0 .. s + pl, at row s
  for (Index pl : {Index(0), Index(3)}) {
    StreamingOptions o;
    o.projection_lag = pl;
    StreamingPuppet sp(pp, o);
    const Streamed s = stream_all(sp, X, 1);
    // (frames decided before the flush: s + pl + w <= T - 1, w = 2)
    for (Index t = 0; t + pl + 2 < X.rows(); ++t) {
      const RowMatrixXd prefix = pp.project(Z.topRows(t + pl + 1));
      CHECK((s.vocal.row(t) - prefix.row(t)).cwiseAbs().maxCoeff() < 1e-12 * (1.0 + prefix.cwiseAbs().maxCoeff()));
    }
    // the frames flushed at the end read the real last frames, as offline
    CHECK((s.vocal.bottomRows(pl + 2) - v_ref.bottomRows(pl + 2)).cwiseAbs().maxCoeff() <
          1e-12 * (1.0 + v_ref.cwiseAbs().maxCoeff()));
  }
  StreamingOptions bad;
  bad.projection_lag = 6;
  CHECK_THROWS_WITH_AS(StreamingPuppet(pp, bad), doctest::Contains("projection_lag"), std::invalid_argument);
  bad.projection_lag = -2;
  CHECK_THROWS_WITH_AS(StreamingPuppet(pp, bad), doctest::Contains("projection context, 5"), std::invalid_argument);
}

TEST_CASE("streaming puppet: a projection of the features alone waits for no deltas") {
  // Python's projected puppets read the A raw columns only (their context forms any deltas)
  const PuppetFile base = random_puppet(5, 4, 2, 23, 30.0, 2);
  const RowMatrixXd X = walk_features(Puppet(base), 50, 2);
  const Puppet pp(add_projection(base, 5, 4, 3, 13, true, false));
  StreamingOptions o;
  o.decode_lag = 2;
  o.trajectory_lag = 1;
  StreamingPuppet sp(pp, o);
  CHECK(sp.options().delta_lag == 0);
  CHECK(sp.options().projection_lag == 5);
  CHECK(std::abs(sp.latency_seconds() - 8.0 / 30.0) < 1e-12);  // (5 + 2) / 30 + 1 / 30
  const Streamed s = stream_all(sp, X, 1);
  const RowMatrixXd v_ref = pp.project(pp.standardize(X));
  CHECK((s.vocal - v_ref).cwiseAbs().maxCoeff() < 1e-12 * (1.0 + v_ref.cwiseAbs().maxCoeff()));
  o.delta_lag = 2;  // an explicit delta look-ahead is honoured, and only delays
  StreamingPuppet slow(pp, o);
  CHECK(std::abs(slow.latency_seconds() - 10.0 / 30.0) < 1e-12);
  const Streamed s2 = stream_all(slow, X, 1);
  CHECK((s2.points - s.points).cwiseAbs().maxCoeff() < 1e-10);
}

TEST_CASE("streaming puppet: without a projection the vocal features are the standardised frames") {
  const Puppet pp(random_puppet(4, 3, 2, 7, 30.0, 2));
  const RowMatrixXd X = walk_features(pp, 40, 3);
  StreamingPuppet sp(pp);
  CHECK(sp.options().delta_lag == 2);
  CHECK(sp.options().projection_lag == 0);
  CHECK(std::abs(sp.latency_seconds() - 6.0 / 30.0) < 1e-12);  // delta 2 + decode 2, trajectory 2
  const Streamed s = stream_all(sp, X, 3);
  CHECK(s.vocal == pp.standardize(X));  // bit for bit: the same arithmetic as offline
  StreamingOptions o;
  o.projection_lag = 1;
  CHECK_THROWS_WITH_AS(StreamingPuppet(pp, o), doctest::Contains("has no projection"), std::invalid_argument);
}

// ------------------------------------------------------------------ guided puppets
namespace {

/// The puppet of `f` with a guide of ±kg frames of the first Cg standardised columns: random map
/// and offset to the 2K face coordinates of both parts, a random SPD residual covariance R.
PuppetFile add_guide(PuppetFile f, Index kg, Index Cg, Index K, double weight, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  const Index M = Cg * (2 * kg + 1), KK = 2 * K;
  std::vector<double> G, c, R;
  for (Index i = 0; i < M * KK; ++i) G.push_back(2.0 * g(rng) / std::sqrt(static_cast<double>(M)));
  for (Index i = 0; i < KK; ++i) c.push_back(0.5 * g(rng));
  Eigen::MatrixXd B(KK, KK);
  for (Index i = 0; i < KK; ++i)
    for (Index j = 0; j < KK; ++j) B(i, j) = g(rng);
  const Eigen::MatrixXd S = 0.2 * (B * B.transpose() / static_cast<double>(KK) + 0.5 * Eigen::MatrixXd::Identity(KK, KK));
  for (Index i = 0; i < KK; ++i)
    for (Index j = 0; j < KK; ++j) R.push_back(S(i, j));
  const auto kk = static_cast<std::uint64_t>(KK);
  f.arrays["guide/map"] = f64({static_cast<std::uint64_t>(M), kk}, G);
  f.arrays["guide/offset"] = f64({kk}, c);
  f.arrays["guide/context"] = int1(kg);
  f.arrays["guide/columns"] = int1(Cg);
  f.arrays["guide/covariance"] = f64({kk, kk}, R);
  f.arrays["guide/weight"] = f64({1}, {weight});
  return f;
}

}  // namespace

TEST_CASE("streaming puppet: a guided puppet with exact lags streams Puppet::animate (1e-8)") {
  struct Config {
    Index width;       // delta width of the audio
    Index proj_k;      // projection context (-1: no projection)
  };
  for (const Config cf : {Config{0, -1}, Config{2, -1}, Config{2, 3}}) {
    PuppetFile base = random_puppet(5, 3, 2, 41, 30.0, cf.width);
    const RowMatrixXd X = walk_features(Puppet(base), 45, 6);
    if (cf.proj_k >= 0) base = add_projection(base, cf.proj_k, 3, 3, 9, false, false);
    const Puppet pp(add_guide(base, 5, 3, 2, 1.5, 12));
    REQUIRE(pp.guided());
    const Puppet plain(base);
    for (bool posterior : {false, true}) {
      for (double fps : {0.0, 25.0, 60.0}) {
        CAPTURE(cf.width);
        CAPTURE(cf.proj_k);
        CAPTURE(posterior);
        CAPTURE(fps);
        StreamingPuppet sp(pp, covering_lags(fps, posterior));
        CHECK(sp.options().guide_lag == 5);
        CHECK(sp.options().guide_weight == 1.5);
        AnimateOptions ao;
        ao.fps = fps;
        ao.posterior = posterior;
        const RowMatrixXd ref = pp.animate(X, ao).points;
        // the guide changes the offline face: the comparison below tests the guide's stream
        CHECK((ref - plain.animate(X, ao).points).cwiseAbs().maxCoeff() > 1e-3);
        for (Index chunk : {Index(1), Index(7), Index(0)}) {
          CAPTURE(chunk);
          const Streamed s = stream_all(sp, X, chunk);
          REQUIRE(s.points.rows() == ref.rows());
          CHECK((s.points - ref).cwiseAbs().maxCoeff() < 1e-8 * (1.0 + ref.cwiseAbs().maxCoeff()));
        }
      }
    }
  }
}

TEST_CASE("streaming puppet: the guide's look-ahead overlaps the decoder's; frame k after input k + latency") {
  // no deltas; with a projection or without; at 30 fps and at NTSC's 29.97 (where k · fps / fps
  // can round above k: ŷ must not wait for the next frame then)
  for (const auto& [proj_k, fps] : {std::pair{Index(-1), 30.0}, std::pair{Index(2), 30.0},
                                    std::pair{Index(-1), 30000.0 / 1001.0}}) {
    CAPTURE(fps);
    PuppetFile base = random_puppet(5, 3, 2, 43, fps, 0);
    const RowMatrixXd X = walk_features(Puppet(base), 50, 7);
    if (proj_k >= 0) base = add_projection(base, proj_k, 3, 3, 10, true, false);
    const Puppet pp(add_guide(base, 5, 3, 2, 1.0, 13));
    const RowMatrixXd yhat = pp.guide_predict(pp.standardize(X));
    for (Index gl : {Index(0), Index(2), Index(5)}) {
      StreamingOptions o;
      o.projection_lag = proj_k >= 0 ? 1 : -1;
      o.guide_lag = gl;
      o.decode_lag = 2;
      o.trajectory_lag = 1;
      StreamingPuppet sp(pp, o);
      const Index pl = proj_k >= 0 ? 1 : 0;
      const Index lat = std::max<Index>(pl + 2, gl) + 1;  // delta_lag 0
      CAPTURE(proj_k);
      CAPTURE(gl);
      CHECK(sp.options().delta_lag == 0);
      CHECK(std::abs(sp.latency_seconds() - static_cast<double>(lat) / fps) < 1e-12);
      for (Index t = 0; t < X.rows(); ++t) {
        const StreamedFrames f = sp.push(X.middleRows(t, 1));
        CHECK(f.size() == (t >= lat ? 1 : 0));
        if (f.size()) CHECK(f.first_frame == t - lat);
      }
      CHECK(sp.flush().size() == lat);
      // chunking is invisible; guide_lag < k is an approximation of the exact stream
      const Streamed one = stream_all(sp, X, 1), all = stream_all(sp, X, 0), seven = stream_all(sp, X, 7);
      CHECK((one.points - all.points).cwiseAbs().maxCoeff() < 1e-10);
      CHECK((one.points - seven.points).cwiseAbs().maxCoeff() < 1e-10);
      StreamingOptions exact_guide = o;
      exact_guide.guide_lag = -1;
      StreamingPuppet exact_stream(pp, exact_guide);
      const Streamed ex = stream_all(exact_stream, X, 1);
      if (gl < 5) {
        CHECK((one.points - ex.points).cwiseAbs().maxCoeff() > 1e-6);
      } else {
        CHECK((one.points - ex.points).cwiseAbs().maxCoeff() == 0.0);
      }
    }
  }
}

TEST_CASE("streaming puppet: ŷ with guide_lag g is the guide of the frames 0 .. t + g (the newest repeated)") {
  // a trajectory far more certain of the evidence than of the model: the face is ŷ to ~1e-6,
  // so the streamed face shows which ŷ the stream used
  const PuppetFile base = random_puppet(4, 3, 2, 47, 30.0, 0);
  const RowMatrixXd X = walk_features(Puppet(base), 40, 8);
  const Puppet pp(add_guide(base, 4, 3, 2, 1e9, 14));
  const RowMatrixXd Z = pp.standardize(X);
  for (Index gl : {Index(0), Index(3)}) {
    StreamingOptions o;
    o.guide_lag = gl;
    o.decode_lag = 1;
    o.trajectory_lag = 0;
    StreamingPuppet sp(pp, o);
    std::vector<StreamedFrames> got;
    for (Index t = 0; t < X.rows(); ++t) got.push_back(sp.push(X.middleRows(t, 1)));
    for (const auto& f : got) {
      for (Index i = 0; i < f.size(); ++i) {
        const Index t = f.first_frame + i;
        const RowMatrixXd prefix = pp.guide_predict(Z.topRows(t + gl + 1));
        CAPTURE(t);
        CHECK((f.face.row(i) - prefix.row(t)).cwiseAbs().maxCoeff() < 1e-5);
      }
    }
    CHECK(got.back().first_frame + got.back().size() == X.rows() - std::max<Index>(1, gl));
  }
}

TEST_CASE("streaming puppet: a guided puppet streamed with λ = 0 is the unguided stream bit for bit") {
  const PuppetFile base = random_puppet(5, 3, 2, 53, 30.0, 2);
  const RowMatrixXd X = walk_features(Puppet(base), 40, 2);
  const Puppet plain(base), guided(add_guide(base, 5, 3, 2, 1.0, 15)), zero(add_guide(base, 5, 3, 2, 0.0, 15));
  for (bool posterior : {false, true}) {
    for (double fps : {0.0, 25.0}) {
      StreamingOptions o;
      o.posterior = posterior;
      o.fps = fps;
      StreamingPuppet a(plain, o), c(zero, o);
      o.guide_weight = 0.0;
      StreamingPuppet b(guided, o);
      CHECK(b.options().guide_lag == 0);  // nothing waits for an unused guide
      CHECK(b.latency_seconds() == a.latency_seconds());
      CHECK(c.latency_seconds() == a.latency_seconds());
      const Streamed sa = stream_all(a, X, 3), sb = stream_all(b, X, 3), sc = stream_all(c, X, 3);
      CHECK((sa.points.array() == sb.points.array()).all());
      CHECK((sa.points.array() == sc.points.array()).all());
      o.guide_weight = -1;
      StreamingPuppet d(guided, o);
      CHECK((stream_all(d, X, 3).points - sa.points).cwiseAbs().maxCoeff() > 1e-3);
    }
  }
}

TEST_CASE("streaming puppet: bad guide options") {
  const PuppetFile base = random_puppet(4, 3, 1, 5);
  const Puppet plain(base), guided(add_guide(base, 3, 2, 1, 1.0, 4));
  StreamingOptions o;
  o.guide_lag = 4;
  CHECK_THROWS_WITH_AS(StreamingPuppet(guided, o), doctest::Contains("guide_lag must be -1 (the puppet's guide context, 3)"),
                       std::invalid_argument);
  o.guide_lag = -2;
  CHECK_THROWS_WITH_AS(StreamingPuppet(guided, o), doctest::Contains("guide_lag"), std::invalid_argument);
  o.guide_lag = 1;
  CHECK_THROWS_WITH_AS(StreamingPuppet(plain, o), doctest::Contains("has no guide"), std::invalid_argument);
  o.guide_lag = -1;
  o.guide_weight = 2.0;
  CHECK_THROWS_WITH_AS(StreamingPuppet(plain, o), doctest::Contains("needs a guided puppet"), std::invalid_argument);
  o.guide_weight = std::numeric_limits<double>::infinity();
  CHECK_THROWS_WITH_AS(StreamingPuppet(guided, o), doctest::Contains("guide_weight must be finite"), std::invalid_argument);
  o.guide_weight = std::nan("");  // NaN: the file's λ
  CHECK(StreamingPuppet(guided, o).options().guide_weight == 1.0);
}
