// Forward-backward and Viterbi against textbook numbers (the Wikipedia umbrella example) and
// brute-force enumeration; the fast passes against the log-sum-exp reference in every regime.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "random_hmm.hpp"
#include "voicepuppet/hmm.hpp"

using namespace voicepuppet;

namespace {

using testing::Model;
using testing::random_model;

// Sum over all paths (log p(x)), and best path, by enumeration.
void brute_force(const Model& m, double& loglik, double& best, std::vector<Index>& best_path) {
  const Index n = m.pi.size(), T = m.log_b.rows();
  Index total = 1;
  for (Index t = 0; t < T; ++t) total *= n;
  double sum = 0;
  best = -std::numeric_limits<double>::infinity();
  std::vector<Index> path(static_cast<size_t>(T));
  for (Index code = 0; code < total; ++code) {
    Index c = code;
    for (Index t = T - 1; t >= 0; --t) {
      path[static_cast<size_t>(t)] = c % n;
      c /= n;
    }
    double lp = std::log(m.pi[path[0]]) + m.log_b(0, path[0]);
    for (Index t = 1; t < T; ++t)
      lp += std::log(m.A(path[static_cast<size_t>(t - 1)], path[static_cast<size_t>(t)])) +
            m.log_b(t, path[static_cast<size_t>(t)]);
    sum += std::exp(lp);
    if (lp > best) {
      best = lp;
      best_path = path;
    }
  }
  loglik = std::log(sum);
}

}  // namespace

TEST_CASE("umbrella example: forward, backward, posteriors, Viterbi") {
  // Wikipedia, "Forward-backward algorithm": rain/no rain, umbrella seen on days 1,2,4,5.
  VectorXd pi(2);
  pi << 0.5, 0.5;
  RowMatrixXd A(2, 2);
  A << 0.7, 0.3, 0.3, 0.7;
  const double u[2] = {0.9, 0.2}, nu[2] = {0.1, 0.8};
  const int obs[5] = {1, 1, 0, 1, 1};
  RowMatrixXd log_b(5, 2);
  for (int t = 0; t < 5; ++t)
    for (int j = 0; j < 2; ++j) log_b(t, j) = std::log(obs[t] ? u[j] : nu[j]);

  const RowMatrixXd la = forward_lattice_log(log_b, pi, A);
  const double fwd[5] = {0.8182, 0.8834, 0.1907, 0.7308, 0.8673};  // normalised P(rain)
  for (int t = 0; t < 5; ++t) {
    const double p = std::exp(la(t, 0)) / (std::exp(la(t, 0)) + std::exp(la(t, 1)));
    CHECK(p == doctest::Approx(fwd[t]).epsilon(1e-3));
  }
  const RowMatrixXd lbeta = backward_lattice_log(log_b, A);


  const double smooth[5] = {0.8673, 0.8204, 0.3075, 0.8204, 0.8673};
  for (const auto& fb : {forward_backward(log_b, pi, A, VectorXi()), forward_backward_log(log_b, pi, A, VectorXi())}) {
    for (int t = 0; t < 5; ++t) {
      CHECK(fb.posteriors(t, 0) == doctest::Approx(smooth[t]).epsilon(1e-3));
      const double lat = std::exp(la(t, 0) + lbeta(t, 0) - fb.log_likelihood);
      CHECK(lat == doctest::Approx(fb.posteriors(t, 0)).epsilon(1e-12));
    }
  }
  const ViterbiResult v = viterbi(log_b, pi, A, VectorXi());
  const Index expect[5] = {0, 0, 1, 0, 0};
  for (int t = 0; t < 5; ++t) CHECK(v.path[t] == expect[t]);
}

