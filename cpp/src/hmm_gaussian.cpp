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
constexpr Index kScreenBlock = 1024;  // frames per block of the float32 screening GEMM

constexpr double kStatsSkip = 1e-13;  // relative share of a state's statistics a skipped frame set may hold

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

namespace {

// Shapes and values of X and the full covariances, checked once per entry point.
void check_full_inputs(const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars) {
  const Index T = X.rows(), d = X.cols(), n_states = means.rows();
  if (T == 0) fail_argument("X has zero frames; pass at least one frame");
  if (d == 0) fail_argument("X has zero columns; observations need at least one dimension");
  require_finite(X, "X");
  check_means(means, d);
  if (covars.rows() != n_states * d || covars.cols() != d) {
    fail_argument("full covars must have shape (", n_states, "*", d, ", ", d, ") i.e. [N, D, D] stacked, got ",
                  shape_of(covars));
  }
  require_finite(covars, "covars");
}

using RowMatrixXf = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
constexpr double kUnitF32 = 0x1.0p-24;  // unit roundoff of float32 (round to nearest)

// Full-covariance Gaussian log densities of X, evaluated in double for all entries (exact_all),
// or screened in float32 with a rigorous per-entry error bound and refined in double for
// chosen entries (screen, refine). See docs/benchmarks.md "## hmm" for the bound.
class FullEmissions {
 public:
  FullEmissions(const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars)
      : X_(X), means_(means), T_(X.rows()), d_(X.cols()), n_(means.rows()) {
    check_full_inputs(X, means, covars);
    u_inv_.resize(static_cast<size_t>(n_));
    mu_u_.resize(static_cast<size_t>(n_));
    c_.resize(n_);
    for (Index n = 0; n < n_; ++n) {
      double ld = 0;
      factor_state(covars, n, d_, u_inv_[static_cast<size_t>(n)], ld);
      mu_u_[static_cast<size_t>(n)] = means.row(n) * u_inv_[static_cast<size_t>(n)];
      c_[n] = -0.5 * (d_ * kLog2Pi + ld);
    }
  }

  Index frames() const { return T_; }
  Index states() const { return n_; }
  bool worth_screening() const { return d_ >= 8 && T_ * n_ >= 64; }

  // Every log density in double: per state, blocks of frames times the triangular U⁻¹,
  // ‖(x − μ)U⁻¹‖² = ‖xU⁻¹ − μU⁻¹‖².
  RowMatrixXd exact_all() const {
    RowMatrixXd out(T_, n_);
    const bool parallel = static_cast<double>(T_) * n_ * d_ * d_ > 2e7;
#if defined(_OPENMP)
#pragma omp parallel for schedule(dynamic, 1) if (parallel)
#endif
    for (Index n = 0; n < n_; ++n) {
      RowMatrixXd Z;
      const auto U = u_inv_[static_cast<size_t>(n)].triangularView<Eigen::Upper>();
      for (Index t0 = 0; t0 < T_; t0 += kBlockFrames) {
        const Index len = std::min(kBlockFrames, T_ - t0);
        Z.noalias() = X_.middleRows(t0, len) * U;
        Z.rowwise() -= mu_u_[static_cast<size_t>(n)].row(0);
        out.col(n).segment(t0, len) = (-0.5 * Z.rowwise().squaredNorm()).array() + c_[n];
      }
    }
    (void)parallel;
    return out;
  }

