#include "voicepuppet/entropic.hpp"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <limits>

namespace voicepuppet {
namespace {

constexpr double kLog2PiE = 2.8378770664093454835606594728112;  // log(2πe)
constexpr double kPi = 3.14159265358979323846264338327950288;

void check_omega(const VectorRef& omega, const char* name) {
  if (omega.size() == 0) fail_argument(name, " is empty; give at least one entry of evidence");
  for (Index k = 0; k < omega.size(); ++k) {
    if (!std::isfinite(omega[k]) || omega[k] < 0) {
      fail_argument(name, "[", k, "] = ", omega[k], ": evidence (expected counts) must be finite and >= 0; "
                    "check the E-step that produced it");
    }
  }
}

void check_z(double z) {
  if (!std::isfinite(z)) fail_argument("z (the entropic prior weight) must be finite, got ", z);
}

// θ_k on the W₋₁ branch for log r_k and a = 1 + λ/Z: θ = r / (−W₋₁(−r·e^a)). Also returns w.
double theta_wm1(double log_r, double a, double& w) {
  const double L = std::min(log_r + a, -1.0);  // ≤ −1 by construction; clamp rounding
  w = lambert_wm1_log(L);
  return std::exp(log_r - std::log(-w));
}

// Z > 0, at least two entries with evidence. Returns θ over all entries.
VectorXd solve_positive_z(const VectorXd& omega, double z) {
  const Index K = omega.size();
  VectorXd log_r(K);
  Index m = -1, n_pos = 0;
  for (Index k = 0; k < K; ++k) {
    if (omega[k] > 0) {
      log_r[k] = std::log(omega[k]) - std::log(z);
      ++n_pos;
      if (m < 0 || omega[k] > omega[m]) m = k;
    }
  }
  const double r_m = std::exp(log_r[m]);
  // Parametrise by v = 1 − θ_m: θ_m's own stationarity fixes a(v) = −r_m/(1−v) − log(1−v); the
  // others follow on W₋₁ and R(v) = Σ_{k≠m} θ_k(a(v)) − v has its maximiser at the root.
  auto residual = [&](double v, double& dR_dv) {
    const double u = 1.0 - v;
    const double a = -r_m / u - std::log1p(-v);
    const double da_du = r_m / (u * u) - 1.0 / u;
    double S = 0, dS_da = 0;
    for (Index k = 0; k < K; ++k) {
      if (k == m || !(omega[k] > 0)) continue;
      double w;
      const double th = theta_wm1(log_r[k], a, w);
      S += th;
      const double denom = std::min(1.0 + w, -1e-300);
      dS_da += -th / denom;
    }
    dR_dv = -dS_da * da_du - 1.0;
    return S - v;
  };
  const double v_hi = 1.0 - 1.0 / static_cast<double>(n_pos);
  double dummy;
  // R(0+) = Σ θ_k(a(0)) > 0; find a v_lo with R > 0 by halving from that value.
  double v_lo = std::min(v_hi, residual(0.0, dummy) + 0.0);
  if (!(v_lo > 0)) {  // the others underflow: θ is the vertex at m
    VectorXd th = VectorXd::Zero(K);
    th[m] = 1;
    return th;
  }
  for (int i = 0; i < 4000 && residual(v_lo, dummy) <= 0; ++i) v_lo *= 0.5;
  double s_lo = std::log(v_lo), s_hi = std::log(v_hi);
  double R_hi = residual(v_hi, dummy);
  double s = s_lo;
  if (R_hi >= 0) {
    s = s_hi;  // root at the upper end (all entries equal)
  } else {
    s = 0.5 * (s_lo + s_hi);
    for (int it = 0; it < 300; ++it) {
      double dR_dv;
      const double v = std::exp(s);
      const double R = residual(v, dR_dv);
      if (R > 0) s_lo = s; else s_hi = s;
      if (R == 0) break;
      const double dR_ds = dR_dv * v;
      double s_new = (dR_ds < 0 && std::isfinite(dR_ds)) ? s - R / dR_ds : 0.5 * (s_lo + s_hi);
      if (!(s_new > s_lo && s_new < s_hi)) s_new = 0.5 * (s_lo + s_hi);
      const double step = std::abs(s_new - s);
      s = s_new;
      if (step <= 1e-15 * std::max(1.0, std::abs(s)) || s_hi - s_lo <= 1e-15 * std::max(1.0, std::abs(s))) break;
    }
  }
  const double v = std::exp(s);
  const double a = -r_m / (1.0 - v) - std::log1p(-v);
  VectorXd th = VectorXd::Zero(K);
  double rest = 0;
  for (Index k = 0; k < K; ++k) {
    if (k == m || !(omega[k] > 0)) continue;
    double w;
    th[k] = theta_wm1(log_r[k], a, w);
    rest += th[k];
  }
  if (rest >= 1) {  // rounding at the all-equal end: renormalise
    th[m] = th.maxCoeff();
    return th / th.sum();
  }
  th[m] = 1.0 - rest;
  return th;
}

// Z < 0: every entry on W₀; θ_k(a) = exp(W₀(r_k e^a) − a), a = 1 + λ/Z, Σθ decreasing in a.
VectorXd solve_negative_z(const VectorXd& omega, double z) {
  const Index K = omega.size();
  VectorXd log_r(K);
  for (Index k = 0; k < K; ++k) {
    log_r[k] = omega[k] > 0 ? std::log(omega[k]) - std::log(-z) : -std::numeric_limits<double>::infinity();
  }
  auto eval = [&](double a, VectorXd& th, double& dG_da) {  // G = log Σθ
    double S = 0, dS = 0;
    for (Index k = 0; k < K; ++k) {
      const double w = omega[k] > 0 ? lambert_w0_log(log_r[k] + a) : 0.0;
      th[k] = std::exp(w - a);
      S += th[k];
      dS += -th[k] / (1.0 + w);
    }
    dG_da = dS / S;
    return std::log(S);
  };
  VectorXd th(K);
  double d;
  double a_lo = 0, a_hi = 1;  // G(0) >= log K >= 0
  for (int i = 0; i < 2100 && eval(a_hi, th, d) > 0; ++i) a_hi *= 2;
  double a = 0.5 * (a_lo + a_hi);
  for (int it = 0; it < 300; ++it) {
    double dG;
    const double G = eval(a, th, dG);
    if (G > 0) a_lo = a; else a_hi = a;
    if (G == 0) break;
    double a_new = dG < 0 ? a - G / dG : 0.5 * (a_lo + a_hi);
    if (!(a_new > a_lo && a_new < a_hi)) a_new = 0.5 * (a_lo + a_hi);
    const double step = std::abs(a_new - a);
    a = a_new;
    if (step <= 1e-15 * std::max(1.0, std::abs(a)) || a_hi - a_lo <= 1e-15 * std::max(1.0, std::abs(a))) break;
  }
  eval(a, th, d);
  return th / th.sum();
}

void check_row_stochastic(const MatrixRef& m, const char* name) {
  require_finite(m, name);
  for (Index i = 0; i < m.rows(); ++i) {
    if ((m.row(i).array() < 0).any()) fail_argument(name, " row ", i, " has a negative entry");
    if (std::abs(m.row(i).sum() - 1.0) > 1e-6) {
      fail_argument(name, " row ", i, " sums to ", m.row(i).sum(), ", expected 1; normalise it");
    }
  }
}

}  // namespace

double lambert_wm1_log(double L) {
  if (std::isnan(L) || L > -1.0 + 1e-12) {
    fail_argument("lambert_wm1_log: log(-x) must be <= -1 (x in [-1/e, 0)), got ", L);
  }
  if (L == -std::numeric_limits<double>::infinity()) return -std::numeric_limits<double>::infinity();
  if (L >= -1.0) return -1.0;
  double w;
  if (L < -2.5) {
    const double l2 = std::log(-L);
    w = L - l2 + l2 / L;  // asymptotic start (de Bruijn)
  } else {
    const double p = -std::sqrt(2.0 * -std::expm1(1.0 + L));  // series about the branch point
    w = -1.0 + p - p * p / 3.0 + 11.0 / 72.0 * p * p * p;
  }
  for (int it = 0; it < 50; ++it) {
    // f(w) = w + log(−w) − L, written about w = −1 (d = w + 1) where it would cancel.
    const double d = w + 1.0;
    const double f = (std::abs(d) < 0.5) ? (d + std::log1p(-d)) - (L + 1.0) : w + std::log(-w) - L;
    if (d == 0) break;
    const double step = f * w / d;  // Newton: f' = (w+1)/w
    double w_new = w - step;
    if (!(w_new <= -1.0)) w_new = 0.5 * (w - 1.0);  // stay on the branch
    const bool done = std::abs(w_new - w) <= 4e-16 * std::abs(w);
    w = w_new;
    if (done) break;
  }
  return w;
}

double lambert_w0_log(double L) {
  if (std::isnan(L)) fail_argument("lambert_w0_log: log x is NaN");
  if (L == std::numeric_limits<double>::infinity()) return L;
  if (L <= 1.0) {
    const double x = std::exp(L);
    if (x == 0) return 0.0;
    double w = std::log1p(x);
    for (int it = 0; it < 50; ++it) {
      const double ew = std::exp(w);
      const double f = w * ew - x;
      const double step = f / (ew * (w + 1.0) - (w + 2.0) * f / (2.0 * w + 2.0));  // Halley
      w -= step;
      if (std::abs(step) <= 4e-16 * std::abs(w)) break;
    }
    return w;
  }
  double w = L - std::log(L);
  for (int it = 0; it < 50; ++it) {  // Newton on w + log w = L
    const double step = (w + std::log(w) - L) * w / (w + 1.0);
    w -= step;
    if (std::abs(step) <= 4e-16 * std::abs(w)) break;
  }
  return w;
}

double entropic_objective(const VectorRef& omega, const VectorRef& theta, double z) {
  check_omega(omega, "omega");
  check_z(z);
  if (theta.size() != omega.size()) {
    fail_argument("theta must have ", omega.size(), " entries (like omega), got ", theta.size());
  }
  double f = 0;
  for (Index k = 0; k < omega.size(); ++k) {
    if (theta[k] < 0 || !std::isfinite(theta[k])) fail_argument("theta[", k, "] = ", theta[k], " is not a probability");
    if (theta[k] == 0) {
      if (omega[k] > 0) return -std::numeric_limits<double>::infinity();
      continue;
    }
    f += (omega[k] + z * theta[k]) * std::log(theta[k]);
  }
  return f;
}

VectorXd entropic_multinomial(const VectorRef& omega_in, double z) {
  check_omega(omega_in, "omega");
  check_z(z);
  const VectorXd omega = omega_in;
  const Index K = omega.size();
  const double total = omega.sum();
  Index n_pos = 0, m = 0;
  for (Index k = 0; k < K; ++k) {
    if (omega[k] > 0) {
      ++n_pos;
      if (omega[k] > omega[m] || !(omega[m] > 0)) m = k;
    }
  }
  if (z < 0) return solve_negative_z(omega, z);
  if (n_pos == 0) {
    fail_argument("omega is all zero: with z >= 0 (got ", z, ") the estimate is not unique; "
                  "keep the previous parameters for an entry without evidence");
  }
  if (z == 0) return omega / total;
  if (n_pos == 1) {
    VectorXd th = VectorXd::Zero(K);
    th[m] = 1;
    return th;
  }
  return solve_positive_z(omega, z);
}

RowMatrixXd entropic_rows(const MatrixRef& counts, double z, const MatrixRef& old) {
  require_finite(counts, "counts");
  check_z(z);
  if ((counts.array() < 0).any()) {
    fail_argument("counts has negative entries; expected counts must be >= 0 (check the E-step)");
  }
  RowMatrixXd out(counts.rows(), counts.cols());
  for (Index i = 0; i < counts.rows(); ++i) {
    if (counts.row(i).sum() > 0 || z < 0) {
      out.row(i) = entropic_multinomial(counts.row(i).transpose(), z).transpose();
    } else {
      if (old.rows() != counts.rows() || old.cols() != counts.cols()) {
        fail_argument("counts row ", i, " has no evidence and old has shape ", shape_of(old), ", expected ",
                      shape_of(counts), ": pass the previous estimate as old");
      }
      out.row(i) = old.row(i);
    }
  }
  return out;
}

GaussianParams entropic_gaussian_mstep(const GaussianStats& stats, double z, double prior,
                                       const MatrixRef& old_means, const MatrixRef& old_covars) {
  check_z(z);
  if (!(prior >= 0) || !std::isfinite(prior)) {
    fail_argument("prior (covariance regulariser) must be finite and >= 0, got ", prior);
  }
  const double zp = std::max(z, 0.0);
  const Index n_states = stats.weight.size(), d = stats.shift.size();
  const bool full = stats.type == CovarianceType::Full;
  const bool have_old = old_means.rows() == n_states && old_means.cols() == d &&
                        old_covars.rows() == (full ? n_states * d : n_states) && old_covars.cols() == d;
  GaussianParams p;
  p.means.resize(n_states, d);
  p.covars.resize(full ? n_states * d : n_states, d);
  for (Index n = 0; n < n_states; ++n) {
    const double w = stats.weight[n];
    if (w < 1e-10) {
      if (!have_old) {
        fail_argument("state ", n, " has no evidence (weight ", w, ") and old_means/old_covars do not have the "
                      "model's shape; pass the previous parameters");
      }
      p.means.row(n) = old_means.row(n);
      if (full) p.covars.middleRows(n * d, d) = old_covars.middleRows(n * d, d);
      else p.covars.row(n) = old_covars.row(n);
      continue;
    }
    if (!(w + zp > 0)) fail_numeric("state ", n, ": weight + Z = ", w + zp, " is not positive");
    const VectorXd m = stats.sum.row(n).transpose() / w;
    p.means.row(n) = (stats.shift + m).transpose();
    if (full) {
      auto c = p.covars.middleRows(n * d, d);
      c = stats.outer.middleRows(n * d, d);
      c.noalias() -= w * (m * m.transpose());
      c = 0.5 * (c + c.transpose()).eval();
      c.diagonal().array() += prior * w;  // the floor per frame, as in Baum–Welch
      c /= (w + zp);
    } else {
      p.covars.row(n) = (stats.outer.row(n) - w * m.transpose().cwiseAbs2()).cwiseMax(0.0);
      p.covars.row(n).array() += prior * w;
      p.covars.row(n) /= (w + zp);
    }
  }
  return p;
}

VectorXd entropic_state_costs(const MatrixRef& transmat, const MatrixRef& covars, CovarianceType type, double z,
                              double prior) {
  check_z(z);
  if (!(prior >= 0) || !std::isfinite(prior)) {
    fail_argument("prior (covariance regulariser) must be finite and >= 0, got ", prior);
  }
  const Index n = transmat.rows();
  if (transmat.cols() != n) fail_argument("transmat must be square, got ", shape_of(transmat));
  check_row_stochastic(transmat, "transmat");
  const double zp = std::max(z, 0.0);
  const bool full = type == CovarianceType::Full;
  const Index d = covars.cols();
  if (covars.rows() != (full ? n * d : n)) fail_argument("covars has shape ", shape_of(covars), " for ", n, " states");
  require_finite(covars, "covars");
  VectorXd cost(n);
  for (Index i = 0; i < n; ++i) {
    double row = 0;
    for (Index j = 0; j < n; ++j) {
      const double p = transmat(i, j);
      if (p > 0) row += p * std::log(p);
    }
    double log_det, trace_inv;
    if (full) {
      const Eigen::MatrixXd c = covars.middleRows(i * d, d);
      Eigen::LLT<Eigen::MatrixXd> llt(c);
      if (llt.info() != Eigen::Success) fail_argument("covars[", i, "] is not positive definite");
      const Eigen::MatrixXd L = llt.matrixL();
      log_det = 2.0 * L.diagonal().array().log().sum();
      const Eigen::MatrixXd Linv = L.triangularView<Eigen::Lower>().solve(Eigen::MatrixXd::Identity(d, d));
      trace_inv = Linv.squaredNorm();  // tr K⁻¹ = ‖L⁻¹‖²_F
    } else {
      if ((covars.row(i).array() <= 0).any()) fail_argument("covars[", i, "] has a non-positive variance");
      log_det = covars.row(i).array().log().sum();
      trace_inv = covars.row(i).array().inverse().sum();
    }
    cost[i] = -z * row + 0.5 * zp * (static_cast<double>(d) * kLog2PiE + log_det) + 0.5 * prior * trace_inv;
  }
  return cost;
}

double entropic_log_prior(const VectorRef& startprob, const MatrixRef& transmat, const MatrixRef& covars,
                          CovarianceType type, double z, double prior) {
  check_z(z);
  if (startprob.size() != transmat.rows()) {
    fail_argument("startprob must have one entry per state (", transmat.rows(), "), got ", startprob.size());
  }
  double lp = 0;
  for (Index i = 0; i < startprob.size(); ++i) {
    if (startprob[i] > 0) lp += z * startprob[i] * std::log(startprob[i]);
  }
  return lp - entropic_state_costs(transmat, covars, type, z, prior).sum();
}

RowMatrixXd transition_trim_candidates(const MatrixRef& transmat, const MatrixRef& expected, double z) {
  check_z(z);
  check_row_stochastic(transmat, "transmat");
  if (expected.rows() != transmat.rows() || expected.cols() != transmat.cols()) {
    fail_argument("expected (transition counts) must have the shape of transmat ", shape_of(transmat), ", got ",
                  shape_of(expected));
  }
  require_finite(expected, "expected");
  RowMatrixXd flags = RowMatrixXd::Zero(transmat.rows(), transmat.cols());
  if (!(z > 0)) return flags;
  for (Index i = 0; i < transmat.rows(); ++i) {
    Index keep;
    transmat.row(i).maxCoeff(&keep);
    for (Index j = 0; j < transmat.cols(); ++j) {
      const double th = transmat(i, j);
      if (j == keep || !(th > 0)) continue;
      const double grad = expected(i, j) / th;  // ∂ log L / ∂θ_ij
      if (std::log(th) <= -grad / z) flags(i, j) = 1;
    }
  }
  return flags;
}

RowMatrixXd trim_transitions(const MatrixRef& transmat, const MatrixRef& flags) {
  if (flags.rows() != transmat.rows() || flags.cols() != transmat.cols()) {
    fail_argument("flags must have the shape of transmat ", shape_of(transmat), ", got ", shape_of(flags));
  }
  RowMatrixXd out = transmat;
  for (Index i = 0; i < out.rows(); ++i) {
    for (Index j = 0; j < out.cols(); ++j) {
      if (flags(i, j) != 0) out(i, j) = 0;
    }
    const double s = out.row(i).sum();
    if (!(s > 0)) fail_argument("trimming the flagged arcs would leave row ", i, " of transmat with no exit; "
                                "keep at least one arc per state");
    out.row(i) /= s;
  }
  return out;
}

VectorXd anneal_schedule(Index n_iter, double z_start, double z_final, Index n_anneal) {
  if (n_iter < 1) fail_argument("n_iter must be >= 1, got ", n_iter);
  if (n_anneal < 0) fail_argument("n_anneal must be >= 0, got ", n_anneal);
  if (!std::isfinite(z_start) || !std::isfinite(z_final)) {
    fail_argument("z_start and z_final must be finite, got ", z_start, " and ", z_final);
  }
  VectorXd z(n_iter);
  for (Index t = 0; t < n_iter; ++t) {
    if (t >= n_anneal) {
      z[t] = z_final;
    } else {
      const double c = 0.5 * (1.0 + std::cos(kPi * static_cast<double>(t) / static_cast<double>(n_anneal)));
      z[t] = z_final + (z_start - z_final) * c;
    }
  }
  return z;
}

}  // namespace voicepuppet
