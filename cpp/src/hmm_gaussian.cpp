#include "voicepuppet/hmm_gaussian.hpp"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace voicepuppet {
namespace {

constexpr double kLog2Pi = 1.8378770664093454835606594728112;
constexpr Index kBlockFrames = 1024;  // frames per block of the emission GEMM (cache-sized)

void check_means(const MatrixRef& means, Index n_dims) {
  if (means.rows() == 0) fail_argument("means is empty; a model needs at least one state");
  if (means.cols() != n_dims) {
    fail_argument("means must have ", n_dims, " columns (the observation dimension), got shape ", shape_of(means));
  }
  require_finite(means, "means");
}

// Inverse of the upper Cholesky factor U (Σ = UᵀU) of state n, and its log determinant.
// The emission of every frame is then ‖(x − μ) U⁻¹‖²: one matrix product per block of frames.
void factor_state(const MatrixRef& covars, Index n, Index d, RowMatrixXd& u_inv, double& log_det) {
  const Eigen::MatrixXd cov = covars.middleRows(n * d, d);
  Eigen::LLT<Eigen::MatrixXd> llt(cov);
  if (llt.info() != Eigen::Success || !(llt.matrixL().toDenseMatrix().diagonal().array() > 0).all()) {
    fail_argument("covars[", n, "] is not positive definite; raise the variance floor "
                  "(min_covar) or give the state more data");
  }
  const Eigen::MatrixXd L = llt.matrixL();
  log_det = 2.0 * L.diagonal().array().log().sum();
  // U⁻¹ = (Lᵀ)⁻¹, by a triangular solve against the identity (never Σ⁻¹ itself).
  u_inv = L.transpose().triangularView<Eigen::Upper>().solve(Eigen::MatrixXd::Identity(d, d));
}

// SplitMix-style uniform in [0, 1) with 53 random bits, portable across standard libraries.
double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }

double standard_normal(std::mt19937_64& rng) {  // Box-Muller, portable and deterministic
  double u1 = uniform01(rng);
  while (u1 <= 0) u1 = uniform01(rng);
  const double u2 = uniform01(rng);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586476925286766559 * u2);
}

Index sample_categorical(const double* p, Index n, std::mt19937_64& rng) {
  const double u = uniform01(rng);
  double c = 0;
  for (Index i = 0; i < n; ++i) {
    c += p[i];
    if (u < c) return i;
  }
  for (Index i = n - 1; i >= 0; --i) {
    if (p[i] > 0) return i;
  }
  return n - 1;
}

}  // namespace

CovarianceType parse_covariance_type(const std::string& name) {
  if (name == "full") return CovarianceType::Full;
  if (name == "diag") return CovarianceType::Diagonal;
  fail_argument("covariance type must be 'full' or 'diag', got '", name, "'");
}

void check_covariances(const MatrixRef& covars, Index n_states, Index d, CovarianceType type) {
  require_finite(covars, "covars");
  if (type == CovarianceType::Full) {
    if (covars.rows() != n_states * d || covars.cols() != d) {
      fail_argument("full covars must have shape (", n_states, "*", d, ", ", d, ") i.e. [N, D, D] stacked, got ",
                    shape_of(covars));
    }
    for (Index n = 0; n < n_states; ++n) {
      const auto c = covars.middleRows(n * d, d);
      const double asym = (c - c.transpose()).cwiseAbs().maxCoeff();
      if (asym > 1e-8 * std::max(1.0, c.cwiseAbs().maxCoeff())) {
        fail_argument("covars[", n, "] is not symmetric (max |C - Cᵀ| = ", asym, ")");
      }
      RowMatrixXd u;
      double ld;
      factor_state(covars, n, d, u, ld);
    }
  } else {
    if (covars.rows() != n_states || covars.cols() != d) {
      fail_argument("diag covars must have shape (", n_states, ", ", d, "), got ", shape_of(covars));
    }
    if (!(covars.array() > 0).all()) {
      fail_argument("diag covars must be positive; raise the variance floor (min_covar)");
    }
  }
}

