#include "voicepuppet/hmm.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voicepuppet {
namespace {

constexpr double kNegInf = -std::numeric_limits<double>::infinity();
constexpr double kStochasticTol = 1e-6;

double logsumexp(const double* v, Index n) {
  double m = kNegInf;
  for (Index i = 0; i < n; ++i) m = std::max(m, v[i]);
  if (m == kNegInf) return kNegInf;
  double s = 0;
  for (Index i = 0; i < n; ++i) s += std::exp(v[i] - m);
  return m + std::log(s);
}

void check_log_b(const MatrixRef& log_b, Index n_states) {
  if (log_b.cols() != n_states) {
    fail_argument("log_b must have one column per state (", n_states, "), got shape ", shape_of(log_b));
  }
  if (log_b.rows() == 0) fail_argument("log_b has zero frames; pass at least one frame");
  if (log_b.array().isNaN().any() || (log_b.array() == std::numeric_limits<double>::infinity()).any()) {
    fail_argument("log_b contains NaN or +inf; log densities must be finite or -inf");
  }
}

[[noreturn]] void fail_impossible(Index seq, Index frame) {
  fail_numeric("sequence ", seq, " has zero probability under the model at frame ", frame,
               " (no allowed state path explains it); check the transitions' sparsity or "
               "widen the emission densities");
}

// Scaled forward-backward of one sequence (rows [s, e) of log_b). Returns false when a frame's
// scaled quantities underflow, in which case the caller falls back to the log-space version.
bool forward_backward_scaled_one(const MatrixRef& log_b, const Transitions& tr, const VectorRef& startprob,
                                 Index s, Index e, Index seq, double& loglik, RowMatrixXd& gamma,
                                 RowMatrixXd& xi, VectorXd& starts) {
  const Index n = tr.n_states;
  const Index len = e - s;
  RowMatrixXd alpha(len, n);
  // Emission likelihoods shifted per frame by the frame's maximum: bb(t, j) = exp(log_b - M_t).
  RowMatrixXd bb(len, n);
  for (Index t = 0; t < len; ++t) {
    const double m = log_b.row(s + t).maxCoeff();
    if (m == kNegInf) fail_impossible(seq, t);
    bb.row(t) = (log_b.row(s + t).array() - m).exp();
  }
  double ll = 0;
  // t = 0
  {
    double m = kNegInf;
    for (Index j = 0; j < n; ++j) {
      if (startprob[j] > 0) m = std::max(m, log_b(s, j));
    }
    if (m == kNegInf) fail_impossible(seq, 0);
    double z = 0;
    for (Index j = 0; j < n; ++j) {
      alpha(0, j) = startprob[j] > 0 ? startprob[j] * std::exp(log_b(s, j) - m) : 0.0;
      z += alpha(0, j);
    }
    alpha.row(0) /= z;
    ll += m + std::log(z);
  }
  VectorXd pred(n);
  for (Index t = 1; t < len; ++t) {
    for (Index j = 0; j < n; ++j) {
      double acc = 0;
      for (Index k = tr.in_ptr[j]; k < tr.in_ptr[j + 1]; ++k) acc += alpha(t - 1, tr.in_src[k]) * tr.in_p[k];
      pred[j] = acc;
    }
    double m = kNegInf;
    for (Index j = 0; j < n; ++j) {
      if (pred[j] > 0) m = std::max(m, log_b(s + t, j));
    }
    if (m == kNegInf) fail_impossible(seq, t);
    double z = 0;
    for (Index j = 0; j < n; ++j) {
      const double v = pred[j] > 0 ? pred[j] * std::exp(log_b(s + t, j) - m) : 0.0;
      alpha(t, j) = v;
      z += v;
    }
    if (!(z > 1e-290)) return false;
    alpha.row(t) /= z;
    ll += m + std::log(z);
  }
  // Backward, each frame normalised to sum one; ξ accumulated on the way.
  VectorXd beta = VectorXd::Constant(n, 1.0 / n);
  VectorXd w(n), beta_prev(n);
  gamma.row(s + len - 1) = alpha.row(len - 1);
  for (Index t = len - 2; t >= 0; --t) {
    w = bb.row(t + 1).transpose().cwiseProduct(beta);
    double norm = 0;
    for (Index i = 0; i < n; ++i) {
      double acc = 0;
      for (Index k = tr.out_ptr[i]; k < tr.out_ptr[i + 1]; ++k) acc += tr.out_p[k] * w[tr.out_dst[k]];
      beta_prev[i] = acc;
      norm += alpha(t, i) * acc;
    }
    if (!(norm > 1e-290)) return false;
    for (Index i = 0; i < n; ++i) {
      const double ai = alpha(t, i) / norm;
      if (ai == 0) continue;
      for (Index k = tr.out_ptr[i]; k < tr.out_ptr[i + 1]; ++k) {
        xi(i, tr.out_dst[k]) += ai * tr.out_p[k] * w[tr.out_dst[k]];
      }
    }
    const double bs = beta_prev.sum();
    if (!(bs > 1e-290)) return false;
    beta = beta_prev / bs;
    double gz = 0;
    for (Index i = 0; i < n; ++i) {
      gamma(s + t, i) = alpha(t, i) * beta[i];
      gz += gamma(s + t, i);
    }
    if (!(gz > 1e-290)) return false;
    gamma.row(s + t) /= gz;
  }
  starts += gamma.row(s).transpose();
  loglik = ll;
  return true;
}

void forward_backward_log_one(const MatrixRef& log_b, const Transitions& tr, const VectorRef& startprob,
                              Index s, Index e, Index seq, double& loglik, RowMatrixXd& gamma,
                              RowMatrixXd& xi, VectorXd& starts) {
  const Index n = tr.n_states;
  const Index len = e - s;
  const RowMatrixXd lb = log_b.middleRows(s, len);
  RowMatrixXd la(len, n), lbeta(len, n);
  std::vector<double> buf(static_cast<size_t>(n));
  for (Index j = 0; j < n; ++j) la(0, j) = std::log(startprob[j]) + lb(0, j);
  for (Index t = 1; t < len; ++t) {
    for (Index j = 0; j < n; ++j) {
      Index c = 0;
      for (Index k = tr.in_ptr[j]; k < tr.in_ptr[j + 1]; ++k) buf[c++] = la(t - 1, tr.in_src[k]) + std::log(tr.in_p[k]);
      la(t, j) = logsumexp(buf.data(), c) + lb(t, j);
    }
  }
  lbeta.row(len - 1).setZero();
  for (Index t = len - 2; t >= 0; --t) {
    for (Index i = 0; i < n; ++i) {
      Index c = 0;
      for (Index k = tr.out_ptr[i]; k < tr.out_ptr[i + 1]; ++k) {
        const Index j = tr.out_dst[k];
        buf[c++] = std::log(tr.out_p[k]) + lb(t + 1, j) + lbeta(t + 1, j);
      }
      lbeta(t, i) = logsumexp(buf.data(), c);
    }
  }
  const double ll = logsumexp(la.row(len - 1).data(), n);
  if (ll == kNegInf) fail_impossible(seq, len - 1);
  for (Index t = 0; t < len; ++t) {
    for (Index i = 0; i < n; ++i) gamma(s + t, i) = std::exp(la(t, i) + lbeta(t, i) - ll);
  }
  for (Index t = 0; t + 1 < len; ++t) {
    for (Index i = 0; i < n; ++i) {
      if (la(t, i) == kNegInf) continue;
      for (Index k = tr.out_ptr[i]; k < tr.out_ptr[i + 1]; ++k) {
        const Index j = tr.out_dst[k];
        xi(i, j) += std::exp(la(t, i) + std::log(tr.out_p[k]) + lb(t + 1, j) + lbeta(t + 1, j) - ll);
      }
    }
  }
  starts += gamma.row(s).transpose();
  loglik = ll;
}

template <class OneSeq>
ForwardBackwardResult run_forward_backward(const MatrixRef& log_b, const VectorRef& startprob,
                                           const MatrixRef& transmat, const IndexVectorRef& lengths,
                                           OneSeq&& one) {
  const Transitions tr = make_transitions(startprob, transmat);
  check_log_b(log_b, tr.n_states);
  const auto bounds = sequence_bounds(lengths, log_b.rows());
  const Index n_seq = static_cast<Index>(bounds.size()) - 1;
  ForwardBackwardResult r;
  r.posteriors = RowMatrixXd::Zero(log_b.rows(), tr.n_states);
  r.expected_transitions = RowMatrixXd::Zero(tr.n_states, tr.n_states);
  r.expected_starts = VectorXd::Zero(tr.n_states);
  r.sequence_log_likelihoods.resize(n_seq);
  for (Index q = 0; q < n_seq; ++q) {
    one(log_b, tr, startprob, bounds[q], bounds[q + 1], q, r);
    r.log_likelihood += r.sequence_log_likelihoods[q];
  }
  return r;
}

}  // namespace

