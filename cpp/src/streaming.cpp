// Fixed-lag decoding (streaming.hpp).
#include "voicepuppet/streaming.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voicepuppet {

namespace {

constexpr double kNegInf = -std::numeric_limits<double>::infinity();

/// log Σ exp(v) of a vector; −inf if every entry is −inf.
double log_sum_exp(const VectorXd& v) {
  const double m = v.maxCoeff();
  if (m == kNegInf) return kNegInf;
  return m + std::log((v.array() - m).exp().sum());
}

}  // namespace

FixedLagDecoder::FixedLagDecoder(const VectorRef& startprob, const MatrixRef& transmat, Index lag)
    : tr_(make_transitions(startprob, transmat)), lag_(lag) {
  if (lag < 0) fail_argument("lag must be >= 0 frames, got ", lag);
  const Index n = tr_.n_states;
  log_start_ = startprob.array().log();
  in_lp_.resize(tr_.in_p.size());
  for (size_t k = 0; k < in_lp_.size(); ++k) in_lp_[k] = std::log(tr_.in_p[k]);
  out_lp_.resize(tr_.out_p.size());
  for (size_t k = 0; k < out_lp_.size(); ++k) out_lp_[k] = std::log(tr_.out_p[k]);
  delta_.resize(n);
  next_.resize(n);
  log_alpha_.resize(lag_ + 1, n);
  log_b_.resize(lag_ + 1, n);
  back_.resize(lag_ + 1, n);
  beta_.resize(n);
  beta_next_.resize(n);
  scratch_.resize(n);
}

void FixedLagDecoder::reset() {
  pushed_ = 0;
  emitted_ = 0;
  loglik_ = 0;
}

void FixedLagDecoder::step(const double* lb) {
  const Index n = tr_.n_states;
  const Index t = pushed_;
  VectorXd alpha(n);
  if (t == 0) {
    for (Index j = 0; j < n; ++j) {
      next_[j] = log_start_[j] + lb[j];
      alpha[j] = next_[j];
    }
  } else {
    const auto prev = log_alpha_.row(ring(t - 1));
    auto back = back_.row(ring(t));
    for (Index j = 0; j < n; ++j) {
      double best = kNegInf, m = kNegInf;
      Index arg = -1;
      for (Index k = tr_.in_ptr[j]; k < tr_.in_ptr[j + 1]; ++k) {  // sources in increasing order
        const Index i = tr_.in_src[k];
        const double v = delta_[i] + in_lp_[static_cast<size_t>(k)];
        if (v > best) {
          best = v;
          arg = i;
        }
        m = std::max(m, prev[i] + in_lp_[static_cast<size_t>(k)]);
      }
      double s = 0;
      if (m != kNegInf) {
        for (Index k = tr_.in_ptr[j]; k < tr_.in_ptr[j + 1]; ++k) {
          s += std::exp(prev[tr_.in_src[k]] + in_lp_[static_cast<size_t>(k)] - m);
        }
      }
      next_[j] = best + lb[j];
      alpha[j] = (m == kNegInf ? kNegInf : m + std::log(s)) + lb[j];
      back[j] = static_cast<std::int32_t>(arg);
    }
  }
  const double c = log_sum_exp(alpha);
  if (c == kNegInf || next_.maxCoeff() == kNegInf) {
    fail_numeric("fixed-lag decoding: frame ", t, " has zero probability under the model (every "
                 "state path is blocked by the transitions or the densities); call reset() and "
                 "check the model and the features");
  }
  log_alpha_.row(ring(t)) = (alpha.array() - c).matrix().transpose();
  for (Index j = 0; j < n; ++j) log_b_(ring(t), j) = lb[j];
  delta_.swap(next_);
  loglik_ += c;
  ++pushed_;
}

