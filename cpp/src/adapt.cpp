#include "voicepuppet/adapt.hpp"

#include "voicepuppet/hmm.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include <cmath>
#include <limits>

namespace voicepuppet {
namespace {

constexpr double kLog2Pi = 1.8378770664093454835606594728112;

/// Each state's covariance as a full matrix, its Cholesky factor and precision.
struct StateGaussians {
  std::vector<RowMatrixXd> cov, prec;
  std::vector<Eigen::LLT<RowMatrixXd>> chol;
  VectorXd log_det;
};

StateGaussians factor(const MatrixRef& covars, CovarianceType type, Index N, Index D) {
  StateGaussians g;
  g.log_det.resize(N);
  for (Index i = 0; i < N; ++i) {
    RowMatrixXd c = type == CovarianceType::Full ? RowMatrixXd(covars.middleRows(i * D, D))
                                                 : RowMatrixXd(covars.row(i).transpose().asDiagonal());
    Eigen::LLT<RowMatrixXd> llt(c);
    if (llt.info() != Eigen::Success) fail_argument("covars of state ", i, " is not positive definite");
    g.log_det(i) = 2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
    RowMatrixXd p = llt.solve(RowMatrixXd::Identity(D, D));
    g.prec.push_back(0.5 * (p + p.transpose()));
    g.cov.push_back(std::move(c));
    g.chol.push_back(std::move(llt));
  }
  return g;
}

double log_abs_det(const RowMatrixXd& A) {
  const Eigen::PartialPivLU<RowMatrixXd> lu(A);
  return lu.matrixLU().diagonal().array().abs().log().sum();
}

/// τ Σ_i π_i E_{x ~ N_i}[log N(A x + b; μ_i, Σ_i)] + τ log|det A|.
double prior_term(const RowMatrixXd& A, const VectorXd& b, const MatrixRef& means,
                  const StateGaussians& g, const VectorXd& pi, double tau) {
  const Index D = A.rows();
  double total = tau * log_abs_det(A);
  for (Index i = 0; i < means.rows(); ++i) {
    if (pi(i) == 0) continue;
    const VectorXd mu = means.row(i).transpose();
    const VectorXd m = A * mu + b - mu;
    const RowMatrixXd L = g.chol[static_cast<size_t>(i)].matrixL();
    // tr(Σ⁻¹ A Σ Aᵀ) = ‖L⁻¹ A L‖²_F with Σ = L Lᵀ
    const RowMatrixXd M = L.triangularView<Eigen::Lower>().solve(A * L);
    const VectorXd u = L.triangularView<Eigen::Lower>().solve(m);
    total += tau * pi(i) * -0.5 * (D * kLog2Pi + g.log_det(i) + M.squaredNorm() + u.squaredNorm());
  }
  return total;
}

/// The identity transform of #D columns.
FeatureTransform identity_transform(Index n_dims) {
  FeatureTransform t;
  t.A = RowMatrixXd::Identity(n_dims, n_dims);
  t.b = VectorXd::Zero(n_dims);
  return t;
}

}  // namespace

AdaptKind parse_adapt_kind(const std::string& name) {
  if (name == "none") return AdaptKind::None;
  if (name == "full") return AdaptKind::Full;
  fail_argument("adaptation must be 'none' or 'full', got '", name, "'");
}

void check_adapt_options(const AdaptOptions& o) {
  if (!(o.tau > 0)) {
    fail_argument("adaptation tau (prior frames) must be > 0 (inf: no adaptation), got ", o.tau,
                  "; use e.g. 100");
  }
  if (o.n_iter < 1 || o.n_iter > 1000) fail_argument("adaptation n_iter must be in [1, 1000], got ", o.n_iter);
  if (o.sweeps < 1 || o.sweeps > 1000) fail_argument("adaptation sweeps must be in [1, 1000], got ", o.sweeps);
}

RowMatrixXd FeatureTransform::apply(const MatrixRef& z) const {
  if (z.cols() != A.cols()) fail_argument("features have ", z.cols(), " columns, the transform ", A.cols());
  RowMatrixXd out = z * A.transpose();
  out.rowwise() += b.transpose();
  return out;
}

double FeatureTransform::log_jacobian(Index n_frames) const {
  return static_cast<double>(n_frames) * log_abs_det(A);
}

FeatureTransform adapt_features(const MatrixRef& z, const IndexVectorRef& lengths,
                                const MatrixRef& means, const MatrixRef& covars,
                                CovarianceType type, const VectorRef& startprob,
                                const MatrixRef& transmat, const AdaptOptions& options) {
  const Index T = z.rows(), D = z.cols(), N = means.rows();
  if (means.cols() != D) fail_argument("means must have ", D, " columns (the features'), got ", means.cols());
  if (T < 1) fail_argument("adaptation needs at least one feature frame");
  require_finite(z, "features to adapt");
  check_covariances(covars, N, D, type);
  FeatureTransform t = identity_transform(D);
  if (options.kind == AdaptKind::None) return t;
  check_adapt_options(options);
  if (std::isinf(options.tau)) return t;
  const double tau = options.tau;

  const StateGaussians g = factor(covars, type, N, D);
  RowMatrixXd pm(N, D);  // Σ_i⁻¹ μ_i
  for (Index i = 0; i < N; ++i) pm.row(i) = (g.prec[static_cast<size_t>(i)] * means.row(i).transpose()).transpose();
  RowMatrixXd xi(T, D + 1);  // [1, z_t]
  xi.col(0).setOnes();
  xi.rightCols(D) = z;

  RowMatrixXd W(D, D + 1);  // [b, A]
  W.col(0).setZero();
  W.rightCols(D).setIdentity();
  VectorXd pi;
  std::vector<RowMatrixXd> G(static_cast<size_t>(N));
  RowMatrixXd S(N, D + 1);
  VectorXd n(N);
  for (Index it = 0;; ++it) {
    const RowMatrixXd A = W.rightCols(D);
    const VectorXd b = W.col(0);
    RowMatrixXd za = z * A.transpose();
    za.rowwise() += b.transpose();
    const RowMatrixXd log_b = gaussian_log_density(za, means, covars, type);
    const ForwardBackwardResult fb = forward_backward(log_b, startprob, transmat, lengths);
    if (it == 0) pi = fb.posteriors.colwise().sum().transpose() / static_cast<double>(T);
    t.log_likelihood.push_back(fb.log_likelihood + static_cast<double>(T) * log_abs_det(A) +
                               prior_term(A, b, means, g, pi, tau));
    if (it == options.n_iter) break;

    // Statistics with the prior's τ frames: n_i, s_i = Σ γ ξ, G_i = Σ γ ξ ξᵀ.
    const RowMatrixXd& gam = fb.posteriors;
    for (Index i = 0; i < N; ++i) {
      const double w0 = tau * pi(i);
      const VectorXd mu = means.row(i).transpose();
      n(i) = gam.col(i).sum() + w0;
      S.row(i) = gam.col(i).transpose() * xi;
      S(i, 0) += w0;
      S.row(i).tail(D) += w0 * mu.transpose();
      RowMatrixXd Gi = xi.transpose() * (xi.array().colwise() * gam.col(i).array()).matrix();
      Gi(0, 0) += w0;
      Gi.block(1, 0, D, 1) += w0 * mu;
      Gi.block(0, 1, 1, D) += w0 * mu.transpose();
      Gi.block(1, 1, D, D) += w0 * (g.cov[static_cast<size_t>(i)] + mu * mu.transpose());
      G[static_cast<size_t>(i)] = std::move(Gi);
    }
    const double beta = n.sum();

    for (Index sweep = 0; sweep < options.sweeps; ++sweep) {
      for (Index r = 0; r < D; ++r) {
        // Row r of W maximises -½ wᵀ Gr w + kᵀ w + β log|c·w|, the other rows fixed.
        RowMatrixXd Gr = RowMatrixXd::Zero(D + 1, D + 1);
        VectorXd k = VectorXd::Zero(D + 1);
        for (Index i = 0; i < N; ++i) {
          const RowMatrixXd& P = g.prec[static_cast<size_t>(i)];
          const RowMatrixXd& Gi = G[static_cast<size_t>(i)];
          Gr += P(r, r) * Gi;
          VectorXd v = W.transpose() * P.row(r).transpose();  // Σ_s P(r,s) w_s ...
          v -= P(r, r) * W.row(r).transpose();                // ... over s ≠ r
          k += pm(i, r) * S.row(i).transpose() - Gi * v;
        }
        // c: the cofactors of row r (∝ column r of A⁻¹); the bias has none.
        VectorXd c(D + 1);
        c(0) = 0.0;
        c.tail(D) = Eigen::PartialPivLU<RowMatrixXd>(W.rightCols(D)).solve(VectorXd::Unit(D, r));
        const Eigen::LLT<RowMatrixXd> llt(Gr);
        const VectorXd gk = llt.solve(k), gc = llt.solve(c);
        const double e1 = c.dot(gc), e2 = c.dot(gk);
        const double disc = std::sqrt(e2 * e2 + 4.0 * e1 * beta);
        double best = -std::numeric_limits<double>::infinity();
        VectorXd best_w;
        for (const double alpha : {(-e2 + disc) / (2.0 * e1), (-e2 - disc) / (2.0 * e1)}) {
          const VectorXd w = alpha * gc + gk;
          const double f = beta * std::log(std::abs(c.dot(w))) - 0.5 * w.dot(Gr * w) + k.dot(w);
          if (f > best) {
            best = f;
            best_w = w;
          }
        }
        W.row(r) = best_w.transpose();
      }
    }
  }
  t.A = W.rightCols(D);
  t.b = W.col(0);
  return t;
}

}  // namespace voicepuppet