RowMatrixXd gaussian_log_density(const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars,
                                 CovarianceType type) {
  const Index T = X.rows(), d = X.cols(), n_states = means.rows();
  if (T == 0) fail_argument("X has zero frames; pass at least one frame");
  if (d == 0) fail_argument("X has zero columns; observations need at least one dimension");
  require_finite(X, "X");
  check_means(means, d);
  RowMatrixXd out(T, n_states);
  if (type == CovarianceType::Diagonal) {
    check_covariances(covars, n_states, d, type);
    // −½ Σ_d (x−μ)²/σ² expanded as x²·(1/σ²) − 2x·(μ/σ²) + μ²/σ²: three matrix products.
    const RowMatrixXd prec = covars.cwiseInverse();
    const RowMatrixXd mp = means.cwiseProduct(prec);
    const VectorXd c = (means.cwiseProduct(mp)).rowwise().sum() + covars.array().log().matrix().rowwise().sum() +
                       VectorXd::Constant(n_states, d * kLog2Pi);
    out.noalias() = X.cwiseAbs2() * prec.transpose();
    out.noalias() -= 2.0 * X * mp.transpose();
    out.rowwise() += c.transpose();
    out *= -0.5;
    return out;
  }
  if (covars.rows() != n_states * d || covars.cols() != d) {
    fail_argument("full covars must have shape (", n_states, "*", d, ", ", d, ") i.e. [N, D, D] stacked, got ",
                  shape_of(covars));
  }
  require_finite(covars, "covars");
  std::vector<RowMatrixXd> u_inv(static_cast<size_t>(n_states));
  std::vector<RowMatrixXd> mu_u(static_cast<size_t>(n_states));
  VectorXd c(n_states);
  for (Index n = 0; n < n_states; ++n) {
    double ld = 0;
    factor_state(covars, n, d, u_inv[static_cast<size_t>(n)], ld);
    mu_u[static_cast<size_t>(n)] = means.row(n) * u_inv[static_cast<size_t>(n)];
    c[n] = -0.5 * (d * kLog2Pi + ld);
  }
  // Per state, blocks of frames times the triangular U⁻¹: ‖(x − μ)U⁻¹‖² = ‖xU⁻¹ − μU⁻¹‖².
  const bool parallel = static_cast<double>(T) * n_states * d * d > 2e7;
#if defined(_OPENMP)
#pragma omp parallel for schedule(dynamic, 1) if (parallel)
#endif
  for (Index n = 0; n < n_states; ++n) {
    RowMatrixXd Z;
    const auto U = u_inv[static_cast<size_t>(n)].triangularView<Eigen::Upper>();
    for (Index t0 = 0; t0 < T; t0 += kBlockFrames) {
      const Index len = std::min(kBlockFrames, T - t0);
      Z.noalias() = X.middleRows(t0, len) * U;
      Z.rowwise() -= mu_u[static_cast<size_t>(n)].row(0);
      out.col(n).segment(t0, len) = (-0.5 * Z.rowwise().squaredNorm()).array() + c[n];
    }
  }
  (void)parallel;
  return out;
}

GaussianStats& GaussianStats::operator+=(const GaussianStats& o) {
  if (o.weight.size() != weight.size() || o.type != type || !(o.shift.array() == shift.array()).all()) {
    fail_argument("GaussianStats to merge must have the same states, type and shift");
  }
  weight += o.weight;
  sum += o.sum;
  outer += o.outer;
  return *this;
}

GaussianStats gaussian_stats(const MatrixRef& X, const MatrixRef& posteriors, const VectorRef& shift,
                             CovarianceType type) {
  const Index T = X.rows(), d = X.cols(), n_states = posteriors.cols();
  if (posteriors.rows() != T) {
    fail_argument("posteriors must have one row per frame (", T, "), got shape ", shape_of(posteriors));
  }
  if (shift.size() != d) fail_argument("shift must have ", d, " entries, got ", shift.size());
  GaussianStats s;
  s.type = type;
  s.shift = shift;
  const RowMatrixXd Xs = X.rowwise() - shift.transpose();
  s.weight = posteriors.colwise().sum().transpose();
  s.sum.noalias() = posteriors.transpose() * Xs;
  if (type == CovarianceType::Diagonal) {
    s.outer.noalias() = posteriors.transpose() * Xs.cwiseAbs2();
    return s;
  }
  s.outer.resize(n_states * d, d);
  const bool parallel = static_cast<double>(T) * n_states * d * d > 2e7;
#if defined(_OPENMP)
#pragma omp parallel for schedule(dynamic, 1) if (parallel)
#endif
  for (Index n = 0; n < n_states; ++n) {
    // Σ_t γ_tn x_t x_tᵀ as a symmetric rank-T update with rows scaled by √γ (half the flops).
    const RowMatrixXd W = posteriors.col(n).cwiseSqrt().asDiagonal() * Xs;
    RowMatrixXd C = RowMatrixXd::Zero(d, d);
    C.selfadjointView<Eigen::Lower>().rankUpdate(W.transpose());
    s.outer.middleRows(n * d, d) = C.selfadjointView<Eigen::Lower>();
  }
  (void)parallel;
  return s;
}