Transitions make_transitions(const VectorRef& startprob, const MatrixRef& transmat) {
  const Index n = startprob.size();
  if (n == 0) fail_argument("startprob is empty; a model needs at least one state");
  if (transmat.rows() != n || transmat.cols() != n) {
    fail_argument("transmat must have shape (", n, ", ", n, ") to match startprob, got ", shape_of(transmat));
  }
  require_finite(startprob, "startprob");
  require_finite(transmat, "transmat");
  if ((startprob.array() < 0).any()) fail_argument("startprob has negative entries");
  if (std::abs(startprob.sum() - 1.0) > kStochasticTol) {
    fail_argument("startprob must sum to 1, sums to ", startprob.sum(), "; normalise it");
  }
  if ((transmat.array() < 0).any()) fail_argument("transmat has negative entries");
  for (Index i = 0; i < n; ++i) {
    const double rs = transmat.row(i).sum();
    if (std::abs(rs - 1.0) > kStochasticTol) {
      fail_argument("transmat row ", i, " must sum to 1, sums to ", rs,
                    "; normalise the rows (a state with no exit needs a self-transition)");
    }
  }
  Transitions tr;
  tr.n_states = n;
  tr.in_ptr.assign(static_cast<size_t>(n + 1), 0);
  tr.out_ptr.assign(static_cast<size_t>(n + 1), 0);
  for (Index i = 0; i < n; ++i) {
    for (Index j = 0; j < n; ++j) {
      if (transmat(i, j) > 0) {
        ++tr.in_ptr[j + 1];
        ++tr.out_ptr[i + 1];
      }
    }
  }
  for (Index k = 0; k < n; ++k) {
    tr.in_ptr[k + 1] += tr.in_ptr[k];
    tr.out_ptr[k + 1] += tr.out_ptr[k];
  }
  const auto n_arcs = static_cast<size_t>(tr.in_ptr[n]);
  tr.in_src.resize(n_arcs);
  tr.in_p.resize(n_arcs);
  tr.out_dst.resize(n_arcs);
  tr.out_p.resize(n_arcs);
  std::vector<Index> in_fill(tr.in_ptr.begin(), tr.in_ptr.end() - 1);
  Index o = 0;
  for (Index i = 0; i < n; ++i) {
    for (Index j = 0; j < n; ++j) {
      const double p = transmat(i, j);
      if (p > 0) {
        tr.out_dst[static_cast<size_t>(o)] = j;
        tr.out_p[static_cast<size_t>(o)] = p;
        ++o;
        const auto slot = static_cast<size_t>(in_fill[static_cast<size_t>(j)]++);
        tr.in_src[slot] = i;
        tr.in_p[slot] = p;
      }
    }
  }
  return tr;
}