  // Float32 estimates of all log densities into `log_b` and bounds |estimate − exact| into
  // `bound` (+inf where float32 overflowed; the estimate is then meaningless). With x̃ = x − s
  // (s the mean of the states' means: near the data, and not moved by outlying frames),
  // m = (μ − s)U⁻¹ and ẑ the float32 value of x̃U⁻¹ − m:
  //   ‖ẑ − z‖ ≤ e = (D + 4)·u·(‖x̃‖·‖U⁻¹‖_F + ‖m‖ + ‖ẑ‖)   (rounding of x̃, U⁻¹, m; the D-term
  //   sums of the product, |Σ a_i b_i| error ≤ γ_D Σ|a_i||b_i|, and ‖|x̃||U⁻¹|‖ ≤ ‖x̃‖‖U⁻¹‖_F;
  //   the subtraction), and q̂ = fl32(‖ẑ‖²) has |q̂ − ‖ẑ‖²| ≤ γ_D‖ẑ‖², so
  //   |q̂ − ‖z‖²| ≤ (2‖ẑ‖ + e)·e + γ_D·q̂, and the log density (−½q + c) errs by half that.
  // A factor 1.25 covers the second-order terms of u.
  void screen(RowMatrixXd& log_b, RowMatrixXd& bound) const {
    const VectorXd s = means_.colwise().mean().transpose();
    const RowMatrixXf Xf = (X_.rowwise() - s.transpose()).cast<float>();
    const VectorXd xnorm = (X_.rowwise() - s.transpose()).rowwise().norm();
    log_b.resize(T_, n_);
    bound.resize(T_, n_);
    const double gamma_d = (d_ + 4) * kUnitF32;
    const bool parallel = static_cast<double>(T_) * n_ * d_ * d_ > 4e7;
#if defined(_OPENMP)
#pragma omp parallel for schedule(dynamic, 1) if (parallel)
#endif
    for (Index n = 0; n < n_; ++n) {
      const RowMatrixXd& U = u_inv_[static_cast<size_t>(n)];
      const RowMatrixXf Uf = U.cast<float>();
      const Eigen::RowVectorXd m = (means_.row(n) - s.transpose()) * U;
      const Eigen::RowVectorXf mf = m.cast<float>();
      const double u_norm = U.norm(), m_norm = m.norm();
      // U⁻¹ is upper triangular: the first h columns of xU⁻¹ need only the first h entries of
      // x, so the product is done as two dense blocks (~3/4 of the dense flops), the wide one a
      // multiple of 16 columns (whole SIMD panels).
      const Index h = d_ >= 32 ? d_ - (d_ / 2 + 15) / 16 * 16 : 0;
      RowMatrixXf Z(std::min(kScreenBlock, T_), d_);
      Eigen::VectorXf q;
      for (Index t0 = 0; t0 < T_; t0 += kScreenBlock) {
        const Index len = std::min(kScreenBlock, T_ - t0);
        auto Zb = Z.topRows(len);
        if (h > 0) Zb.leftCols(h).noalias() = Xf.block(t0, 0, len, h) * Uf.topLeftCorner(h, h);
        Zb.rightCols(d_ - h).noalias() = Xf.middleRows(t0, len) * Uf.rightCols(d_ - h);
        Zb.rowwise() -= mf;
        q = Zb.rowwise().squaredNorm();
        for (Index r = 0; r < len; ++r) {
          const Index t = t0 + r;
          const double qh = static_cast<double>(q[r]);
          if (!std::isfinite(qh) || qh > 1e36) {
            log_b(t, n) = 0.0;
            bound(t, n) = std::numeric_limits<double>::infinity();
            continue;
          }
          const double zn = std::sqrt(qh * (1.0 + gamma_d));
          const double e = gamma_d * (xnorm[t] * u_norm + m_norm + zn);
          log_b(t, n) = c_[n] - 0.5 * qh;
          bound(t, n) = 0.625 * ((2.0 * zn + e) * e + gamma_d * qh);  // 1.25 · ½(…)
        }
      }
    }
    (void)parallel;
  }

  // Double-precision log densities of the (t, n) entries in `entries` (state-major lists of
  // frames: entries[n] = frames of state n), written into log_b with bound 0.
  void refine(const std::vector<std::vector<Index>>& entries, RowMatrixXd& log_b, RowMatrixXd& bound) const {
    Index total = 0;
    for (const auto& e : entries) total += static_cast<Index>(e.size());
    const bool parallel = static_cast<double>(total) * d_ * d_ > 2e7;
#if defined(_OPENMP)
#pragma omp parallel for schedule(dynamic, 1) if (parallel)
#endif
    for (Index n = 0; n < n_; ++n) {
      const auto& frames = entries[static_cast<size_t>(n)];
      if (frames.empty()) continue;
      const auto U = u_inv_[static_cast<size_t>(n)].triangularView<Eigen::Upper>();
      RowMatrixXd G, Z;
      const Index count = static_cast<Index>(frames.size());
      for (Index k0 = 0; k0 < count; k0 += kBlockFrames) {
        const Index len = std::min(kBlockFrames, count - k0);
        G.resize(len, d_);
        for (Index r = 0; r < len; ++r) G.row(r) = X_.row(frames[static_cast<size_t>(k0 + r)]);
        Z.noalias() = G * U;
        Z.rowwise() -= mu_u_[static_cast<size_t>(n)].row(0);
        for (Index r = 0; r < len; ++r) {
          const Index t = frames[static_cast<size_t>(k0 + r)];
          log_b(t, n) = c_[n] - 0.5 * Z.row(r).squaredNorm();
          bound(t, n) = 0.0;
        }
      }
    }
    (void)parallel;
  }

