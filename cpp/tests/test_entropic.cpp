// Entropic estimation: Lambert W identities, the MAP multinomial against a dense 1-D search and
// its limits (Z = 0 is maximum likelihood; zero evidence; single survivor), the entropic
// covariance as the stationary point of its objective, trimming and the annealing schedule.
#include <doctest/doctest.h>

#include <Eigen/LU>

#include <cmath>
#include <limits>
#include <random>

#include "voicepuppet/entropic.hpp"

using namespace voicepuppet;

namespace {

// Brute force: maximise the objective over θ = (p, 1 − p) on a fine grid plus golden refinement.
double best_two(double w1, double w2, double z) {
  auto f = [&](double p) {
    const double q = 1.0 - p;
    double v = 0;
    v += (p > 0) ? (w1 + z * p) * std::log(p) : (w1 > 0 ? -INFINITY : 0.0);
    v += (q > 0) ? (w2 + z * q) * std::log(q) : (w2 > 0 ? -INFINITY : 0.0);
    return v;
  };
  double best = -INFINITY, bp = 0;
  const int n = 200000;
  for (int i = 0; i <= n; ++i) {
    const double p = static_cast<double>(i) / n;
    if (f(p) > best) { best = f(p); bp = p; }
  }
  double lo = std::max(0.0, bp - 1.0 / n), hi = std::min(1.0, bp + 1.0 / n);
  for (int it = 0; it < 200; ++it) {
    const double a = lo + (hi - lo) * 0.382, b = lo + (hi - lo) * 0.618;
    if (f(a) < f(b)) lo = a; else hi = b;
  }
  return std::max(best, f(0.5 * (lo + hi)));
}

}  // namespace

TEST_CASE("Lambert W branches satisfy w + log|w| = log|x| across the double range") {
  for (double L : {-1.0 - 1e-12, -1.0 - 1e-6, -1.1, -2.0, -2.6, -10.0, -700.0, -1e5, -1e200}) {
    const double w = lambert_wm1_log(L);
    CHECK(w <= -1.0);
    const double d = w + 1.0;
    const double f = (std::abs(d) < 0.5) ? (d + std::log1p(-d)) - (L + 1.0) : w + std::log(-w) - L;
    CHECK(std::abs(f) <= 1e-13 * std::max(1.0, std::abs(L)));
  }
  // Near the branch point: W₋₁ ≈ −1 − sqrt(2(1 + e x)).
  CHECK(lambert_wm1_log(-1.0 - 1e-9) == doctest::Approx(-1.0 - std::sqrt(2e-9)).epsilon(1e-8));
  CHECK(lambert_wm1_log(std::log(2.0 * std::exp(-2.0))) == doctest::Approx(-2.0));  // W(−2e⁻²) = −2
  for (double L : {-700.0, -20.0, -1.0, 0.0, 1.0, 1.5, 5.0, 700.0, 1e6, 1e250}) {
    const double w = lambert_w0_log(L);
    if (L < 0) {
      CHECK(w * std::exp(w) == doctest::Approx(std::exp(L)).epsilon(1e-14));
    } else {
      CHECK(w + std::log(w) == doctest::Approx(L).epsilon(1e-14));
    }
  }
  CHECK(lambert_w0_log(1.0) == doctest::Approx(1.0));  // W(e) = 1
  CHECK_THROWS_AS(lambert_wm1_log(-0.5), std::invalid_argument);
}

TEST_CASE("entropic multinomial equals a brute-force maximisation for two entries") {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-3.0, 2.0);
  for (int t = 0; t < 60; ++t) {
    const double w1 = std::pow(10.0, u(rng)), w2 = std::pow(10.0, u(rng));
    const double z = (t % 3 == 0) ? -std::pow(10.0, u(rng) / 2) : std::pow(10.0, u(rng) / 2);
    VectorXd om(2);
    om << w1, w2;
    const VectorXd th = entropic_multinomial(om, z);
    CHECK(th.sum() == doctest::Approx(1.0).epsilon(1e-14));
    const double ours = entropic_objective(om, th, z);
    const double ref = best_two(w1, w2, z);
    CHECK(ours >= ref - 1e-9 * std::max(1.0, std::abs(ref)));
  }
}

