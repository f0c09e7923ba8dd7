#pragma once
// Random trajectory models, state sequences and a dense reference solve of the trajectory
// objective (assembled from its definition with selection matrices, not from the block formulas
// of trajectory.cpp), for the C++ tests of trajectory.hpp.
#include "voicepuppet/types.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>

#include <random>

namespace voicepuppet::testing {

struct RandomModel {
  RowMatrixXd means, vel_means, covars;  // full: N·2D by 2D
};

/// `n` states of `d` dims: N(0, 1) pose means, N(0, 0.3²) velocity means, covariances
/// a aᵀ / 2d + I / 2 (a standard normal).
inline RandomModel random_model(Index n, Index d, std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  RandomModel m;
  m.means = RowMatrixXd::NullaryExpr(n, d, [&] { return g(rng); });
  m.vel_means = RowMatrixXd::NullaryExpr(n, d, [&] { return 0.3 * g(rng); });
  m.covars.resize(n * 2 * d, 2 * d);
  for (Index i = 0; i < n; ++i) {
    Eigen::MatrixXd a = Eigen::MatrixXd::NullaryExpr(2 * d, 2 * d, [&] { return g(rng); });
    Eigen::MatrixXd k = a * a.transpose() / static_cast<double>(2 * d) + 0.5 * Eigen::MatrixXd::Identity(2 * d, 2 * d);
    m.covars.middleRows(i * 2 * d, 2 * d) = k;
  }
  return m;
}

/// The dense normal equations of Σ_t Σ_n w_tn · (frame t's cost under n) (frame 0 scores y_0
/// against μ with (K^xx)⁻¹; frame t ≥ 1 scores [y_t, y_t − y_{t−1}] against [μ, μ̇] with K⁻¹),
/// plus, with `targets`, Σ_t (y_t − ŷ_t)ᵀ W (y_t − ŷ_t); solved by LDLT. `diagonal`: the
/// covariances' diagonals only.
inline Eigen::MatrixXd dense_solve(const RandomModel& m, const Eigen::MatrixXd& weights, bool diagonal,
                                   const RowMatrixXd* targets = nullptr, const Eigen::MatrixXd* w_ev = nullptr) {
  using Eigen::MatrixXd;
  const Index n = m.means.rows(), d = m.means.cols(), T = weights.rows();
  MatrixXd h = MatrixXd::Zero(T * d, T * d);
  Eigen::VectorXd r = Eigen::VectorXd::Zero(T * d);
  for (Index t = 0; t < T; ++t) {
    MatrixXd e = MatrixXd::Zero(d, T * d);
    e.block(0, t * d, d, d).setIdentity();
    if (targets != nullptr) {
      h += e.transpose() * *w_ev * e;
      r += e.transpose() * *w_ev * targets->row(t).transpose();
    }
    for (Index s = 0; s < n; ++s) {
      const double w = weights(t, s);
      if (w == 0.0) continue;
      MatrixXd k = m.covars.middleRows(s * 2 * d, 2 * d);
      if (diagonal) k = MatrixXd(k.diagonal().asDiagonal());
      if (t == 0) {
        const MatrixXd p = MatrixXd(k.topLeftCorner(d, d)).llt().solve(MatrixXd::Identity(d, d));
        h += w * e.transpose() * p * e;
        r += w * e.transpose() * p * m.means.row(s).transpose();
        continue;
      }
      MatrixXd sel = MatrixXd::Zero(2 * d, T * d);
      sel.block(0, t * d, d, d).setIdentity();
      sel.block(d, t * d, d, d).setIdentity();
      sel.block(d, (t - 1) * d, d, d) = -MatrixXd::Identity(d, d);
      Eigen::VectorXd target(2 * d);
      target << m.means.row(s).transpose(), m.vel_means.row(s).transpose();
      const MatrixXd p = k.llt().solve(MatrixXd::Identity(2 * d, 2 * d));
      h += w * sel.transpose() * p * sel;
      r += w * sel.transpose() * p * target;
    }
  }
  Eigen::VectorXd y = h.ldlt().solve(r);
  return Eigen::Map<const RowMatrixXd>(y.data(), T, d);
}

/// The model's diagonal variances, #N by 2D.
inline RowMatrixXd diag_of(const RandomModel& m) {
  const Index n = m.means.rows(), d = m.means.cols();
  RowMatrixXd v(n, 2 * d);
  for (Index s = 0; s < n; ++s) v.row(s) = m.covars.middleRows(s * 2 * d, 2 * d).diagonal().transpose();
  return v;
}

inline double rel(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).cwiseAbs().maxCoeff() / b.cwiseAbs().maxCoeff();
}

/// Random states in runs of 1..6 frames.
inline VectorXi random_states(Index T, Index n, std::mt19937& rng) {
  std::uniform_int_distribution<Index> u(0, n - 1), dwell(1, 6);
  VectorXi s(T);
  Index t = 0;
  while (t < T) {
    const Index st = u(rng), len = dwell(rng);
    for (Index k = 0; k < len && t < T; ++k) s[t++] = st;
  }
  return s;
}

inline Eigen::MatrixXd one_hot(const VectorXi& s, Index n) {
  Eigen::MatrixXd w = Eigen::MatrixXd::Zero(s.size(), n);
  for (Index t = 0; t < s.size(); ++t) w(t, s[t]) = 1.0;
  return w;
}

/// A random SPD d x d matrix (an evidence precision): scale · (a aᵀ / d + 0.2 I).
inline Eigen::MatrixXd random_spd(Index d, std::mt19937& rng, double scale) {
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::MatrixXd a = Eigen::MatrixXd::NullaryExpr(d, d, [&] { return g(rng); });
  return scale * (a * a.transpose() / static_cast<double>(d) + 0.2 * Eigen::MatrixXd::Identity(d, d));
}

}  // namespace voicepuppet::testing