 private:
  const MatrixRef& X_;
  const MatrixRef& means_;
  Index T_, d_, n_;
  std::vector<RowMatrixXd> u_inv_, mu_u_;
  VectorXd c_;
};

constexpr double kScreenMargin = 50.0;  // nats below a frame's best emission: e^-50 ≈ 2e-22
constexpr double kPosteriorFloor = 1e-13;  // unrefined entries keep γ·e^{2Δ} below this
constexpr Index kMaxRounds = 6;

// Screened log densities and what it took to get them.
struct Screened {
  RowMatrixXd log_b, bound;
  ScreeningInfo info;
};

// Adds the listed entries to the refined set and evaluates them in double; returns how many.
Index refine_entries(const FullEmissions& em, std::vector<std::vector<Index>>& pick, Screened& sc) {
  Index count = 0;
  for (const auto& p : pick) count += static_cast<Index>(p.size());
  if (count > 0) em.refine(pick, sc.log_b, sc.bound);
  for (auto& p : pick) p.clear();
  sc.info.refined += count;
  return count;
}

void refine_all(const FullEmissions& em, Screened& sc) {
  sc.log_b = em.exact_all();
  sc.bound.setZero(em.frames(), em.states());
  sc.info.refined = em.frames() * em.states();
  sc.info.all_double = true;
}

// Float32 screening followed by the first refinement: every entry whose float32 value, raised
// by its bound, comes within kScreenMargin nats of the frame's best lower bound (and every entry
// where float32 overflowed). Falls back to all-double when that is most of the matrix.
Screened screen_and_refine(const FullEmissions& em) {
  Screened sc;
  sc.info.entries = em.frames() * em.states();
  if (!em.worth_screening()) {
    refine_all(em, sc);
    return sc;
  }
  em.screen(sc.log_b, sc.bound);
  const Index T = em.frames(), N = em.states();
  std::vector<std::vector<Index>> pick(static_cast<size_t>(N));
  Index count = 0;
  for (Index t = 0; t < T; ++t) {
    double best = -std::numeric_limits<double>::infinity();
    for (Index n = 0; n < N; ++n) best = std::max(best, sc.log_b(t, n) - sc.bound(t, n));
    for (Index n = 0; n < N; ++n) {
      if (!std::isfinite(sc.bound(t, n)) || sc.log_b(t, n) + sc.bound(t, n) >= best - kScreenMargin) {
        pick[static_cast<size_t>(n)].push_back(t);
        ++count;
      }
    }
  }
  if (2 * count > T * N) {
    refine_all(em, sc);
    return sc;
  }
  refine_entries(em, pick, sc);
  return sc;
}

// Refines every unrefined entry whose posterior could exceed kPosteriorFloor (γ·e^{2Δ} above
// it); returns the number refined.
Index refine_by_posterior(const FullEmissions& em, const RowMatrixXd& gamma, Screened& sc) {
  std::vector<std::vector<Index>> pick(static_cast<size_t>(em.states()));
  const double log_floor = std::log(kPosteriorFloor);
  for (Index t = 0; t < em.frames(); ++t) {
    for (Index n = 0; n < em.states(); ++n) {
      const double b = sc.bound(t, n);
      // γ computed as 0 underflowed below ~1e-300; an entry with a large bound still matters
      if (b > 0 && std::log(std::max(gamma(t, n), 1e-300)) + 2.0 * b > log_floor) {
        pick[static_cast<size_t>(n)].push_back(t);
      }
    }
  }
  return refine_entries(em, pick, sc);
}

// Forward-backward on the screened densities until no unrefined entry can carry posterior
// mass above kPosteriorFloor; then log p(X) errs by at most Σ_unrefined γ·Δ ≤ kPosteriorFloor·
// max_Δ Δe^{-2Δ}·count ≤ 0.19·kPosteriorFloor per unrefined entry, to first order.
ForwardBackwardResult screened_forward_backward(const FullEmissions& em, Screened& sc, const VectorRef& startprob,
                                                const MatrixRef& transmat, const IndexVectorRef& lengths) {
  for (Index round = 0;; ++round) {
    ForwardBackwardResult fb = forward_backward(sc.log_b, startprob, transmat, lengths);
    ++sc.info.rounds;
    if (sc.info.all_double) return fb;
    if (refine_by_posterior(em, fb.posteriors, sc) == 0) return fb;
    if (round + 1 >= kMaxRounds) refine_all(em, sc);
  }
}

// The all-double path of the entry points: every log density in double, then `lattice` on them.
template <class Lattice>
auto all_double(const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars, CovarianceType type,
                ScreeningInfo* info, Lattice&& lattice) {
  const RowMatrixXd log_b = gaussian_log_density(X, means, covars, type);
  if (info != nullptr) *info = ScreeningInfo{log_b.size(), log_b.size(), 1, true};
  return lattice(log_b);
}

}  // namespace