std::vector<Index> sequence_bounds(const IndexVectorRef& lengths, Index n_frames) {
  std::vector<Index> b{0};
  if (lengths.size() == 0) {
    b.push_back(n_frames);
    return b;
  }
  Index total = 0;
  for (Index q = 0; q < lengths.size(); ++q) {
    if (lengths[q] <= 0) {
      fail_argument("lengths[", q, "] is ", lengths[q], "; every sequence needs at least one frame");
    }
    total += lengths[q];
    b.push_back(total);
  }
  if (total != n_frames) {
    fail_argument("lengths sum to ", total, " but there are ", n_frames, " frames; they must agree");
  }
  return b;
}

ForwardBackwardResult forward_backward(const MatrixRef& log_b, const VectorRef& startprob,
                                       const MatrixRef& transmat, const IndexVectorRef& lengths) {
  return run_forward_backward(
      log_b, startprob, transmat, lengths,
      [](const MatrixRef& lb, const Transitions& tr, const VectorRef& pi, Index s, Index e, Index q,
         ForwardBackwardResult& r) {
        double ll = 0;
        RowMatrixXd xi_q = RowMatrixXd::Zero(tr.n_states, tr.n_states);
        VectorXd starts_q = VectorXd::Zero(tr.n_states);
        if (!forward_backward_scaled_one(lb, tr, pi, s, e, q, ll, r.posteriors, xi_q, starts_q)) {
          xi_q.setZero();
          starts_q.setZero();
          forward_backward_log_one(lb, tr, pi, s, e, q, ll, r.posteriors, xi_q, starts_q);
        }
        r.expected_transitions += xi_q;
        r.expected_starts += starts_q;
        r.sequence_log_likelihoods[q] = ll;
      });
}