GaussianParams gaussian_mstep(const GaussianStats& stats, double variance_floor, const MatrixRef& old_means,
                              const MatrixRef& old_covars) {
  if (!(variance_floor >= 0) || !std::isfinite(variance_floor)) {
    fail_argument("variance_floor must be finite and >= 0, got ", variance_floor);
  }
  const Index n_states = stats.weight.size(), d = stats.shift.size();
  const bool full = stats.type == CovarianceType::Full;
  const bool have_old = old_means.rows() == n_states && old_covars.rows() == (full ? n_states * d : n_states);
  GaussianParams p;
  p.means.resize(n_states, d);
  p.covars.resize(full ? n_states * d : n_states, d);
  // Global moments, for states with no evidence when no old parameters are given.
  const double w_all = stats.weight.sum();
  const VectorXd m_all = stats.sum.colwise().sum().transpose() / std::max(w_all, 1e-300);
  for (Index n = 0; n < n_states; ++n) {
    const double w = stats.weight[n];
    if (w < 1e-10) {
      if (have_old) {
        p.means.row(n) = old_means.row(n);
        if (full) {
          p.covars.middleRows(n * d, d) = old_covars.middleRows(n * d, d);
        } else {
          p.covars.row(n) = old_covars.row(n);
        }
        continue;
      }
      p.means.row(n) = (stats.shift + m_all).transpose();
      if (full) {
        Eigen::MatrixXd outer_all = Eigen::MatrixXd::Zero(d, d);
        for (Index k = 0; k < n_states; ++k) outer_all += stats.outer.middleRows(k * d, d);
        p.covars.middleRows(n * d, d) = outer_all / std::max(w_all, 1e-300) - m_all * m_all.transpose();
        p.covars.middleRows(n * d, d).diagonal().array() += variance_floor;
      } else {
        RowMatrixXd sq = stats.outer.colwise().sum() / std::max(w_all, 1e-300);
        p.covars.row(n) = sq.row(0) - m_all.transpose().cwiseAbs2();
        p.covars.row(n).array() += variance_floor;
      }
      continue;
    }
    const VectorXd m = stats.sum.row(n).transpose() / w;  // mean about the shift
    p.means.row(n) = (stats.shift + m).transpose();
    if (full) {
      auto c = p.covars.middleRows(n * d, d);
      c = stats.outer.middleRows(n * d, d) / w;
      c.noalias() -= m * m.transpose();
      c = 0.5 * (c + c.transpose()).eval();
      c.diagonal().array() += variance_floor;
    } else {
      p.covars.row(n) = (stats.outer.row(n) / w) - m.transpose().cwiseAbs2();
      p.covars.row(n) = p.covars.row(n).cwiseMax(0.0);
      p.covars.row(n).array() += variance_floor;
    }
  }
  return p;
}

EStepResult& EStepResult::operator+=(const EStepResult& o) {
  log_likelihood += o.log_likelihood;
  expected_transitions += o.expected_transitions;
  expected_starts += o.expected_starts;
  stats += o.stats;
  return *this;
}

EStepResult gaussian_hmm_estep(const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob,
                               const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars,
                               CovarianceType type, const VectorRef& shift) {
  const RowMatrixXd log_b = gaussian_log_density(X, means, covars, type);
  const ForwardBackwardResult fb = forward_backward(log_b, startprob, transmat, lengths);
  EStepResult r;
  r.log_likelihood = fb.log_likelihood;
  r.expected_transitions = fb.expected_transitions;
  r.expected_starts = fb.expected_starts;
  r.stats = gaussian_stats(X, fb.posteriors, shift, type);
  return r;
}

RowMatrixXd normalize_counts(const MatrixRef& counts, const MatrixRef& old) {
  if (old.rows() != counts.rows() || old.cols() != counts.cols()) {
    fail_argument("old must have the shape of counts ", shape_of(counts), ", got ", shape_of(old));
  }
  require_finite(counts, "counts");
  if ((counts.array() < 0).any()) fail_argument("counts must be non-negative");
  RowMatrixXd out(counts.rows(), counts.cols());
  for (Index i = 0; i < counts.rows(); ++i) {
    const double s = counts.row(i).sum();
    if (s > 0) {
      out.row(i) = counts.row(i) / s;
    } else {
      out.row(i) = old.row(i);
    }
  }
  return out;
}