TEST_CASE("forward-backward and Viterbi agree with brute-force enumeration") {
  for (unsigned seed = 1; seed <= 12; ++seed) {
    const Index n = 2 + seed % 3, T = 1 + seed % 6;
    const Model m = random_model(n, T, seed, seed % 2 ? 0.4 : 0.0);
    double ll = 0, best = 0;
    std::vector<Index> path;
    brute_force(m, ll, best, path);
    const auto fb = forward_backward(m.log_b, m.pi, m.A, VectorXi());
    CHECK(fb.log_likelihood == doctest::Approx(ll).epsilon(1e-12));
    CHECK(log_likelihood(m.log_b, m.pi, m.A, VectorXi()) == doctest::Approx(ll).epsilon(1e-12));
    const auto v = viterbi(m.log_b, m.pi, m.A, VectorXi());
    CHECK(v.log_probability == doctest::Approx(best).epsilon(1e-12));
    for (Index t = 0; t < T; ++t) CHECK(v.path[t] == path[static_cast<size_t>(t)]);
  }
}

TEST_CASE("fast and log-space forward-backward agree, sparse and dense, many sequences") {
  for (unsigned seed = 1; seed <= 6; ++seed) {
    Model m = random_model(7, 300, seed, seed % 2 ? 0.6 : 0.0);
    m.log_b *= 40.0;  // very peaked emissions: nothing may underflow
    VectorXi lengths(3);
    lengths << 100, 1, 199;
    const auto a = forward_backward(m.log_b, m.pi, m.A, lengths);
    const auto b = forward_backward_log(m.log_b, m.pi, m.A, lengths);
    CHECK(a.log_likelihood == doctest::Approx(b.log_likelihood).epsilon(1e-12));
    CHECK((a.posteriors - b.posteriors).cwiseAbs().maxCoeff() < 1e-9);
    CHECK((a.expected_transitions - b.expected_transitions).cwiseAbs().maxCoeff() < 1e-8);
    CHECK((a.expected_starts - b.expected_starts).cwiseAbs().maxCoeff() < 1e-9);
    CHECK(a.expected_starts.sum() == doctest::Approx(3.0));
    CHECK(a.expected_transitions.sum() == doctest::Approx(297.0));
    for (Index t = 0; t < 300; ++t) CHECK(a.posteriors.row(t).sum() == doctest::Approx(1.0).epsilon(1e-12));
  }
}

namespace {

// Every quantity of `a` equals the log-space reference `b`: log-likelihoods to 1e-12 relative,
// posteriors to 1e-9 absolute (the reference's exp(log α + log β − ll) carries the rounding of
// lattice entries of up to ~1e6 nats), rows summing to one, and every expected count to 1e-10
// relative to itself down to the smallest normal double (a tiny count dropped to zero would
// prune its arc for good in EM).
void check_equals_reference(const ForwardBackwardResult& a, const ForwardBackwardResult& b) {
  CHECK(a.log_likelihood == doctest::Approx(b.log_likelihood).epsilon(1e-12));
  for (Index q = 0; q < b.sequence_log_likelihoods.size(); ++q)
    CHECK(a.sequence_log_likelihoods[q] == doctest::Approx(b.sequence_log_likelihoods[q]).epsilon(1e-12));
  CHECK((a.posteriors - b.posteriors).cwiseAbs().maxCoeff() < 1e-9);
  CHECK((a.posteriors.rowwise().sum().array() - 1.0).abs().maxCoeff() < 1e-13);
  CHECK((a.expected_starts - b.expected_starts).cwiseAbs().maxCoeff() < 1e-9);
  // The reference's exp of sums of lattice entries of size ~|log p| errs by ~|log p|·1e-16 relative.
  const double rtol = 1e-10 * std::max(1.0, std::abs(b.log_likelihood) / 1e5);
  // Below the smallest normal double relative accuracy has no meaning: a posterior under it is
  // flushed to 0 (exp_or_zero), which moves a count by at most DBL_MIN per frame.
  const double atol = std::numeric_limits<double>::min() * static_cast<double>(b.posteriors.rows());
  const RowMatrixXd err = (a.expected_transitions - b.expected_transitions).cwiseAbs();
  for (Index i = 0; i < err.rows(); ++i)
    for (Index j = 0; j < err.cols(); ++j) CHECK(err(i, j) <= rtol * b.expected_transitions(i, j) + atol);
}

// Left-to-right, n states (stay 0.9, advance 0.1, last absorbing); `early` frames that fit
// state 0, then `late` frames that fit the last state, state k costing gap·(k − fit)² nats. The
// best crossing puts the first middle states in early frames, the last ones in late frames.
Model left_to_right_jump(Index n, Index early, Index late, double gap) {
  Model m;
  m.pi = VectorXd::Zero(n);
  m.pi[0] = 1.0;
  m.A = RowMatrixXd::Zero(n, n);
  for (Index i = 0; i + 1 < n; ++i) {
    m.A(i, i) = 0.9;
    m.A(i, i + 1) = 0.1;
  }
  m.A(n - 1, n - 1) = 1.0;
  m.log_b.resize(early + late, n);
  for (Index t = 0; t < early + late; ++t) {
    const Index fit = t < early ? 0 : n - 1;
    for (Index k = 0; k < n; ++k) m.log_b(t, k) = -gap * static_cast<double>((k - fit) * (k - fit));
  }
  return m;
}

}  // namespace