TEST_CASE("entropic multinomial limits: ML at Z = 0, extinction, single survivor, Z < 0") {
  VectorXd om(4);
  om << 3, 0, 1, 6;
  const VectorXd ml = entropic_multinomial(om, 0.0);
  CHECK((ml - om / 10.0).cwiseAbs().maxCoeff() == 0.0);
  const VectorXd th = entropic_multinomial(om, 1.0);
  CHECK(th[1] == 0.0);  // zero evidence is extinguished
  CHECK(th[3] > ml[3]);  // the prior sharpens toward the dominant entry
  CHECK(th[2] < ml[2]);
  VectorXd one(3);
  one << 0, 2.5, 0;
  CHECK(entropic_multinomial(one, 1.0) == VectorXd::Unit(3, 1));
  // Z < 0 (high temperature) spreads mass, even onto zero-evidence entries.
  const VectorXd hot = entropic_multinomial(om, -2.0);
  CHECK(hot[1] > 0);
  CHECK(hot[3] < ml[3]);
  // The stationarity condition ω/θ + Z log θ = const holds on the evidence entries.
  const double c0 = om[0] / th[0] + std::log(th[0]);
  for (Index k : {2, 3}) CHECK(om[k] / th[k] + std::log(th[k]) == doctest::Approx(c0).epsilon(1e-10));
  // Tiny totals: the prior dominates and nearly all mass goes to the largest entry.
  VectorXd tiny(3);
  tiny << 1e-12, 3e-12, 2e-12;
  const VectorXd tt = entropic_multinomial(tiny, 1.0);
  CHECK(tt[1] > 1.0 - 1e-10);
  CHECK(tt[0] > 0);
  CHECK(tt.sum() == doctest::Approx(1.0));
}

TEST_CASE("entropic multinomial rejects bad input") {
  VectorXd bad(2);
  bad << 1.0, -0.5;
  CHECK_THROWS_AS(entropic_multinomial(bad, 1.0), std::invalid_argument);
  bad << 1.0, std::numeric_limits<double>::quiet_NaN();
  CHECK_THROWS_AS(entropic_multinomial(bad, 1.0), std::invalid_argument);
  CHECK_THROWS_AS(entropic_multinomial(VectorXd::Zero(3), 1.0), std::invalid_argument);
  CHECK_THROWS_AS(entropic_multinomial(VectorXd::Ones(3), std::numeric_limits<double>::infinity()),
                  std::invalid_argument);
  CHECK(entropic_multinomial(VectorXd::Zero(3), -1.0).isApprox(VectorXd::Constant(3, 1.0 / 3)));
}

TEST_CASE("entropic covariance is the stationary point of its objective") {
  // One state, D = 2: K = (S + c w I)/(w + Z) maximises −(w+Z)/2 log|K| − ½ tr(K⁻¹(S + c w I)).
  GaussianStats st;
  st.type = CovarianceType::Full;
  st.shift = VectorXd::Zero(2);
  st.weight = VectorXd::Constant(1, 5.0);
  st.sum = RowMatrixXd(1, 2);
  st.sum << 5.0, 10.0;  // mean (1, 2)
  st.outer = RowMatrixXd(2, 2);
  st.outer << 5.0 + 4.0, 10.0 + 1.0, 10.0 + 1.0, 20.0 + 3.0;  // S = [[4, 1], [1, 3]]
  const double z = 1.0, c = 0.5;
  const GaussianParams p = entropic_gaussian_mstep(st, z, c, RowMatrixXd(), RowMatrixXd());
  CHECK(p.means(0, 0) == doctest::Approx(1.0));
  CHECK(p.means(0, 1) == doctest::Approx(2.0));
  Eigen::Matrix2d S;
  S << 4, 1, 1, 3;
  const Eigen::Matrix2d K = p.covars;
  CHECK((K - (S + 5.0 * c * Eigen::Matrix2d::Identity()) / 6.0).cwiseAbs().maxCoeff() < 1e-12);
  auto obj = [&](const Eigen::Matrix2d& M) {
    return -(5.0 + z) / 2 * std::log(M.determinant()) -
           0.5 * (M.inverse() * (S + 5.0 * c * Eigen::Matrix2d::Identity())).trace();
  };
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0, 0.05);
  for (int t = 0; t < 50; ++t) {
    Eigen::Matrix2d E;
    E << g(rng), g(rng), 0, g(rng);
    E(1, 0) = E(0, 1);
    CHECK(obj(K + E) <= obj(K) + 1e-12);
  }
  // Z = 0 and no floor: the maximum-likelihood covariance.
  const GaussianParams ml = entropic_gaussian_mstep(st, 0.0, 0.0, RowMatrixXd(), RowMatrixXd());
  CHECK((ml.covars - RowMatrixXd(S / 5.0)).cwiseAbs().maxCoeff() < 1e-12);
  // Z = 0 with a floor: Baum–Welch's floored estimate S/w + c I, the same as gaussian_mstep.
  const GaussianParams bw = entropic_gaussian_mstep(st, 0.0, c, RowMatrixXd(), RowMatrixXd());
  const GaussianParams bw_ref = gaussian_mstep(st, c, RowMatrixXd(), RowMatrixXd());
  CHECK((bw.covars - RowMatrixXd(S / 5.0 + c * Eigen::Matrix2d::Identity())).cwiseAbs().maxCoeff() < 1e-12);
  CHECK((bw.covars - bw_ref.covars).cwiseAbs().maxCoeff() < 1e-12);
}

