// Tests of dpds.hpp against independent truth: the gradient against central finite differences
// of the log-likelihood, the mu/nu solve against a least-squares fit on an explicitly built
// design matrix, the streaming generator against the batch path, and the Kalman smoother
// against a dense Gaussian solve of the same scalar LDS.
#include <doctest/doctest.h>

#include "voicepuppet/dpds.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <random>
#include <stdexcept>

using namespace voicepuppet;

namespace {

struct DpdsData {
  RowMatrixXd a, mu, nu, Y;
  VectorXi labels, offsets;
};

DpdsData dpds_data(Index P, Index D, std::mt19937& rng, Index S = 3, Index T = 25) {
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.2, 0.9);
  std::uniform_int_distribution<Index> ph(0, P - 1);
  DpdsData d;
  d.a = RowMatrixXd::NullaryExpr(P, D, [&] { return u(rng); });
  d.mu = RowMatrixXd::NullaryExpr(P, D, [&] { return g(rng); });
  d.nu = RowMatrixXd::NullaryExpr(P, D, [&] { return 0.5 * g(rng); });
  d.offsets.resize(S + 1);
  for (Index s = 0; s <= S; ++s) d.offsets[s] = s * T;
  d.labels.resize(S * T);
  Index cur = ph(rng);
  for (Index t = 0; t < S * T; ++t) {
    if (t % 3 == 0) cur = ph(rng);
    d.labels[t] = cur;
  }
  d.Y = dpds_generate(d.a, d.mu, d.nu, d.labels, d.offsets) +
        RowMatrixXd::NullaryExpr(S * T, D, [&] { return 0.1 * g(rng); });
  return d;
}

}  // namespace

TEST_CASE("dpds gradient equals central finite differences") {
  std::mt19937 rng(7);
  DpdsData d = dpds_data(4, 3, rng);
  VectorXd r = VectorXd::Constant(3, 0.05);
  DpdsGradient g = dpds_gradient(d.a, d.mu, d.nu, r, d.Y, d.offsets, d.labels);
  const double h = 1e-6;
  auto ll = [&](const RowMatrixXd& a, const RowMatrixXd& mu, const RowMatrixXd& nu) {
    return dpds_gradient(a, mu, nu, r, d.Y, d.offsets, d.labels).log_likelihood;
  };
  for (Index p = 0; p < 4; ++p)
    for (Index j = 0; j < 3; ++j) {
      RowMatrixXd ap = d.a, am = d.a;
      ap(p, j) += h;
      am(p, j) -= h;
      const double fd = (ll(ap, d.mu, d.nu) - ll(am, d.mu, d.nu)) / (2 * h);
      CHECK(g.grad_a(p, j) == doctest::Approx(fd).epsilon(1e-5).scale(1.0));
      RowMatrixXd np = d.nu, nm = d.nu;
      np(p, j) += h;
      nm(p, j) -= h;
      CHECK(g.grad_nu(p, j) == doctest::Approx((ll(d.a, d.mu, np) - ll(d.a, d.mu, nm)) / (2 * h)).epsilon(1e-5).scale(1.0));
      RowMatrixXd mp = d.mu, mm = d.mu;
      mp(p, j) += h;
      mm(p, j) -= h;
      CHECK(g.grad_mu(p, j) == doctest::Approx((ll(d.a, mp, d.nu) - ll(d.a, mm, d.nu)) / (2 * h)).epsilon(1e-5).scale(1.0));
    }
}

TEST_CASE("dpds mu/nu solve equals least squares on the explicit design matrix") {
  std::mt19937 rng(11);
  const Index P = 4, D = 2;
  DpdsData d = dpds_data(P, D, rng);
  const Index N = d.Y.rows();
  DpdsSolve s = dpds_solve(d.a, d.Y, d.offsets, d.labels, VectorXd::Zero(D));
  for (Index j = 0; j < D; ++j) {
    // column k of the design: the path obtained with parameter k set to 1 and all others 0
    Eigen::MatrixXd X = Eigen::MatrixXd::Zero(N, 2 * P);
    for (Index k = 0; k < 2 * P; ++k) {
      RowMatrixXd mu = RowMatrixXd::Zero(P, D), nu = RowMatrixXd::Zero(P, D);
      if (k < P) mu(k, j) = 1; else nu(k - P, j) = 1;
      X.col(k) = dpds_generate(d.a, mu, nu, d.labels, d.offsets).col(j);
    }
    Eigen::VectorXd theta = X.completeOrthogonalDecomposition().solve(d.Y.col(j));
    for (Index p = 0; p < P; ++p) {
      if (s.nu_used[p]) CHECK(s.nu(p, j) == doctest::Approx(theta[P + p]).epsilon(1e-8).scale(1.0));
      if (s.mu_used[p]) CHECK(s.mu(p, j) == doctest::Approx(theta[p]).epsilon(1e-8).scale(1.0));
    }
    const double rss = (d.Y.col(j) - X * theta).squaredNorm() / static_cast<double>(N);
    CHECK(s.r[j] == doctest::Approx(rss).epsilon(1e-8));
  }
}