TEST_CASE("a state thousands of nats below the others is not lost (issue 2)") {
  // The colleague's reproduction: ~100 frames that fit the last state, thousands of nats early.
  const Model m = left_to_right_jump(5, 10, 100, 3000.0);
  const auto ref = forward_backward_log(m.log_b, m.pi, m.A, VectorXi());
  const auto fb = forward_backward(m.log_b, m.pi, m.A, VectorXi());
  check_equals_reference(fb, ref);
  CHECK(log_likelihood(m.log_b, m.pi, m.A, VectorXi()) == doctest::Approx(ref.log_likelihood).epsilon(1e-12));
  // Independent of both: the best path is a lower bound and exceeds log p(x) by at most the log
  // of the number of paths (monotone paths of 110 frames through 5 states: < 110^4). The best
  // crossing costs 1 + 4 + 1 = 6 gaps (a scaled pass that lost states 1..3 found 14).
  const double best = viterbi(m.log_b, m.pi, m.A, VectorXi()).log_probability;
  CHECK(fb.log_likelihood >= best);
  CHECK(fb.log_likelihood <= best + 4 * std::log(110.0));
  CHECK(best > -6 * 3000.0 - 20.0);
  CHECK(fb.posteriors(109, 4) == doctest::Approx(1.0).epsilon(1e-12));
}

TEST_CASE("exact in every regime: lost-and-found states, many sequences, tiny counts") {
  // Variants of the jump in several sequences (one of a single frame) and of gaps from a few
  // to thousands of nats, around the flush threshold (700) and the underflow of doubles (745).
  for (const double gap : {5.0, 300.0, 690.0, 705.0, 745.0, 800.0, 3000.0, 1e5}) {
    const Model a = left_to_right_jump(6, 7, 40, gap), b = left_to_right_jump(6, 30, 3, gap);
    Model m = a;
    m.log_b.resize(a.log_b.rows() + 1 + b.log_b.rows(), 6);
    m.log_b << a.log_b, b.log_b.row(0), b.log_b;
    VectorXi lengths(3);
    lengths << a.log_b.rows(), 1, b.log_b.rows();
    CAPTURE(gap);
    const auto ref = forward_backward_log(m.log_b, m.pi, m.A, lengths);
    check_equals_reference(forward_backward(m.log_b, m.pi, m.A, lengths), ref);
    CHECK(log_likelihood(m.log_b, m.pi, m.A, lengths) == doctest::Approx(ref.log_likelihood).epsilon(1e-12));
  }
  // A state that comes back after a long absence: a cycle 0 → 1 → 2 → 0 where state 2 is
  // reachable only through 1, which fits nothing for 200 frames; then only 2 fits.
  Model c;
  c.pi = VectorXd::Constant(3, 1.0 / 3);
  c.A.resize(3, 3);
  c.A << 0.98, 0.02, 0.0, 0.0, 0.5, 0.5, 0.3, 0.0, 0.7;
  c.log_b = RowMatrixXd::Constant(260, 3, -2500.0);
  c.log_b.topRows(200).col(0).setZero();
  c.log_b.bottomRows(60).col(2).setZero();
  c.log_b.row(100).col(1).setConstant(-10.0);
  check_equals_reference(forward_backward(c.log_b, c.pi, c.A, VectorXi()),
                         forward_backward_log(c.log_b, c.pi, c.A, VectorXi()));
  // Transition probabilities so small that log p is below −709 (exp(−log p) would overflow).
  Model d = random_model(4, 200, 5);
  d.A(0, 3) = d.A(2, 1) = 4e-309;
  d.A.row(0) /= d.A.row(0).sum();
  d.A.row(2) /= d.A.row(2).sum();
  d.log_b *= 30.0;
  const auto fd = forward_backward(d.log_b, d.pi, d.A, VectorXi());
  CHECK(fd.expected_transitions.allFinite());
  check_equals_reference(fd, forward_backward_log(d.log_b, d.pi, d.A, VectorXi()));
  // Random sparse and dense models with emissions spread over thousands of nats, so lattice
  // entries and expected counts span hundreds of orders of magnitude.
  for (unsigned seed = 1; seed <= 8; ++seed) {
    Model m = random_model(6, 120, seed, seed % 2 ? 0.7 : 0.0);
    m.log_b *= 50.0 * seed;
    VectorXi lengths(2);
    lengths << 50, 70;
    CAPTURE(seed);
    const auto ref = forward_backward_log(m.log_b, m.pi, m.A, lengths);
    check_equals_reference(forward_backward(m.log_b, m.pi, m.A, lengths), ref);
    CHECK(log_likelihood(m.log_b, m.pi, m.A, lengths) == doctest::Approx(ref.log_likelihood).epsilon(1e-12));
  }
}

