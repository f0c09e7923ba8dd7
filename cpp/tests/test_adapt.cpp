// Tests of adapt.hpp: a planted speaker (frames of a known Gaussian HMM seen through a known
// affine distortion) is undone, the penalised likelihood never decreases over EM iterations,
// τ = ∞ and kind None are the identity, bad values are refused by name. The same update against
// a plain numpy reference is in tests/test_adapt.py.
#include <doctest/doctest.h>

#include "throws_with.hpp"

#include "voicepuppet/adapt.hpp"
#include "voicepuppet/hmm.hpp"
#include "voicepuppet/hmm_gaussian.hpp"

#include <Eigen/LU>

#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

using namespace voicepuppet;

namespace {

// Only std::invalid_argument counts: every refusal here is a bad argument.
constexpr auto throws_with = &voicepuppet::testing::throws_with<std::invalid_argument>;

/// Four states in 3-D, overlapping a little, sticky transitions, full covariances.
struct Hmm {
  VectorXd startprob = VectorXd::Constant(4, 0.25);
  RowMatrixXd transmat, means, covars;
  Hmm() {
    transmat = RowMatrixXd::Constant(4, 4, 0.1 / 3);
    transmat.diagonal().setConstant(0.9);
    means.resize(4, 3);
    means << 0, 0, 0,  2, 0, 0.5,  0, 2, -0.5,  1.5, 1.5, 1.5;
    covars.resize(12, 3);
    std::mt19937 rng(3);
    std::normal_distribution<double> g(0, 0.3);
    for (Index i = 0; i < 4; ++i) {
      RowMatrixXd L(3, 3);
      for (Index a = 0; a < 3; ++a)
        for (Index b = 0; b < 3; ++b) L(a, b) = g(rng);
      covars.middleRows(i * 3, 3) = L * L.transpose() + 0.4 * RowMatrixXd::Identity(3, 3);
    }
  }
};

/// The planted speaker: y = M⁻¹ (x − c), so the transform that undoes it is A = M, b = c. M
/// scales about the states' centroid m̄ (c = m̄ − M m̄ + a shift), as a new voice spreads the
/// same sounds differently and shifts them: within EM's reach from the identity, but far
/// enough that decoding y as it is confuses the states.
struct Planted {
  Hmm hmm;
  SampleResult sample;
  RowMatrixXd M, y;
  VectorXd c;
  explicit Planted(Index T) {
    sample = gaussian_hmm_sample(hmm.startprob, hmm.transmat, hmm.means, hmm.covars, CovarianceType::Full, T, 11);
    M.resize(3, 3);
    M << 1.4, 0.2, 0.0,  0.0, 0.7, 0.1,  0.1, 0.0, 1.3;
    const VectorXd centroid = hmm.means.colwise().mean().transpose();
    c = centroid - M * centroid + 0.7 * Eigen::Vector3d(1.0, -1.0, 0.7);
    y = (sample.X.rowwise() - c.transpose()) * M.inverse().transpose();
  }
  FeatureTransform adapt(AdaptKind kind, double tau, Index n_iter = 6) const {
    AdaptOptions o;
    o.kind = kind;
    o.tau = tau;
    o.n_iter = n_iter;
    return adapt_features(y, VectorXi(), hmm.means, hmm.covars, CovarianceType::Full, hmm.startprob,
                          hmm.transmat, o);
  }
  double state_accuracy(const RowMatrixXd& z) const {
    const RowMatrixXd lb = gaussian_log_density(z, hmm.means, hmm.covars, CovarianceType::Full);
    const VectorXi path = viterbi(lb, hmm.startprob, hmm.transmat, VectorXi()).path;
    return (path.array() == sample.states.array()).cast<double>().mean();
  }
};

}  // namespace

TEST_CASE("adapt: a planted speaker's affine distortion is recovered, and the states with it") {
  const Planted p(3000);
  const FeatureTransform t = p.adapt(AdaptKind::Full, 1.0);
  CHECK((t.A - p.M).cwiseAbs().maxCoeff() < 0.06);
  CHECK((t.b - p.c).cwiseAbs().maxCoeff() < 0.05);
  // Decoded as heard, the states are confused; adapted, as well as the undistorted frames.
  const double clean = p.state_accuracy(p.sample.X);
  CHECK(p.state_accuracy(p.y) < 0.85);
  CHECK(p.state_accuracy(t.apply(p.y)) >= clean - 0.005);
  CHECK((t.apply(p.y) - p.sample.X).cwiseAbs().maxCoeff() < 0.5);
}

TEST_CASE("adapt: the penalised likelihood never decreases over EM iterations") {
  const Planted p(400);
  for (const double tau : {0.5, 30.0, 1000.0}) {
    const FeatureTransform t = p.adapt(AdaptKind::Full, tau, 8);
    REQUIRE(t.log_likelihood.size() == 9);
    for (size_t k = 1; k < t.log_likelihood.size(); ++k) {
      CHECK(t.log_likelihood[k] >= t.log_likelihood[k - 1] - 1e-7 * std::abs(t.log_likelihood[k - 1]));
    }
    CHECK(t.log_likelihood.back() > t.log_likelihood.front());
  }
}

TEST_CASE("adapt: a strong prior stays near the identity; tau = inf and kind None are the identity") {
  const Planted p(300);
  const FeatureTransform weak = p.adapt(AdaptKind::Full, 1.0), strong = p.adapt(AdaptKind::Full, 1e6);
  const RowMatrixXd I = RowMatrixXd::Identity(3, 3);
  CHECK((strong.A - I).norm() < 2e-3 * (weak.A - I).norm());
  CHECK(strong.b.norm() < 2e-3 * weak.b.norm());
  for (const AdaptKind kind : {AdaptKind::None, AdaptKind::Full}) {
    const FeatureTransform t = p.adapt(kind, std::numeric_limits<double>::infinity());
    CHECK(t.A == I);
    CHECK(t.b == VectorXd::Zero(3));
    CHECK(t.log_likelihood.empty());
    CHECK(t.apply(p.y) == p.y);
  }
}

TEST_CASE("adapt: bad values are refused by name") {
  const Planted p(50);
  CHECK(throws_with([&] { p.adapt(AdaptKind::Full, 0.0); }, "tau"));
  CHECK(throws_with([&] { p.adapt(AdaptKind::Full, -1.0); }, "tau"));
  CHECK(throws_with([&] { p.adapt(AdaptKind::Full, std::nan("")); }, "tau"));
  CHECK(throws_with([&] { p.adapt(AdaptKind::Full, 10.0, 0); }, "n_iter"));
  CHECK(throws_with([] { parse_adapt_kind("bias"); }, "'none' or 'full'"));
  AdaptOptions o;
  o.kind = AdaptKind::Full;
  const RowMatrixXd wide = RowMatrixXd::Zero(10, 4);
  CHECK(throws_with([&] {
    adapt_features(wide, VectorXi(), p.hmm.means, p.hmm.covars, CovarianceType::Full, p.hmm.startprob,
                   p.hmm.transmat, o);
  }, "columns"));
  RowMatrixXd bad = p.y;
  bad(3, 1) = std::nan("");
  CHECK(throws_with([&] {
    adapt_features(bad, VectorXi(), p.hmm.means, p.hmm.covars, CovarianceType::Full, p.hmm.startprob,
                   p.hmm.transmat, o);
  }, "features to adapt"));
}
