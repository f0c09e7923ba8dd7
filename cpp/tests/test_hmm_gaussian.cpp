// Float32-screened Gaussian HMM inference (hmm_gaussian.hpp) against the all-double evaluation:
// the screening bound holds entry by entry, and score, Viterbi and posteriors are the same.
#include <doctest/doctest.h>

#include <Eigen/QR>

#include <cmath>
#include <random>

#include "voicepuppet/hmm_gaussian.hpp"

using namespace voicepuppet;

namespace {

struct GaussianModel {
  VectorXd pi;
  RowMatrixXd A, means, covars;
};

// n sticky states in d dims, means `spread` apart, covariances of condition number ~`cond`.
GaussianModel separated_model(Index n, Index d, double spread, double cond, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  GaussianModel m;
  m.pi = VectorXd::Constant(n, 1.0 / n);
  m.A = RowMatrixXd::Constant(n, n, 0.1 / (n - 1));
  m.A.diagonal().setConstant(0.9);
  m.means.resize(n, d);
  for (Index i = 0; i < m.means.size(); ++i) m.means.data()[i] = g(rng) * spread / std::sqrt(double(d));
  m.covars.resize(n * d, d);
  for (Index k = 0; k < n; ++k) {
    Eigen::MatrixXd B(d, d);
    for (Index i = 0; i < B.size(); ++i) B.data()[i] = g(rng);
    const Eigen::MatrixXd Q = Eigen::HouseholderQR<Eigen::MatrixXd>(B).householderQ();
    Eigen::VectorXd ev(d);
    for (Index i = 0; i < d; ++i) ev[i] = std::pow(cond, -double(i) / double(d - 1));
    m.covars.middleRows(k * d, d) = Q * ev.asDiagonal() * Q.transpose();
  }
  return m;
}

}  // namespace

TEST_CASE("float32 screening: the bound holds, and score, Viterbi, posteriors equal all-double") {
  for (const double cond : {10.0, 1e7}) {
    CAPTURE(cond);
    const GaussianModel m = separated_model(12, 16, 30.0, cond, 7);
    const SampleResult s = gaussian_hmm_sample(m.pi, m.A, m.means, m.covars, CovarianceType::Full, 4000, 3);
    const RowMatrixXd exact = gaussian_log_density(s.X, m.means, m.covars, CovarianceType::Full);
    const ScreenedLogDensity sc = gaussian_log_density_screened(s.X, m.means, m.covars);
    CHECK(((sc.log_b - exact).cwiseAbs().array() <= sc.bound.array()).all());

    VectorXi lengths(2);
    lengths << 1500, 2500;
    ScreeningInfo info;
    const double ll = gaussian_hmm_score(s.X, lengths, m.pi, m.A, m.means, m.covars, CovarianceType::Full, false, &info);
    const double ll_exact = gaussian_hmm_score(s.X, lengths, m.pi, m.A, m.means, m.covars, CovarianceType::Full, true);
    CHECK(std::abs(ll - ll_exact) <= 1e-12 * std::abs(ll_exact));
    CHECK_FALSE(info.all_double);
    CHECK(info.refined < info.entries / 4);

    const ViterbiResult v = gaussian_hmm_decode(s.X, lengths, m.pi, m.A, m.means, m.covars, CovarianceType::Full);
    const ViterbiResult v_exact =
        gaussian_hmm_decode(s.X, lengths, m.pi, m.A, m.means, m.covars, CovarianceType::Full, true);
    CHECK(v.path == v_exact.path);
    CHECK(std::abs(v.log_probability - v_exact.log_probability) <= 1e-12 * std::abs(v_exact.log_probability));

    const ForwardBackwardResult fb =
        gaussian_hmm_posteriors(s.X, lengths, m.pi, m.A, m.means, m.covars, CovarianceType::Full);
    const ForwardBackwardResult fb_exact =
        gaussian_hmm_posteriors(s.X, lengths, m.pi, m.A, m.means, m.covars, CovarianceType::Full, true);
    CHECK((fb.posteriors - fb_exact.posteriors).cwiseAbs().maxCoeff() < 1e-10);
    CHECK((fb.expected_transitions - fb_exact.expected_transitions).cwiseAbs().maxCoeff() < 1e-8);
    CHECK(std::abs(fb.log_likelihood - fb_exact.log_likelihood) <= 1e-12 * std::abs(fb_exact.log_likelihood));
  }
}

TEST_CASE("float32 screening falls back to all-double when the states overlap") {
  const GaussianModel m = separated_model(10, 10, 0.3, 10.0, 11);
  const SampleResult s = gaussian_hmm_sample(m.pi, m.A, m.means, m.covars, CovarianceType::Full, 2000, 5);
  ScreeningInfo info;
  const VectorXi none;
  const double ll = gaussian_hmm_score(s.X, none, m.pi, m.A, m.means, m.covars, CovarianceType::Full, false, &info);
  CHECK(info.all_double);
  CHECK(ll == gaussian_hmm_score(s.X, none, m.pi, m.A, m.means, m.covars, CovarianceType::Full, true));
}
