// DPDS and labelled SLDS kernels (dpds.hpp): generation, the eq. 1 gradient by the adjoint
// recursion, the exact μ/ν/r maximisation of Algorithm 1, and the per-dimension Kalman smoother.
#include "voicepuppet/dpds.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <Eigen/QR>

#include <cmath>
#include <vector>

namespace voicepuppet {

namespace {

constexpr double kLog2Pi = 1.8378770664093454835606594728112;

void check_params(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu) {
  if (a.rows() == 0 || a.cols() == 0) fail_argument("a must be non-empty (phones x dims), got ", shape_of(a));
  if (mu.rows() != a.rows() || mu.cols() != a.cols())
    fail_argument("mu must have the shape of a (", shape_of(a), "), got ", shape_of(mu));
  if (nu.rows() != a.rows() || nu.cols() != a.cols())
    fail_argument("nu must have the shape of a (", shape_of(a), "), got ", shape_of(nu));
  require_finite(a, "a");
  require_finite(mu, "mu");
  require_finite(nu, "nu");
}

void check_same(const MatrixRef& m, const MatrixRef& like, const char* name) {
  if (m.rows() != like.rows() || m.cols() != like.cols())
    fail_argument(name, " must have shape ", shape_of(like), " (phones x dims), got ", shape_of(m));
  require_finite(m, name);
}

void check_positive(const MatrixRef& m, const char* name) {
  if (!(m.array() > 0.0).all()) fail_argument(name, " must be positive (variances), got min ", m.minCoeff());
}

}  // namespace

Index check_sequences(Index n_frames, const IndexVectorRef& offsets, const IndexVectorRef& labels,
                      Index n_phones) {
  if (n_frames <= 0) fail_argument("Y must have at least one frame, got 0");
  if (labels.size() != n_frames)
    fail_argument("labels must have one phone per frame (", n_frames, "), got ", labels.size());
  if (offsets.size() < 2)
    fail_argument("offsets must hold the S+1 sequence boundaries (at least 2), got ", offsets.size());
  if (offsets[0] != 0 || offsets[offsets.size() - 1] != n_frames)
    fail_argument("offsets must start at 0 and end at the number of frames (", n_frames, "), got ",
                  offsets[0], " .. ", offsets[offsets.size() - 1]);
  for (Index s = 0; s + 1 < offsets.size(); ++s)
    if (offsets[s + 1] <= offsets[s])
      fail_argument("offsets must increase strictly (no empty sequences); sequence ", s, " spans ",
                    offsets[s], " .. ", offsets[s + 1]);
  for (Index t = 0; t < n_frames; ++t)
    if (labels[t] < 0 || labels[t] >= n_phones)
      fail_argument("labels must be phone indices 0..", n_phones - 1, "; frame ", t, " has ", labels[t]);
  return offsets.size() - 1;
}

RowMatrixXd dpds_generate(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu,
                          const IndexVectorRef& labels, const IndexVectorRef& offsets) {
  check_params(a, mu, nu);
  const Index T = labels.size(), D = a.cols();
  VectorXi whole(2);
  whole << 0, T;
  const IndexVectorRef off = offsets.size() == 0 ? IndexVectorRef(whole) : offsets;
  const Index S = check_sequences(T, off, labels, a.rows());
  RowMatrixXd X(T, D);
  for (Index s = 0; s < S; ++s) {
    X.row(off[s]) = mu.row(labels[off[s]]);
    for (Index t = off[s] + 1; t < off[s + 1]; ++t)
      X.row(t) = a.row(labels[t]).cwiseProduct(X.row(t - 1)) + nu.row(labels[t]);
  }
  return X;
}

DpdsStream::DpdsStream(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu) {
  check_params(a, mu, nu);
  a_ = a;
  mu_ = mu;
  nu_ = nu;
  x_ = VectorXd::Zero(a.cols());
}

RowMatrixXd DpdsStream::push(const IndexVectorRef& labels) {
  const Index T = labels.size(), D = a_.cols(), P = a_.rows();
  for (Index t = 0; t < T; ++t)
    if (labels[t] < 0 || labels[t] >= P)
      fail_argument("labels must be phone indices 0..", P - 1, "; label ", t, " of this chunk is ", labels[t]);
  RowMatrixXd X(T, D);
  for (Index t = 0; t < T; ++t) {
    const Index p = labels[t];
    if (!started_) {
      x_ = mu_.row(p).transpose();
      started_ = true;
    } else {
      x_ = a_.row(p).transpose().cwiseProduct(x_) + nu_.row(p).transpose();
    }
    X.row(t) = x_.transpose();
    ++frames_;
  }
  return X;
}

DpdsGradient dpds_gradient(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu,
                           const VectorRef& r, const MatrixRef& Y, const IndexVectorRef& offsets,
                           const IndexVectorRef& labels) {
  check_params(a, mu, nu);
  const Index P = a.rows(), D = a.cols(), N = Y.rows();
  if (Y.cols() != D) fail_argument("Y must have ", D, " columns (the dims of a), got ", Y.cols());
  require_finite(Y, "Y");
  if (r.size() != D) fail_argument("r must have ", D, " output variances, got ", r.size());
  if (!r.allFinite() || !(r.array() > 0.0).all())
    fail_argument("r must be finite and positive (output variances), got min ", r.minCoeff());
  const Index S = check_sequences(N, offsets, labels, P);
  DpdsGradient out;
  out.grad_a = RowMatrixXd::Zero(P, D);
  out.grad_mu = RowMatrixXd::Zero(P, D);
  out.grad_nu = RowMatrixXd::Zero(P, D);
  RowMatrixXd X = dpds_generate(a, mu, nu, labels, offsets);
  out.residual = Y - X;
  const Eigen::RowVectorXd inv_r = r.cwiseInverse().transpose();
  const double log_det = (r.array() * (2.0 * M_PI)).log().sum();
  out.log_likelihood = -0.5 * (static_cast<double>(N) * log_det +
                               (out.residual.array().square().rowwise() * inv_r.array()).sum());
  Eigen::RowVectorXd lambda(D);
  for (Index s = 0; s < S; ++s) {
    const Index b = offsets[s], e = offsets[s + 1];
    lambda.setZero();
    for (Index t = e - 1; t >= b; --t) {
      // λ_t = g_t + a_{s_{t+1}} ∘ λ_{t+1}  (λ holds λ_{t+1} scaled already on entry)
      if (t + 1 < e) lambda = lambda.cwiseProduct(a.row(labels[t + 1]));
      lambda += out.residual.row(t).cwiseProduct(inv_r);
      if (t > b) {
        out.grad_a.row(labels[t]) += lambda.cwiseProduct(X.row(t - 1));
        out.grad_nu.row(labels[t]) += lambda;
      } else {
        out.grad_mu.row(labels[t]) += lambda;
      }
    }
  }
  return out;
}

DpdsSolve dpds_solve(const MatrixRef& a, const MatrixRef& Y, const IndexVectorRef& offsets,
                     const IndexVectorRef& labels, const VectorRef& r_floor) {
  const Index P = a.rows(), D = a.cols(), N = Y.rows(), K = 2 * P;
  if (P == 0 || D == 0) fail_argument("a must be non-empty (phones x dims), got ", shape_of(a));
  require_finite(a, "a");
  if (Y.cols() != D) fail_argument("Y must have ", D, " columns (the dims of a), got ", Y.cols());
  require_finite(Y, "Y");
  if (r_floor.size() != D || !r_floor.allFinite() || (r_floor.array() < 0.0).any())
    fail_argument("r_floor must hold ", D, " finite non-negative variance floors");
  const Index S = check_sequences(N, offsets, labels, P);

  // Normal equations per dimension: G_j θ_j = b_j, θ = [μ_0..μ_{P−1}, ν_0..ν_{P−1}] (column j).
  // Within a sequence only the parameters of phones seen so far have non-zero coefficients: they
  // get local indices 0..m−1 (in order of appearance), the coefficients live in Ct (#D by m, one
  // contiguous row per dimension) and the sequence's normal equations in local m×m blocks
  // (rank-one updates), scattered into the global 2P×2P systems at the end of the sequence.
  std::vector<Eigen::MatrixXd> G(static_cast<size_t>(D), Eigen::MatrixXd::Zero(K, K));
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(K, D);
  std::vector<Eigen::MatrixXd> Gloc(static_cast<size_t>(D), Eigen::MatrixXd::Zero(K, K));
  RowMatrixXd Bloc = RowMatrixXd::Zero(D, K);
  RowMatrixXd Ct = RowMatrixXd::Zero(D, K);
  std::vector<Index> active;  // global parameter index of each local index
  std::vector<Index> local_of(static_cast<size_t>(K), -1);
  active.reserve(static_cast<size_t>(K));
  Eigen::Matrix<Index, Eigen::Dynamic, 1> used = Eigen::Matrix<Index, Eigen::Dynamic, 1>::Zero(K);

  auto activate = [&](Index param) {
    Index loc = local_of[static_cast<size_t>(param)];
    if (loc < 0) {
      loc = static_cast<Index>(active.size());
      active.push_back(param);
      local_of[static_cast<size_t>(param)] = loc;
      Ct.col(loc).setZero();
    }
    Ct.col(loc).array() += 1.0;
    used[param] = 1;
  };
  auto accumulate = [&](Index t) {
    const Index m = static_cast<Index>(active.size());
    for (Index j = 0; j < D; ++j) {
      const auto c = Ct.row(j).head(m);
      Gloc[static_cast<size_t>(j)].topLeftCorner(m, m).selfadjointView<Eigen::Lower>().rankUpdate(
          c.transpose());
      Bloc.row(j).head(m) += Y(t, j) * c;
    }
  };

  for (Index s = 0; s < S; ++s) {
    const Index b = offsets[s], e = offsets[s + 1];
    activate(labels[b]);  // μ of the first phone
    accumulate(b);
    for (Index t = b + 1; t < e; ++t) {
      const Index m = static_cast<Index>(active.size());
      for (Index j = 0; j < D; ++j) Ct.row(j).head(m) *= a(labels[t], j);
      activate(P + labels[t]);  // ν of this frame's phone
      accumulate(t);
    }
    const Index m = static_cast<Index>(active.size());
    for (Index j = 0; j < D; ++j) {
      Eigen::MatrixXd& Gl = Gloc[static_cast<size_t>(j)];
      Eigen::MatrixXd& Gj = G[static_cast<size_t>(j)];
      for (Index u = 0; u < m; ++u) {
        const Index pu = active[static_cast<size_t>(u)];
        B(pu, j) += Bloc(j, u);
        for (Index v = 0; v < u; ++v) {
          const Index pv = active[static_cast<size_t>(v)];
          Gj(pu, pv) += Gl(u, v);
          Gj(pv, pu) += Gl(u, v);
        }
        Gj(pu, pu) += Gl(u, u);
      }
      Gl.topLeftCorner(m, m).setZero();
      Bloc.row(j).head(m).setZero();
    }
    for (Index p : active) local_of[static_cast<size_t>(p)] = -1;
    active.clear();
  }

  std::vector<Index> idx;
  for (Index k = 0; k < K; ++k)
    if (used[k]) idx.push_back(k);
  const Index U = static_cast<Index>(idx.size());
  Eigen::MatrixXd theta = Eigen::MatrixXd::Zero(K, D);
  Eigen::MatrixXd Gu(U, U);
  Eigen::VectorXd bu(U);
  for (Index j = 0; j < D; ++j) {
    Eigen::MatrixXd& Gj = G[static_cast<size_t>(j)];
    for (Index u = 0; u < U; ++u) {
      bu[u] = B(idx[static_cast<size_t>(u)], j);
      for (Index v = u; v < U; ++v) {
        Gu(u, v) = Gj(idx[static_cast<size_t>(u)], idx[static_cast<size_t>(v)]);
        Gu(v, u) = Gu(u, v);
      }
    }
    Eigen::VectorXd x;
    Eigen::LLT<Eigen::MatrixXd> llt(Gu);
    if (llt.info() == Eigen::Success && llt.rcond() > 1e-12) {
      x = llt.solve(bu);
    } else {
      x = Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>(Gu).solve(bu);
    }
    if (!x.allFinite())
      fail_numeric("dpds_solve: the mu/nu normal equations of dimension ", j,
                   " gave non-finite values; check the data for huge values");
    for (Index u = 0; u < U; ++u) theta(idx[static_cast<size_t>(u)], j) = x[u];
  }

  DpdsSolve out;
  out.mu = theta.topRows(P);
  out.nu = theta.bottomRows(P);
  out.mu_used = used.head(P);
  out.nu_used = used.tail(P);
  const RowMatrixXd X = dpds_generate(a, out.mu, out.nu, labels, offsets);
  const RowMatrixXd res = Y - X;
  out.r = (res.array().square().colwise().sum().transpose() / static_cast<double>(N)).matrix();
  out.r = out.r.cwiseMax(r_floor);
  if (!(out.r.array() > 0.0).all())
    fail_numeric("dpds_solve: a dimension is fitted exactly (zero residual variance); give a "
                 "positive r_floor");
  const Eigen::RowVectorXd inv_r = out.r.cwiseInverse().transpose();
  out.log_likelihood = -0.5 * (static_cast<double>(N) * (out.r.array() * (2.0 * M_PI)).log().sum() +
                               (res.array().square().rowwise() * inv_r.array()).sum());
  return out;
}

SldsSmooth slds_smooth(const MatrixRef& a, const MatrixRef& nu, const MatrixRef& q,
                       const MatrixRef& r, const MatrixRef& mu1, const MatrixRef& var1,
                       const MatrixRef& Y, const IndexVectorRef& offsets,
                       const IndexVectorRef& labels) {
  check_params(a, mu1, nu);
  check_same(q, a, "q");
  check_same(r, a, "r");
  check_same(var1, a, "var1");
  check_positive(q, "q");
  check_positive(r, "r");
  check_positive(var1, "var1");
  const Index P = a.rows(), D = a.cols(), N = Y.rows();
  if (Y.cols() != D) fail_argument("Y must have ", D, " columns (the dims of a), got ", Y.cols());
  require_finite(Y, "Y");
  const Index S = check_sequences(N, offsets, labels, P);
  SldsSmooth out;
  out.mean.resize(N, D);
  out.var.resize(N, D);
  out.cross = RowMatrixXd::Zero(N, D);
  out.pred_mean.resize(N, D);
  out.pred_var.resize(N, D);
  double ll = 0.0;
  for (Index s = 0; s < S; ++s) {
    const Index b = offsets[s], e = offsets[s + 1];
    // filter
    for (Index t = b; t < e; ++t) {
      const Index p = labels[t];
      if (t == b) {
        out.pred_mean.row(t) = mu1.row(p);
        out.pred_var.row(t) = var1.row(p);
      } else {
        out.pred_mean.row(t) = a.row(p).cwiseProduct(out.mean.row(t - 1)) + nu.row(p);
        out.pred_var.row(t) =
            a.row(p).cwiseProduct(a.row(p)).cwiseProduct(out.var.row(t - 1)) + q.row(p);
      }
      for (Index j = 0; j < D; ++j) {
        const double Sv = out.pred_var(t, j) + r(p, j);
        const double innov = Y(t, j) - out.pred_mean(t, j);
        const double K = out.pred_var(t, j) / Sv;
        ll += -0.5 * (kLog2Pi + std::log(Sv) + innov * innov / Sv);
        out.mean(t, j) = out.pred_mean(t, j) + K * innov;
        out.var(t, j) = out.pred_var(t, j) * r(p, j) / Sv;  // (1 − K) P⁻, computed stably
      }
    }
    // Rauch–Tung–Striebel smoother
    for (Index t = e - 2; t >= b; --t) {
      const Index pn = labels[t + 1];
      for (Index j = 0; j < D; ++j) {
        const double J = out.var(t, j) * a(pn, j) / out.pred_var(t + 1, j);
        out.mean(t, j) += J * (out.mean(t + 1, j) - out.pred_mean(t + 1, j));
        out.cross(t + 1, j) = J * out.var(t + 1, j);
        out.var(t, j) += J * J * (out.var(t + 1, j) - out.pred_var(t + 1, j));
      }
    }
  }
  out.log_likelihood = ll;
  return out;
}

}  // namespace voicepuppet