ForwardBackwardResult forward_backward_log(const MatrixRef& log_b, const VectorRef& startprob,
                                           const MatrixRef& transmat, const IndexVectorRef& lengths) {
  return run_forward_backward(
      log_b, startprob, transmat, lengths,
      [](const MatrixRef& lb, const Transitions& tr, const VectorRef& pi, Index s, Index e, Index q,
         ForwardBackwardResult& r) {
        double ll = 0;
        forward_backward_log_one(lb, tr, pi, s, e, q, ll, r.posteriors, r.expected_transitions,
                                 r.expected_starts);
        r.sequence_log_likelihoods[q] = ll;
      });
}

RowMatrixXd forward_lattice_log(const MatrixRef& log_b, const VectorRef& startprob, const MatrixRef& transmat) {
  const Transitions tr = make_transitions(startprob, transmat);
  check_log_b(log_b, tr.n_states);
  const Index n = tr.n_states, len = log_b.rows();
  RowMatrixXd la(len, n);
  std::vector<double> buf(static_cast<size_t>(n));
  for (Index j = 0; j < n; ++j) la(0, j) = std::log(startprob[j]) + log_b(0, j);
  for (Index t = 1; t < len; ++t) {
    for (Index j = 0; j < n; ++j) {
      Index c = 0;
      for (Index k = tr.in_ptr[j]; k < tr.in_ptr[j + 1]; ++k) buf[c++] = la(t - 1, tr.in_src[k]) + std::log(tr.in_p[k]);
      la(t, j) = logsumexp(buf.data(), c) + log_b(t, j);
    }
  }
  return la;
}

RowMatrixXd backward_lattice_log(const MatrixRef& log_b, const MatrixRef& transmat) {
  const Index n = transmat.rows();
  const Transitions tr = make_transitions(VectorXd::Constant(n, 1.0 / std::max<Index>(n, 1)), transmat);
  check_log_b(log_b, n);
  const Index len = log_b.rows();
  RowMatrixXd lbeta(len, n);
  std::vector<double> buf(static_cast<size_t>(n));
  lbeta.row(len - 1).setZero();
  for (Index t = len - 2; t >= 0; --t) {
    for (Index i = 0; i < n; ++i) {
      Index c = 0;
      for (Index k = tr.out_ptr[i]; k < tr.out_ptr[i + 1]; ++k) {
        const Index j = tr.out_dst[k];
        buf[c++] = std::log(tr.out_p[k]) + log_b(t + 1, j) + lbeta(t + 1, j);
      }
      lbeta(t, i) = logsumexp(buf.data(), c);
    }
  }
  return lbeta;
}

