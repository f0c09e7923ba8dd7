// Fixed-lag decoding against its definition: the decision for frame s after frame s + L is the
// offline Viterbi / forward-backward answer on the prefix 0 .. s + L (hmm.hpp, an independent
// implementation); with L >= T - 1 it is the offline answer on the whole sequence.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <random>

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/streaming.hpp"

using namespace voicepuppet;

namespace {

struct Model {
  VectorXd pi;
  RowMatrixXd A;
  RowMatrixXd log_b;
};

Model random_model(Index n, Index T, unsigned seed, double sparsity) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.05, 1.0);
  Model m;
  m.pi.resize(n);
  m.A.resize(n, n);
  for (Index i = 0; i < n; ++i) {
    m.pi[i] = u(rng);
    for (Index j = 0; j < n; ++j) m.A(i, j) = (j != i && u(rng) < sparsity) ? 0.0 : u(rng);
    m.A.row(i) /= m.A.row(i).sum();
  }
  m.pi /= m.pi.sum();
  m.log_b.resize(T, n);
  std::normal_distribution<double> g(-3.0, 2.0);
  for (Index t = 0; t < T; ++t)
    for (Index j = 0; j < n; ++j) m.log_b(t, j) = g(rng);
  return m;
}

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