TEST_CASE("dpds stream equals batch generation") {
  std::mt19937 rng(3);
  DpdsData d = dpds_data(5, 4, rng, 1, 40);
  RowMatrixXd batch = dpds_generate(d.a, d.mu, d.nu, d.labels, VectorXi());
  DpdsStream st(d.a, d.mu, d.nu);
  RowMatrixXd first = st.push(d.labels.head(17));
  RowMatrixXd second = st.push(d.labels.tail(23));
  CHECK((first - batch.topRows(17)).cwiseAbs().maxCoeff() < 1e-14);
  CHECK((second - batch.bottomRows(23)).cwiseAbs().maxCoeff() < 1e-14);
  CHECK(st.frames() == 40);
}

TEST_CASE("slds smoother equals a dense Gaussian solve") {
  // one dimension, one sequence of T frames: x ~ N(m, Σx) with Σx from the linear recursion,
  // y = x + v; posterior and evidence by dense linear algebra.
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  const Index P = 3, T = 9;
  RowMatrixXd a(P, 1), nu(P, 1), q(P, 1), r(P, 1), mu1(P, 1), v1(P, 1);
  a << 0.8, -0.3, 0.5;
  nu << 0.2, -0.1, 0.4;
  q << 0.3, 0.1, 0.2;
  r << 0.05, 0.2, 0.1;
  mu1 << 1.0, -1.0, 0.5;
  v1 << 0.4, 0.6, 0.5;
  VectorXi labels(T), offsets(2);
  for (Index t = 0; t < T; ++t) labels[t] = (t * 7 / 3) % P;
  offsets << 0, T;
  RowMatrixXd Y = RowMatrixXd::NullaryExpr(T, 1, [&] { return g(rng); });
  SldsSmooth s = slds_smooth(a, nu, q, r, mu1, v1, Y, offsets, labels);
  // x = M ε + c with ε_1 ~ N(0, v1), ε_t ~ N(0, q): M lower triangular products of a
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(T, T);
  Eigen::VectorXd c(T), ev(T), Rv(T);
  for (Index t = 0; t < T; ++t) {
    const Index p = labels[t];
    c[t] = t == 0 ? mu1(p, 0) : a(p, 0) * c[t - 1] + nu(p, 0);
    ev[t] = t == 0 ? v1(p, 0) : q(p, 0);
    Rv[t] = r(p, 0);
    M(t, t) = 1.0;
    if (t > 0) M.row(t).head(t) = a(p, 0) * M.row(t - 1).head(t);
  }
  Eigen::MatrixXd Sx = M * ev.asDiagonal() * M.transpose();
  Eigen::MatrixXd Sy = Sx;
  Sy.diagonal() += Rv;
  Eigen::LLT<Eigen::MatrixXd> L(Sy);
  Eigen::VectorXd yv = Y.col(0);
  Eigen::VectorXd post_mean = c + Sx * L.solve(yv - c);
  Eigen::MatrixXd post_cov = Sx - Sx * L.solve(Sx);
  const double logdet = 2.0 * L.matrixLLT().diagonal().array().log().sum();
  const double ll = -0.5 * (T * std::log(2 * M_PI) + logdet + (yv - c).dot(L.solve(yv - c)));
  CHECK(s.log_likelihood == doctest::Approx(ll).epsilon(1e-10));
  for (Index t = 0; t < T; ++t) {
    CHECK(s.mean(t, 0) == doctest::Approx(post_mean[t]).epsilon(1e-9));
    CHECK(s.var(t, 0) == doctest::Approx(post_cov(t, t)).epsilon(1e-9));
    if (t > 0) CHECK(s.cross(t, 0) == doctest::Approx(post_cov(t, t - 1)).epsilon(1e-9));
  }
}

TEST_CASE("dpds bad input throws invalid_argument") {
  RowMatrixXd a = RowMatrixXd::Constant(2, 2, 0.5), Y = RowMatrixXd::Zero(4, 2);
  VectorXi labels(4), offsets(2), bad_off(3);
  labels << 0, 1, 0, 5;
  offsets << 0, 4;
  CHECK_THROWS_AS(dpds_solve(a, Y, offsets, labels, VectorXd::Zero(2)), std::invalid_argument);
  labels[3] = 1;
  bad_off << 0, 2, 2;
  CHECK_THROWS_AS(dpds_solve(a, Y, bad_off, labels, VectorXd::Zero(2)), std::invalid_argument);
  CHECK_THROWS_AS(dpds_gradient(a, a, a, VectorXd::Zero(2), Y, offsets, labels), std::invalid_argument);
}