double log_likelihood(const MatrixRef& log_b, const VectorRef& startprob, const MatrixRef& transmat,
                      const IndexVectorRef& lengths) {
  const Transitions tr = make_transitions(startprob, transmat);
  check_log_b(log_b, tr.n_states);
  const auto bounds = sequence_bounds(lengths, log_b.rows());
  const Index n = tr.n_states;
  double total = 0;
  VectorXd alpha(n), pred(n), la(n), lpred(n);
  std::vector<double> buf(static_cast<size_t>(n));
  for (size_t q = 0; q + 1 < bounds.size(); ++q) {
    const Index s = bounds[q], e = bounds[q + 1];
    double m = kNegInf;
    for (Index j = 0; j < n; ++j) {
      if (startprob[j] > 0) m = std::max(m, log_b(s, j));
    }
    if (m == kNegInf) fail_impossible(static_cast<Index>(q), 0);
    for (Index j = 0; j < n; ++j) alpha[j] = startprob[j] > 0 ? startprob[j] * std::exp(log_b(s, j) - m) : 0.0;
    double z = alpha.sum();
    alpha /= z;
    total += m + std::log(z);
    for (Index t = s + 1; t < e; ++t) {
      for (Index j = 0; j < n; ++j) {
        double acc = 0;
        for (Index k = tr.in_ptr[j]; k < tr.in_ptr[j + 1]; ++k) acc += alpha[tr.in_src[k]] * tr.in_p[k];
        pred[j] = acc;
      }
      m = kNegInf;
      for (Index j = 0; j < n; ++j) {
        if (pred[j] > 0) m = std::max(m, log_b(t, j));
      }
      if (m == kNegInf) fail_impossible(static_cast<Index>(q), t - s);
      z = 0;
      for (Index j = 0; j < n; ++j) {
        alpha[j] = pred[j] > 0 ? pred[j] * std::exp(log_b(t, j) - m) : 0.0;
        z += alpha[j];
      }
      if (!(z > 1e-290)) {  // underflow of the shifted products: redo this frame in logs
        for (Index j = 0; j < n; ++j) lpred[j] = pred[j] > 0 ? std::log(pred[j]) + log_b(t, j) : kNegInf;
        const double lz = logsumexp(lpred.data(), n);
        if (lz == kNegInf) fail_impossible(static_cast<Index>(q), t - s);
        alpha = (lpred.array() - lz).exp();
        total += lz;
        continue;
      }
      alpha /= z;
      total += m + std::log(z);
    }
  }
  return total;
}

ViterbiResult viterbi(const MatrixRef& log_b, const VectorRef& startprob, const MatrixRef& transmat,
                      const IndexVectorRef& lengths) {
  const Transitions tr = make_transitions(startprob, transmat);
  check_log_b(log_b, tr.n_states);
  const auto bounds = sequence_bounds(lengths, log_b.rows());
  const Index n = tr.n_states;
  std::vector<double> in_lp(tr.in_p.size());
  for (size_t k = 0; k < in_lp.size(); ++k) in_lp[k] = std::log(tr.in_p[k]);
  ViterbiResult r;
  r.path.resize(log_b.rows());
  VectorXd delta(n), next(n);
  for (size_t q = 0; q + 1 < bounds.size(); ++q) {
    const Index s = bounds[q], e = bounds[q + 1];
    Eigen::Matrix<std::int32_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> back(e - s, n);
    for (Index j = 0; j < n; ++j) delta[j] = std::log(startprob[j]) + log_b(s, j);
    for (Index t = s + 1; t < e; ++t) {
      for (Index j = 0; j < n; ++j) {
        double best = kNegInf;
        Index arg = -1;
        for (Index k = tr.in_ptr[j]; k < tr.in_ptr[j + 1]; ++k) {  // sources in increasing order
          const double v = delta[tr.in_src[k]] + in_lp[static_cast<size_t>(k)];
          if (v > best) {
            best = v;
            arg = tr.in_src[k];
          }
        }
        next[j] = best + log_b(t, j);
        back(t - s, j) = static_cast<std::int32_t>(arg);
      }
      delta.swap(next);
    }
    Index state = 0;
    const double best = delta.maxCoeff(&state);
    if (best == kNegInf) fail_impossible(static_cast<Index>(q), e - s - 1);
    r.log_probability += best;
    for (Index t = e - 1; t >= s; --t) {
      r.path[t] = state;
      if (t > s) state = back(t - s, state);
    }
  }
  return r;
}

}  // namespace voicepuppet