TEST_CASE("transition trimming flags weak arcs only and keeps every row alive") {
  RowMatrixXd A(2, 3), xi(2, 3);
  A << 0.7, 0.299, 0.001, 0.5, 0.5, 0.0;
  xi << 70, 29.9, 0.001, 10, 10, 0;
  const RowMatrixXd flags = transition_trim_candidates(A, xi, 1.0);
  // arc (0,2): log 0.001 = −6.9 <= −(0.001/0.001)/1 = −1 → trimmed; (0,1): −1.2 > −100 → kept.
  CHECK(flags(0, 2) == 1);
  CHECK(flags(0, 1) == 0);
  CHECK(flags.row(1).sum() == 0);
  CHECK(transition_trim_candidates(A, xi, 0.0).sum() == 0);
  const RowMatrixXd B = trim_transitions(A, flags);
  CHECK(B(0, 2) == 0);
  CHECK(B.row(0).sum() == doctest::Approx(1.0));
  CHECK(B(0, 0) / B(0, 1) == doctest::Approx(0.7 / 0.299));
  RowMatrixXd all = RowMatrixXd::Ones(2, 3);
  CHECK_THROWS_AS(trim_transitions(A, all), std::invalid_argument);
}

TEST_CASE("annealing schedule ramps monotonically from z_start to z_final") {
  const VectorXd z = anneal_schedule(10, -1.0, 1.0, 6);
  CHECK(z[0] == doctest::Approx(-1.0));
  for (Index t = 1; t < 10; ++t) CHECK(z[t] >= z[t - 1]);
  for (Index t = 6; t < 10; ++t) CHECK(z[t] == 1.0);
  CHECK(anneal_schedule(3, -1.0, 1.0, 0) == VectorXd::Constant(3, 1.0));
  CHECK_THROWS_AS(anneal_schedule(0, 0.0, 1.0, 0), std::invalid_argument);
}

TEST_CASE("state costs: closed form for diagonal Gaussians, and they add up to the log prior") {
  RowMatrixXd A(2, 2), C(2, 3);
  A << 0.5, 0.5, 0.0, 1.0;
  C << 1.0, 2.0, 4.0, 0.5, 0.5, 0.5;
  VectorXd pi(2);
  pi << 0.25, 0.75;
  const double z = 1.5, c = 0.2;
  const VectorXd cost = entropic_state_costs(A, C, CovarianceType::Diagonal, z, c);
  const double l2pe = std::log(2 * M_PI * std::exp(1.0));
  CHECK(cost[0] == doctest::Approx(z * std::log(2.0) + 0.5 * z * (3 * l2pe + std::log(8.0)) + 0.5 * c * 1.75));
  CHECK(cost[1] == doctest::Approx(0.5 * z * (3 * l2pe + 3 * std::log(0.5)) + 0.5 * c * 6.0));
  const double lp = entropic_log_prior(pi, A, C, CovarianceType::Diagonal, z, c);
  CHECK(lp == doctest::Approx(z * (0.25 * std::log(0.25) + 0.75 * std::log(0.75)) - cost.sum()));
  // Full covariances that are diagonal give the same costs.
  RowMatrixXd F = RowMatrixXd::Zero(6, 3);
  for (Index i = 0; i < 2; ++i)
    for (Index k = 0; k < 3; ++k) F(i * 3 + k, k) = C(i, k);
  CHECK((entropic_state_costs(A, F, CovarianceType::Full, z, c) - cost).cwiseAbs().maxCoeff() < 1e-12);
}

TEST_CASE("entropic_rows: row-wise estimate, rows without evidence kept, bad input rejected") {
  RowMatrixXd counts(3, 3), old(3, 3);
  counts << 5, 1, 0, 0, 0, 0, 2, 2, 2;
  old << 0.2, 0.3, 0.5, 0.1, 0.8, 0.1, 1.0 / 3, 1.0 / 3, 1.0 / 3;
  const RowMatrixXd r = entropic_rows(counts, 1.0, old);
  CHECK(r.row(0).transpose().isApprox(entropic_multinomial(counts.row(0).transpose(), 1.0)));
  CHECK(r.row(1) == old.row(1));
  for (Index k = 0; k < 3; ++k) CHECK(r(2, k) == doctest::Approx(1.0 / 3));  // symmetric evidence
  CHECK_THROWS_AS(entropic_rows(counts, 1.0, RowMatrixXd(1, 3)), std::invalid_argument);
  counts(0, 0) = -1;
  CHECK_THROWS_AS(entropic_rows(counts, 1.0, old), std::invalid_argument);
}