RowMatrixXd gaussian_log_density(const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars,
                                 CovarianceType type) {
  const Index T = X.rows(), d = X.cols(), n_states = means.rows();
  if (type == CovarianceType::Full) return FullEmissions(X, means, covars).exact_all();
  if (T == 0) fail_argument("X has zero frames; pass at least one frame");
  if (d == 0) fail_argument("X has zero columns; observations need at least one dimension");
  require_finite(X, "X");
  check_means(means, d);
  check_covariances(covars, n_states, d, type);
  // −½ Σ_d (x−μ)²/σ² expanded as x²·(1/σ²) − 2x·(μ/σ²) + μ²/σ²: three matrix products.
  RowMatrixXd out(T, n_states);
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

ScreenedLogDensity gaussian_log_density_screened(const MatrixRef& X, const MatrixRef& means,
                                                 const MatrixRef& covars) {
  const FullEmissions em(X, means, covars);
  ScreenedLogDensity r;
  em.screen(r.log_b, r.bound);
  return r;
}

double gaussian_hmm_score(const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob,
                          const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars,
                          CovarianceType type, bool exact, ScreeningInfo* info) {
  if (type != CovarianceType::Full || exact) {
    return all_double(X, means, covars, type, info, [&](const RowMatrixXd& lb) {
      return log_likelihood(lb, startprob, transmat, lengths);
    });
  }
  const FullEmissions em(X, means, covars);
  Screened sc = screen_and_refine(em);
  // log p(X) is increasing in every log density, so raising each unrefined entry by its bound
  // and lowering it by its bound brackets the all-double value rigorously.
  double result = 0;
  for (Index round = 0;; ++round) {
    ++sc.info.rounds;
    if (sc.info.all_double) {
      result = log_likelihood(sc.log_b, startprob, transmat, lengths);
      break;
    }
    const double hi = log_likelihood(sc.log_b + sc.bound, startprob, transmat, lengths);
    const double lo = log_likelihood(sc.log_b - sc.bound, startprob, transmat, lengths);
    if (hi - lo <= 1e-13 * std::max(1.0, std::abs(lo))) {
      result = 0.5 * (hi + lo);
      break;
    }
    const ForwardBackwardResult fb = forward_backward(sc.log_b, startprob, transmat, lengths);
    if (refine_by_posterior(em, fb.posteriors, sc) == 0 || round + 1 >= kMaxRounds) refine_all(em, sc);
  }
  if (info != nullptr) *info = sc.info;
  return result;
}

ViterbiResult gaussian_hmm_decode(const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob,
                                  const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars,
                                  CovarianceType type, bool exact, ScreeningInfo* info) {
  if (type != CovarianceType::Full || exact) {
    return all_double(X, means, covars, type, info, [&](const RowMatrixXd& lb) {
      return viterbi(lb, startprob, transmat, lengths);
    });
  }
  const FullEmissions em(X, means, covars);
  Screened sc = screen_and_refine(em);
  // Viterbi on upper bounds (exact where refined): if the best path only visits refined entries,
  // its score is exact and every other path's true score is at most its upper score, so no
  // path beats it. Otherwise refine the path's unrefined entries and their frames' rivals.
  ViterbiResult vit;
  std::vector<std::vector<Index>> pick(static_cast<size_t>(em.states()));
  for (Index round = 0;; ++round) {
    ++sc.info.rounds;
    vit = viterbi(sc.log_b + sc.bound, startprob, transmat, lengths);
    if (sc.info.all_double) break;
    Index missing = 0;
    for (Index t = 0; t < em.frames(); ++t) {
      const Index s = vit.path[t];
      if (sc.bound(t, s) == 0) continue;
      ++missing;
      const double floor_t = sc.log_b(t, s) - sc.bound(t, s) - kScreenMargin;
      for (Index n = 0; n < em.states(); ++n) {
        if (sc.bound(t, n) > 0 && sc.log_b(t, n) + sc.bound(t, n) >= floor_t) {
          pick[static_cast<size_t>(n)].push_back(t);
        }
      }
    }
    if (missing == 0) break;
    refine_entries(em, pick, sc);
    if (round + 1 >= kMaxRounds) refine_all(em, sc);
  }
  if (info != nullptr) *info = sc.info;
  return vit;
}

ForwardBackwardResult gaussian_hmm_posteriors(const MatrixRef& X, const IndexVectorRef& lengths,
                                              const VectorRef& startprob, const MatrixRef& transmat,
                                              const MatrixRef& means, const MatrixRef& covars, CovarianceType type,
                                              bool exact, ScreeningInfo* info) {
  if (type != CovarianceType::Full || exact) {
    return all_double(X, means, covars, type, info, [&](const RowMatrixXd& lb) {
      return forward_backward(lb, startprob, transmat, lengths);
    });
  }
  const FullEmissions em(X, means, covars);
  Screened sc = screen_and_refine(em);
  ForwardBackwardResult fb = screened_forward_backward(em, sc, startprob, transmat, lengths);
  if (info != nullptr) *info = sc.info;
  return fb;
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
  // Frames whose share of a state's statistics is negligible are left out of its outer
  // products: with r_t = ‖x_t − shift‖² and S_n = Σ_t γ_tn (1 + r_t), a frame is skipped when
  // γ_tn (1 + r_t) < 1e-13·S_n / T, so the skipped frames hold at most 1e-13·S_n of the
  // state's weight + trace(outer), and the outer sum (PSD) moves by at most that in any norm.
  const VectorXd r1 = (Xs.rowwise().squaredNorm().array() + 1.0).matrix();
  const VectorXd state_total = posteriors.transpose() * r1;
  const bool parallel = static_cast<double>(T) * n_states * d * d > 2e7;
#if defined(_OPENMP)
#pragma omp parallel for schedule(dynamic, 1) if (parallel)
#endif
  for (Index n = 0; n < n_states; ++n) {
    const double cut = kStatsSkip * state_total[n] / static_cast<double>(T);
    std::vector<Index> keep;
    keep.reserve(static_cast<size_t>(T));
    for (Index t = 0; t < T; ++t) {
      if (posteriors(t, n) * r1[t] >= cut && posteriors(t, n) > 0) keep.push_back(t);
    }
    // Σ_t γ_tn x_t x_tᵀ as a symmetric rank-k update with rows scaled by √γ (half the flops).
    RowMatrixXd W(static_cast<Index>(keep.size()), d);
    for (Index k = 0; k < W.rows(); ++k) {
      const Index t = keep[static_cast<size_t>(k)];
      W.row(k) = std::sqrt(posteriors(t, n)) * Xs.row(t);
    }
    RowMatrixXd C = RowMatrixXd::Zero(d, d);
    if (W.rows() > 0) C.selfadjointView<Eigen::Lower>().rankUpdate(W.transpose());
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
                               CovarianceType type, const VectorRef& shift, bool exact, ScreeningInfo* info) {
  const ForwardBackwardResult fb =
      gaussian_hmm_posteriors(X, lengths, startprob, transmat, means, covars, type, exact, info);
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