void FixedLagDecoder::decide(Index s, Index t_end, bool final_pass, DecodedFrames& out, Index row) {
  // Viterbi: trace back from the best state at t_end.
  Index state = 0;
  delta_.maxCoeff(&state);
  for (Index u = t_end; u > s; --u) state = back_(ring(u), state);
  out.states[row] = state;
  if (final_pass) return;  // flush computes the posteriors in one backward sweep
  // Posterior: backward over the look-ahead t_end .. s.
  beta_.setZero();
  for (Index u = t_end - 1; u >= s; --u) backward_step(u);
  posterior_row(s, out, row);
}

void FixedLagDecoder::backward_step(Index u) {
  // log β_u(i) = log Σ_j a_ij b_j(x_{u+1}) β_{u+1}(j), rescaled to max 0 (posteriors only
  // need β up to a constant).
  const Index n = tr_.n_states;
  const auto lb = log_b_.row(ring(u + 1));
  for (Index j = 0; j < n; ++j) scratch_[j] = lb[j] + beta_[j];
  for (Index i = 0; i < n; ++i) {
    double m = kNegInf;
    for (Index k = tr_.out_ptr[i]; k < tr_.out_ptr[i + 1]; ++k) {
      m = std::max(m, scratch_[tr_.out_dst[k]] + out_lp_[static_cast<size_t>(k)]);
    }
    double acc = 0;
    if (m != kNegInf) {
      for (Index k = tr_.out_ptr[i]; k < tr_.out_ptr[i + 1]; ++k) {
        acc += std::exp(scratch_[tr_.out_dst[k]] + out_lp_[static_cast<size_t>(k)] - m);
      }
    }
    beta_next_[i] = m == kNegInf ? kNegInf : m + std::log(acc);
  }
  const double norm = beta_next_.maxCoeff();
  beta_ = (beta_next_.array() - (norm == kNegInf ? 0.0 : norm)).matrix();
}

void FixedLagDecoder::posterior_row(Index s, DecodedFrames& out, Index row) const {
  const VectorXd g = log_alpha_.row(ring(s)).transpose() + beta_;
  const double z = log_sum_exp(g);
  out.posteriors.row(row) = (g.array() - z).exp().matrix().transpose();
}

DecodedFrames FixedLagDecoder::push(const MatrixRef& log_b) {
  const Index n = tr_.n_states;
  if (log_b.cols() != n) {
    fail_argument("log_b must have ", n, " columns (one per state), got ", shape_of(log_b));
  }
  for (Index t = 0; t < log_b.rows(); ++t) {
    for (Index j = 0; j < n; ++j) {
      const double v = log_b(t, j);
      if (std::isnan(v) || v == std::numeric_limits<double>::infinity()) {
        fail_argument("log_b row ", t, " state ", j, " is ", v,
                      "; log densities must be finite or -inf");
      }
    }
  }
  const Index n_new = std::max<Index>(0, pushed_ + log_b.rows() - lag_) -
                      std::max<Index>(0, pushed_ - lag_);
  DecodedFrames out;
  out.first_frame = emitted_;
  out.states.resize(n_new);
  out.posteriors.resize(n_new, n);
  Index row = 0;
  for (Index t = 0; t < log_b.rows(); ++t) {
    step(log_b.row(t).data());
    const Index last = pushed_ - 1;
    if (last >= lag_) {
      decide(last - lag_, last, false, out, row++);
      ++emitted_;
    }
  }
  return out;
}

DecodedFrames FixedLagDecoder::flush() {
  const Index n = tr_.n_states;
  DecodedFrames out;
  out.first_frame = emitted_;
  const Index k = pushed_ - emitted_;
  out.states.resize(k);
  out.posteriors.resize(k, n);
  if (k > 0) {
    const Index t_end = pushed_ - 1;
    for (Index s = emitted_; s <= t_end; ++s) decide(s, t_end, true, out, s - emitted_);
    // One backward sweep from the end for the posteriors of the held-back frames.
    beta_.setZero();
    for (Index s = t_end; s >= emitted_; --s) {
      if (s < t_end) backward_step(s);
      posterior_row(s, out, s - emitted_);
    }
  }
  reset();
  return out;
}

}  // namespace voicepuppet
