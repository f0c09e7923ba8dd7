// Forward-backward and Viterbi against textbook numbers (the Wikipedia umbrella example) and
// brute-force enumeration; scaled against log-space implementations.
#include <doctest/doctest.h>

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

TEST_CASE("scaled and log-space forward-backward agree, sparse and dense, many sequences") {
  for (unsigned seed = 1; seed <= 6; ++seed) {
    Model m = random_model(7, 300, seed, seed % 2 ? 0.6 : 0.0);
    m.log_b *= 40.0;  // very peaked emissions: the scaled path must not underflow
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