RowMatrixXd kmeans(const MatrixRef& X, Index k, std::uint64_t seed, Index n_iter) {
  const Index T = X.rows(), d = X.cols();
  if (k <= 0) fail_argument("k must be positive, got ", k);
  if (T < k) fail_argument("k-means needs at least k = ", k, " frames, got ", T, "; use fewer states or more data");
  require_finite(X, "X");
  std::mt19937_64 rng(seed);
  RowMatrixXd centres(k, d);
  VectorXd dist(T);
  centres.row(0) = X.row(static_cast<Index>(rng() % static_cast<std::uint64_t>(T)));
  dist = (X.rowwise() - centres.row(0)).rowwise().squaredNorm();
  for (Index c = 1; c < k; ++c) {
    const double total = dist.sum();
    Index pick = 0;
    if (total > 0) {
      const double u = uniform01(rng) * total;
      double acc = 0;
      pick = T - 1;
      for (Index t = 0; t < T; ++t) {
        acc += dist[t];
        if (u < acc) {
          pick = t;
          break;
        }
      }
    } else {
      pick = static_cast<Index>(rng() % static_cast<std::uint64_t>(T));
    }
    centres.row(c) = X.row(pick);
    dist = dist.cwiseMin((X.rowwise() - centres.row(c)).rowwise().squaredNorm());
  }
  std::vector<Index> label(static_cast<size_t>(T));
  for (Index it = 0; it < n_iter; ++it) {
    // squared distances via ‖x‖² − 2x·c + ‖c‖²
    const RowMatrixXd cross = X * centres.transpose();
    const VectorXd cn = centres.rowwise().squaredNorm();
    bool changed = false;
    for (Index t = 0; t < T; ++t) {
      Index best = 0;
      (cn.transpose() - 2.0 * cross.row(t)).minCoeff(&best);
      if (label[static_cast<size_t>(t)] != best || it == 0) changed = true;
      label[static_cast<size_t>(t)] = best;
    }
    RowMatrixXd sums = RowMatrixXd::Zero(k, d);
    VectorXd counts = VectorXd::Zero(k);
    for (Index t = 0; t < T; ++t) {
      sums.row(label[static_cast<size_t>(t)]) += X.row(t);
      counts[label[static_cast<size_t>(t)]] += 1;
    }
    for (Index c = 0; c < k; ++c) {
      if (counts[c] > 0) centres.row(c) = sums.row(c) / counts[c];
    }
    if (!changed) break;
  }
  return centres;
}

SampleResult gaussian_hmm_sample(const VectorRef& startprob, const MatrixRef& transmat, const MatrixRef& means,
                                 const MatrixRef& covars, CovarianceType type, Index n_frames, std::uint64_t seed) {
  const Transitions tr = make_transitions(startprob, transmat);
  const Index n_states = tr.n_states, d = means.cols();
  if (means.rows() != n_states) {
    fail_argument("means must have one row per state (", n_states, "), got shape ", shape_of(means));
  }
  check_means(means, d);
  check_covariances(covars, n_states, d, type);
  if (n_frames <= 0) fail_argument("n_frames must be positive, got ", n_frames);
  std::vector<Eigen::MatrixXd> L(static_cast<size_t>(n_states));
  for (Index n = 0; n < n_states; ++n) {
    if (type == CovarianceType::Full) {
      L[static_cast<size_t>(n)] = Eigen::LLT<Eigen::MatrixXd>(Eigen::MatrixXd(covars.middleRows(n * d, d))).matrixL();
    } else {
      L[static_cast<size_t>(n)] = covars.row(n).cwiseSqrt().transpose().asDiagonal();
    }
  }
  std::mt19937_64 rng(seed);
  SampleResult r;
  r.X.resize(n_frames, d);
  r.states.resize(n_frames);
  VectorXd z(d);
  Index s = sample_categorical(startprob.data(), n_states, rng);
  for (Index t = 0; t < n_frames; ++t) {
    if (t > 0) {
      const Index k0 = tr.out_ptr[s], k1 = tr.out_ptr[s + 1];
      const Index pick = sample_categorical(tr.out_p.data() + k0, k1 - k0, rng);
      s = tr.out_dst[static_cast<size_t>(k0 + pick)];
    }
    for (Index i = 0; i < d; ++i) z[i] = standard_normal(rng);
    r.states[t] = s;
    r.X.row(t) = means.row(s) + (L[static_cast<size_t>(s)] * z).transpose();
  }
  return r;
}

}  // namespace voicepuppet
