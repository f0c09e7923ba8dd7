#include "voicepuppet/hmm.hpp"
#include "voicepuppet/interrupt.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voicepuppet {
namespace {

using ArrayXd = Eigen::ArrayXd;
using RowVectorXd = Eigen::RowVectorXd;

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

// Below this shift a term exp(src - max) is taken as zero; e^-700 ≈ 9.9e-305 is still a normal
// double, so every kept term is exact to rounding.
constexpr double kFlush = -700.0;
// A kept sum at least kKeptFloor times the output's total arc probability dominates everything
// flushed: the flushed terms add at most e^-700 · Σp, a relative 9.9e-305 / 1e-280 < 1e-24 of it.
// Below it, the output is recomputed by log-sum-exp over its arcs (exact whatever the spread).
constexpr double kKeptFloor = 1e-280;

// One arc list (by destination for the forward pass, by source for the backward pass).
struct ArcList {
  const Index* ptr;
  const Index* idx;
  const double* p;
  const double* lp;    // log p
  const double* psum;  // Σ p over each output's arcs
};

ArcList arcs_in(const Transitions& tr) {
  return {tr.in_ptr.data(), tr.in_src.data(), tr.in_p.data(), tr.in_lp.data(), tr.in_sum.data()};
}
ArcList arcs_out(const Transitions& tr) {
  return {tr.out_ptr.data(), tr.out_dst.data(), tr.out_p.data(), tr.out_lp.data(), tr.out_sum.data()};
}

// Scratch of log_transfer, kept so the backward pass can reuse the shifted terms for ξ.
struct Transfer {
  double shift = kNegInf;  // max of src
  ArrayXd e;               // exp(src - shift), flushed to 0 below kFlush
  ArrayXd acc;             // kept sums Σ p · e per output
  std::vector<char> exact;  // 1 where the output was recomputed by log-sum-exp
  std::vector<double> buf;
  explicit Transfer(Index n) : e(n), acc(n), exact(static_cast<size_t>(n)), buf(static_cast<size_t>(n)) {}
};

// out[o] = log Σ_{arcs k of o} p_k · exp(src[idx_k]), exact in every regime: linear sums of terms
// shifted by max(src), with each output whose kept sum cannot be trusted (see kKeptFloor) redone
// by log-sum-exp over its arcs. Costs n exp + n log + one multiply-add per arc in the common case.
void log_transfer(const ArcList& a, Index n, const double* src, double* out, Transfer& w) {
  const Eigen::Map<const ArrayXd> x(src, n);
  Eigen::Map<ArrayXd> y(out, n);
  w.shift = x.maxCoeff();
  if (w.shift == kNegInf) {
    y.setConstant(kNegInf);
    w.e.setZero();
    w.acc.setZero();
    std::fill(w.exact.begin(), w.exact.end(), 0);
    return;
  }
  w.e = x - w.shift;
  w.e = (w.e < kFlush).select(0.0, w.e.exp());
  for (Index o = 0; o < n; ++o) {
    double acc = 0;
    for (Index k = a.ptr[o]; k < a.ptr[o + 1]; ++k) acc += a.p[k] * w.e[a.idx[k]];
    w.acc[o] = acc;
  }
  y = w.acc.log() + w.shift;
  for (Index o = 0; o < n; ++o) {
    const bool redo = !(w.acc[o] >= kKeptFloor * a.psum[o]);
    w.exact[static_cast<size_t>(o)] = redo;
    if (!redo) continue;
    Index c = 0;
    for (Index k = a.ptr[o]; k < a.ptr[o + 1]; ++k) w.buf[static_cast<size_t>(c++)] = src[a.idx[k]] + a.lp[k];
    out[o] = logsumexp(w.buf.data(), c);
  }
}

// Forward lattice log α of rows [s, e) of log_b into la (len by n); throws when a frame has no
// allowed state.
void forward_log_pass(const MatrixRef& log_b, const Transitions& tr, const VectorRef& startprob, Index s,
                      Index e, Index seq, RowMatrixXd& la, Transfer& w) {
  const Index n = tr.n_states;
  const ArcList a = arcs_in(tr);
  la.row(0) = startprob.transpose().array().log() + log_b.row(s).array();
  if (la.row(0).maxCoeff() == kNegInf) fail_impossible(seq, 0);
  for (Index t = 1; t < e - s; ++t) {
    check_interrupt();
    log_transfer(a, n, la.row(t - 1).data(), la.row(t).data(), w);
    la.row(t) += log_b.row(s + t);
    if (la.row(t).maxCoeff() == kNegInf) fail_impossible(seq, t);
  }
}

// γ_t ∝ exp(log α_t + log β_t), normalised over the frame's states: the rounding common to a
// frame's lattice entries (|log α| grows with t) cancels, so rows sum to one to rounding.
template <class Out>
void set_posterior(const Eigen::Ref<const RowVectorXd>& la, const RowVectorXd& lbeta, Out&& gamma) {
  gamma = la + lbeta;
  gamma = exp_or_zero(gamma.array() - gamma.maxCoeff());
  gamma /= gamma.sum();
}

// Forward-backward of one sequence (rows [s, e) of log_b) on log lattices with shifted linear
// sums (log_transfer): exact like forward_backward_log_one at a fraction of its exps.
// γ_t(i) = exp(log α + log β − ll) (normalised per frame); ξ_t(i, j) = γ_t(i) · p_ij · exp(w_j − log β_t(i)) with
// w = log b_{t+1} + log β_{t+1}, taken from the transfer's shifted terms where they are exact.
void forward_backward_one(const MatrixRef& log_b, const Transitions& tr, const VectorRef& startprob, Index s,
                          Index e, Index seq, double& loglik, RowMatrixXd& gamma, RowMatrixXd& xi,
                          VectorXd& starts) {
  const Index n = tr.n_states;
  const Index len = e - s;
  RowMatrixXd la(len, n);
  Transfer w(n);
  forward_log_pass(log_b, tr, startprob, s, e, seq, la, w);
  const double ll = logsumexp(la.row(len - 1).data(), n);
  if (ll == kNegInf) fail_impossible(seq, len - 1);
  const ArcList a = arcs_out(tr);
  RowVectorXd lbeta = RowVectorXd::Zero(n), lbeta_prev(n), wv(n);
  set_posterior(la.row(len - 1), lbeta, gamma.row(s + len - 1));
  for (Index t = len - 2; t >= 0; --t) {
    wv = log_b.row(s + t + 1) + lbeta;
    log_transfer(a, n, wv.data(), lbeta_prev.data(), w);
    set_posterior(la.row(t), lbeta_prev, gamma.row(s + t));
    for (Index i = 0; i < n; ++i) {
      const double g = gamma(s + t, i);
      if (g == 0) continue;
      if (w.exact[static_cast<size_t>(i)]) {
        for (Index k = a.ptr[i]; k < a.ptr[i + 1]; ++k) {
          xi(i, a.idx[k]) += g * std::exp(a.lp[k] + wv[a.idx[k]] - lbeta_prev[i]);  // exponent ≤ 0
        }
      } else {
        // exp(w_j − log β_t(i)) = e_j / acc_i for the kept j; flushed j (e_j = 0, w_j finite)
        // are added exactly so no arc's count is lost.
        const double gs = g / w.acc[i];
        for (Index k = a.ptr[i]; k < a.ptr[i + 1]; ++k) {
          const Index j = a.idx[k];
          const double ej = w.e[j];
          if (ej > 0) {
            xi(i, j) += gs * a.p[k] * ej;
          } else if (wv[j] > kNegInf) {
            xi(i, j) += g * std::exp(a.lp[k] + wv[j] - lbeta_prev[i]);
          }
        }
      }
    }
    lbeta.swap(lbeta_prev);
  }
  starts += gamma.row(s).transpose();
  loglik = ll;
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
  tr.in_lp.resize(n_arcs);
  tr.out_lp.resize(n_arcs);
  for (size_t k = 0; k < n_arcs; ++k) {
    tr.in_lp[k] = std::log(tr.in_p[k]);
    tr.out_lp[k] = std::log(tr.out_p[k]);
  }
  tr.in_sum.assign(static_cast<size_t>(n), 0.0);
  tr.out_sum.assign(static_cast<size_t>(n), 0.0);
  for (Index j = 0; j < n; ++j) {
    for (Index k = tr.in_ptr[j]; k < tr.in_ptr[j + 1]; ++k) tr.in_sum[static_cast<size_t>(j)] += tr.in_p[k];
    for (Index k = tr.out_ptr[j]; k < tr.out_ptr[j + 1]; ++k) tr.out_sum[static_cast<size_t>(j)] += tr.out_p[k];
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
        forward_backward_one(lb, tr, pi, s, e, q, ll, r.posteriors, r.expected_transitions, r.expected_starts);
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
  const ArcList a = arcs_in(tr);
  Transfer w(n);
  RowVectorXd la(n), next(n);
  double total = 0;
  for (size_t q = 0; q + 1 < bounds.size(); ++q) {
    const Index s = bounds[q], e = bounds[q + 1];
    la = startprob.transpose().array().log() + log_b.row(s).array();
    if (la.maxCoeff() == kNegInf) fail_impossible(static_cast<Index>(q), 0);
    for (Index t = s + 1; t < e; ++t) {
      check_interrupt();
      log_transfer(a, n, la.data(), next.data(), w);
      la = next + log_b.row(t);
      if (la.maxCoeff() == kNegInf) fail_impossible(static_cast<Index>(q), t - s);
    }
    total += logsumexp(la.data(), n);
  }
  return total;
}

ViterbiResult viterbi(const MatrixRef& log_b, const VectorRef& startprob, const MatrixRef& transmat,
                      const IndexVectorRef& lengths) {
  const Transitions tr = make_transitions(startprob, transmat);
  check_log_b(log_b, tr.n_states);
  const auto bounds = sequence_bounds(lengths, log_b.rows());
  const Index n = tr.n_states;
  const std::vector<double>& in_lp = tr.in_lp;
  ViterbiResult r;
  r.path.resize(log_b.rows());
  VectorXd delta(n), next(n);
  for (size_t q = 0; q + 1 < bounds.size(); ++q) {
    const Index s = bounds[q], e = bounds[q + 1];
    Eigen::Matrix<std::int32_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> back(e - s, n);
    for (Index j = 0; j < n; ++j) delta[j] = std::log(startprob[j]) + log_b(s, j);
    for (Index t = s + 1; t < e; ++t) {
      check_interrupt();
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