TEST_CASE("a state that cannot be occupied gets exactly zero posterior and zero counts") {
  // State 2 never emits (log b = −inf) and state 1 fits every frame 1,500 nats worse than the
  // others: Eigen's vectorised exp would return ~5.6e−309 for both instead of 0.
  Model m = random_model(9, 80, 3);  // enough states for whole SIMD packets
  m.log_b.col(2).setConstant(-std::numeric_limits<double>::infinity());
  m.log_b.col(1).setConstant(-1500.0);
  const auto fb = forward_backward(m.log_b, m.pi, m.A, VectorXi());
  CHECK(fb.posteriors.col(2).cwiseAbs().maxCoeff() == 0.0);
  CHECK(fb.posteriors.col(1).cwiseAbs().maxCoeff() == 0.0);
  CHECK(fb.expected_transitions.row(2).cwiseAbs().maxCoeff() == 0.0);
  CHECK(fb.expected_transitions.col(2).cwiseAbs().maxCoeff() == 0.0);
  CHECK(fb.expected_starts[2] == 0.0);
}

TEST_CASE("bad input throws invalid_argument with the argument's name") {
  const Model m = random_model(3, 10, 3);
  RowMatrixXd bad_a = m.A;
  bad_a(1, 1) += 0.1;
  CHECK_THROWS_WITH_AS(forward_backward(m.log_b, m.pi, bad_a, VectorXi()), doctest::Contains("transmat row 1"),
                       std::invalid_argument);
  VectorXi lengths(2);
  lengths << 4, 5;
  CHECK_THROWS_WITH_AS(viterbi(m.log_b, m.pi, m.A, lengths), doctest::Contains("lengths sum to 9"),
                       std::invalid_argument);
  lengths << 10, 0;
  CHECK_THROWS_AS(viterbi(m.log_b, m.pi, m.A, lengths), std::invalid_argument);
  RowMatrixXd nan_b = m.log_b;
  nan_b(2, 1) = std::numeric_limits<double>::quiet_NaN();
  CHECK_THROWS_WITH_AS(log_likelihood(nan_b, m.pi, m.A, VectorXi()), doctest::Contains("log_b"),
                       std::invalid_argument);
  CHECK_THROWS_AS(forward_backward(m.log_b.leftCols(2), m.pi, m.A, VectorXi()), std::invalid_argument);
  // A sequence the model cannot produce: a numerical, not an argument, failure.
  RowMatrixXd dead = m.log_b;
  dead.row(4).setConstant(-std::numeric_limits<double>::infinity());
  CHECK_THROWS_AS(forward_backward(dead, m.pi, m.A, VectorXi()), std::runtime_error);
}
