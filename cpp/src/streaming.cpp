// Fixed-lag decoding (streaming.hpp).
#include "voicepuppet/streaming.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>

namespace voicepuppet {

namespace {

constexpr double kNegInf = -std::numeric_limits<double>::infinity();

/// log Σ exp(v) of a vector; −inf if every entry is −inf.
double log_sum_exp(const VectorXd& v) {
  const double m = v.maxCoeff();
  if (m == kNegInf) return kNegInf;
  return m + std::log(exp_or_zero(v.array() - m).sum());
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
  out.posteriors.row(row) = exp_or_zero(g.array() - z).matrix().transpose();
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

// ------------------------------------------------------------------ StreamingPuppet
RowMatrixXd StreamingPuppet::VocalModel::log_density(const RowMatrixXd& z) const {
  const Index T = z.rows(), N = means.rows();
  RowMatrixXd out(T, N);
  for (Index n = 0; n < N; ++n) {
    for (Index t = 0; t < T; ++t) {
      const VectorXd d = (z.row(t) - means.row(n)).transpose();
      const double q = diagonal ? (d.array().square() * inv_var.row(n).transpose().array()).sum()
                                : chol[static_cast<size_t>(n)].triangularView<Eigen::Lower>().solve(d).squaredNorm();
      out(t, n) = constant[n] - 0.5 * q;
    }
  }
  return out;
}

namespace {

/// Output frames of a resampled sequence of n input frames (as trajectory.cpp's
/// resample_states / resample_weights: every output time inside the input's duration).
Index resampled_count(Index n, double fps_in, double fps_out) {
  const double x = static_cast<double>(n) * fps_out / fps_in;
  return std::max<Index>(1, static_cast<Index>(std::ceil(x - 1e-9 * std::max(1.0, x))));
}

/// Where output frame k falls among n known input frames for a linear interpolation, as
/// trajectory.cpp's resample_weights: input j and weight fr of input j + 1 (u = k · fps_in /
/// fps_out clamped to the last frame at the end, `final_pass`). False while a frame it needs is
/// not known yet. At equal rates frame k is input k: k · fps / fps can round just above k and
/// would wait one frame for a weight of ~1e-16.
bool interpolation_at(Index k, Index n, double fps_in, double fps_out, bool final_pass, Index& j, double& fr) {
  if (fps_in == fps_out) {
    j = k;
    fr = 0.0;
    return k < n;
  }
  double u = static_cast<double>(k) * fps_in / fps_out;
  if (final_pass) u = std::min(u, static_cast<double>(n - 1));
  j = final_pass ? std::min(static_cast<Index>(std::floor(u)), n - 1) : static_cast<Index>(std::floor(u));
  fr = u - static_cast<double>(j);
  if (final_pass && j + 1 >= n) fr = 0.0;
  return j < n && !(fr > 0.0 && j + 1 >= n);
}

/// The first input frame an output stream resampled up to (not including) output frame
/// `next_out` may still read: the window [first, n) is trimmed to it.
Index first_needed(Index next_out, double fps_in, double fps_out, Index first, Index n) {
  const double u = static_cast<double>(next_out) * fps_in / fps_out;
  return std::max<Index>(first, std::min<Index>(static_cast<Index>(std::floor(u)) - 1, n));
}

/// (1 − fr) · v[j] + fr · v[j + 1] of a window v of frames first ...
VectorXd interpolate(const std::vector<VectorXd>& v, Index first, Index j, double fr) {
  const VectorXd& a = v[static_cast<size_t>(j - first)];
  return fr > 0.0 ? VectorXd((1.0 - fr) * a + fr * v[static_cast<size_t>(j + 1 - first)]) : a;
}

constexpr double kLog2Pi = 1.8378770664093454835606594728112;

/// Rows from .. to − 1 of a context map out_s = [z_{s−k}, …, z_{s+k}] (first C columns) · map +
/// offset over the ring z (frames z_first ..), the context clamped to the first frame and to the
/// newest one frame s may read (s + lag; the last known frame at the end), as Puppet::project
/// and Puppet::guide_predict clamp to the recording's edges: with lag = k the row is the
/// offline one. Shared by the projection and the guide.
RowMatrixXd context_rows(const std::vector<VectorXd>& z, Index z_first, Index from, Index to, Index k, Index C,
                         Index lag, Index known, bool final_pass, const RowMatrixXd& map, const VectorXd& offset) {
  const Index n = std::max<Index>(to - from, 0);
  RowMatrixXd x(n, C * (2 * k + 1));
  for (Index s = from; s < to; ++s) {
    const Index hi = final_pass ? known - 1 : s + lag;
    for (Index j = -k; j <= k; ++j) {
      const Index u = std::clamp<Index>(s + j, 0, hi);
      x.row(s - from).segment((j + k) * C, C) = z[static_cast<size_t>(u - z_first)].head(C).transpose();
    }
  }
  RowMatrixXd v = x * map;
  v.rowwise() += offset.transpose();
  return v;
}

std::vector<TrajectoryModel> part_models(const Puppet& puppet, double fps) {
  std::vector<TrajectoryModel> m;
  for (Index p = 0; p < puppet.n_parts(); ++p) m.push_back(puppet.trajectory_model(fps, p));
  return m;
}

}  // namespace

StreamingPuppet::StreamingPuppet(const Puppet& puppet, const StreamingOptions& options)
    : puppet_(puppet), options_(options) {
  if (options.decode_lag < 0) fail_argument("decode_lag must be >= 0 frames, got ", options.decode_lag);
  if (options.trajectory_lag < 0) {
    fail_argument("trajectory_lag must be >= 0 frames, got ", options.trajectory_lag);
  }
  if (!(options.fps >= 0) || !std::isfinite(options.fps)) {
    fail_argument("fps must be 0 (the puppet's rate) or a positive frame rate, got ", options.fps);
  }
  out_fps_ = options.fps == 0 ? puppet_.fps() : options.fps;
  const Index w = puppet_.delta_width();
  if (options.delta_lag < -1 || options.delta_lag > w) {
    fail_argument("delta_lag must be -1 (the puppet's delta width, ", w, ") or 0 .. ", w,
                  " frames, got ", options.delta_lag);
  }
  const Index k = puppet_.projection_context();
  // λ of the guide (as Puppet::animate's guide_weight: negative or NaN the file's, 0 unguided)
  double lambda = options.guide_weight;
  if (std::isnan(lambda) || lambda < 0) lambda = puppet_.guide_weight();
  if (!std::isfinite(lambda)) fail_argument("guide_weight must be finite, got ", options.guide_weight);
  if (lambda > 0 && !puppet_.guided()) {
    fail_argument("guide_weight = ", lambda, " needs a guided puppet, but this one has no guide; "
                  "train it with guide=\"ridge\" or pass 0");
  }
  guide_on_ = lambda > 0;
  options_.guide_weight = lambda;
  const Index kg = puppet_.guided() ? puppet_.guide_context() : 0;
  if (options.guide_lag < -1 || options.guide_lag > kg) {
    fail_argument("guide_lag must be -1 (the puppet's guide context, ", kg, ") or 0 .. ", kg, " frames",
                  puppet_.guided() ? "" : " (this puppet has no guide)", ", got ", options.guide_lag);
  }
  guide_lag_ = guide_on_ ? (options.guide_lag < 0 ? kg : options.guide_lag) : 0;
  options_.guide_lag = guide_lag_;
  // A projection (or a guide) of the features alone never reads the deltas: waiting for them
  // would only add latency (Puppet::vocal_delta_width).
  const bool guide_deltas = guide_on_ && puppet_.guide_columns() > puppet_.n_features();
  delta_lag_ = options.delta_lag < 0 ? (guide_deltas ? w : puppet_.vocal_delta_width()) : options.delta_lag;
  options_.delta_lag = delta_lag_;
  if (options.projection_lag < -1 || options.projection_lag > k) {
    fail_argument("projection_lag must be -1 (the puppet's projection context, ", k, ") or 0 .. ", k,
                  " frames", puppet_.projected() ? "" : " (this puppet has no projection)", ", got ",
                  options.projection_lag);
  }
  projection_lag_ = options.projection_lag < 0 ? k : options.projection_lag;
  options_.projection_lag = projection_lag_;
  ring_columns_ = std::max<Index>(puppet_.projected() ? puppet_.projection_columns() : 0,
                                  guide_on_ ? puppet_.guide_columns() : 0);
  mean_ = puppet_.file().at("audio/mean").matrix().row(0).transpose();
  std_ = puppet_.file().at("audio/std").matrix().row(0).transpose();
  const auto models = part_models(puppet_, out_fps_);
  for (Index p = 0; p < puppet_.n_parts(); ++p) {
    const PuppetPart& pt = puppet_.part(p);
    VocalModel vm;
    const Index N = pt.n_states(), A = pt.vocal_means.cols();
    vm.means = pt.vocal_means;
    vm.constant.resize(N);
    vm.diagonal = pt.vocal_type == CovarianceType::Diagonal;
    if (vm.diagonal) {
      vm.inv_var = pt.vocal_covars.cwiseInverse();
      for (Index n = 0; n < N; ++n) {
        vm.constant[n] = -0.5 * (static_cast<double>(A) * kLog2Pi + pt.vocal_covars.row(n).array().log().sum());
      }
    } else {
      for (Index n = 0; n < N; ++n) {
        Eigen::LLT<Eigen::MatrixXd> llt(Eigen::MatrixXd(pt.vocal_covars.middleRows(n * A, A)));
        if (llt.info() != Eigen::Success) fail_argument("vocal covariance of state ", n, " is not positive definite");
        vm.chol.push_back(llt.matrixL());
        vm.constant[n] = -0.5 * (static_cast<double>(A) * kLog2Pi +
                                 2.0 * vm.chol.back().diagonal().array().log().sum());
      }
    }
    const TrajectoryModel& tm = models[static_cast<size_t>(p)];
    parts_.push_back(PartStream{std::move(vm), FixedLagDecoder(pt.startprob, pt.transmat, options.decode_lag),
                                guide_on_ ? FixedLagTrajectory(tm, options.trajectory_lag, lambda * puppet_.guide_precision(p))
                                          : FixedLagTrajectory(tm, options.trajectory_lag),
                                {}, {}, 0, 0, 0, {}, {}, 0, 0});
    parts_.back().col = p == 0 ? 0 : parts_[static_cast<size_t>(p - 1)].col + puppet_.part(p - 1).n_dims();
  }
}

double StreamingPuppet::latency_seconds() const {
  // the guide's look-ahead runs alongside the projection's and the decoder's
  const Index audio = delta_lag_ + std::max<Index>(projection_lag_ + options_.decode_lag, guide_lag_);
  return static_cast<double>(audio) / puppet_.fps() + static_cast<double>(options_.trajectory_lag) / out_fps_;
}

double StreamingPuppet::log_likelihood() const {
  double s = 0;
  for (const auto& ps : parts_) s += ps.decoder.log_likelihood();
  return s;
}

void StreamingPuppet::reset() {
  for (auto& ps : parts_) {
    ps.decoder.reset();
    ps.trajectory.flush();  // discards the held-back frames and resets
    ps.states.clear();
    ps.weights.clear();
    ps.first = ps.decided = ps.next_out = 0;
    ps.pending_states.clear();
    ps.pending_weights.clear();
    ps.in_trajectory = 0;
  }
  raw_.clear();
  raw_first_ = standardized_ = 0;
  z_.clear();
  z_first_ = projected_ = vocal_ = 0;
  yhat_.clear();
  yout_.clear();
  guided_ = yhat_first_ = yout_first_ = yout_next_ = 0;
  pushed_ = emitted_ = 0;
}

RowMatrixXd StreamingPuppet::feed(PartStream& ps, const DecodedFrames& f, bool final_pass) {
  const double fin = puppet_.fps(), fout = out_fps_;
  const bool post = options_.posterior;
  for (Index k = 0; k < f.size(); ++k) {
    if (post) {
      ps.weights.emplace_back(f.posteriors.row(k).transpose());
    } else {
      ps.states.push_back(f.states[k]);
    }
  }
  ps.decided += f.size();
  const Index n = ps.decided;
  const Index m_total = final_pass ? resampled_count(n, fin, fout) : -1;
  // Output frames whose input frames are decided, resampled as resample_states/_weights do.
  std::vector<Index> out_states;
  std::vector<VectorXd> out_weights;
  for (;; ++ps.next_out) {
    const Index k = ps.next_out;
    if (final_pass && k >= m_total) break;
    if (fin == fout) {
      if (k >= n) break;
      if (post) {
        out_weights.push_back(ps.weights[static_cast<size_t>(k - ps.first)]);
      } else {
        out_states.push_back(ps.states[static_cast<size_t>(k - ps.first)]);
      }
      continue;
    }
    if (!post) {
      const double u = static_cast<double>(k) * fin / fout;
      Index j = static_cast<Index>(std::floor(u + 1e-9 * std::max(1.0, u)));
      if (final_pass) j = std::min(j, n - 1);
      if (j >= n) break;
      out_states.push_back(ps.states[static_cast<size_t>(j - ps.first)]);
    } else {
      Index j = 0;
      double fr = 0.0;
      if (!interpolation_at(k, n, fin, fout, final_pass, j, fr)) break;
      out_weights.push_back(interpolate(ps.weights, ps.first, j, fr));
    }
  }
  // Forget input frames no later output frame needs.
  {
    const Index keep = first_needed(ps.next_out, fin, fout, ps.first, n);
    const auto drop = static_cast<std::ptrdiff_t>(keep - ps.first);
    if (post) {
      ps.weights.erase(ps.weights.begin(), ps.weights.begin() + std::min<std::ptrdiff_t>(drop, ps.weights.size()));
    } else {
      ps.states.erase(ps.states.begin(), ps.states.begin() + std::min<std::ptrdiff_t>(drop, ps.states.size()));
    }
    ps.first = keep;
  }
  ps.pending_states.insert(ps.pending_states.end(), out_states.begin(), out_states.end());
  ps.pending_weights.insert(ps.pending_weights.end(), out_weights.begin(), out_weights.end());
  RowMatrixXd face = push_ready(ps);
  if (final_pass) {
    const RowMatrixXd rest = ps.trajectory.flush();
    RowMatrixXd all(face.rows() + rest.rows(), rest.cols());
    if (face.rows()) all.topRows(face.rows()) = face;
    if (rest.rows()) all.bottomRows(rest.rows()) = rest;
    face = std::move(all);
  }
  return face;
}

RowMatrixXd StreamingPuppet::push_ready(PartStream& ps) {
  const bool post = options_.posterior;
  const Index pending = static_cast<Index>(post ? ps.pending_weights.size() : ps.pending_states.size());
  // a frame enters the trajectory once its state (or posterior row) and its ŷ are known
  const Index n = guide_on_ ? std::min(pending, yout_next_ - ps.in_trajectory) : pending;
  RowMatrixXd face;
  const Index K = ps.trajectory.model().n_dims();
  RowMatrixXd targets;
  if (guide_on_) {
    targets.resize(n, K);
    for (Index i = 0; i < n; ++i) {
      targets.row(i) = yout_[static_cast<size_t>(ps.in_trajectory + i - yout_first_)].segment(ps.col, K).transpose();
    }
  }
  if (post) {
    RowMatrixXd w(n, ps.decoder.n_states());
    for (Index i = 0; i < n; ++i) w.row(i) = ps.pending_weights[static_cast<size_t>(i)].transpose();
    face = guide_on_ ? ps.trajectory.push_weights(w, targets) : ps.trajectory.push_weights(w);
    ps.pending_weights.erase(ps.pending_weights.begin(), ps.pending_weights.begin() + static_cast<std::ptrdiff_t>(n));
  } else {
    VectorXi st(n);
    for (Index i = 0; i < n; ++i) st[i] = ps.pending_states[static_cast<size_t>(i)];
    face = guide_on_ ? ps.trajectory.push_states(st, targets) : ps.trajectory.push_states(st);
    ps.pending_states.erase(ps.pending_states.begin(), ps.pending_states.begin() + static_cast<std::ptrdiff_t>(n));
  }
  ps.in_trajectory += n;
  return face;
}

StreamedFrames StreamingPuppet::assemble(std::vector<RowMatrixXd>& faces) {
  StreamedFrames out;
  out.first_frame = emitted_;
  const Index m = faces.empty() ? 0 : faces.front().rows();
  Index K = 0;
  for (const auto& f : faces) {
    if (f.rows() != m) fail_numeric("streaming puppet: face parts emitted different frame counts");  // a bug
    K += f.cols();
  }
  out.face.resize(m, puppet_.n_dims());
  Index col = 0;
  for (const auto& f : faces) {
    if (m > 0) out.face.middleCols(col, f.cols()) = f;
    col += f.cols();
  }
  out.points = m > 0 ? puppet_.to_points(out.face) : RowMatrixXd(0, 2 * puppet_.n_points());
  emitted_ += m;
  return out;
}

RowMatrixXd StreamingPuppet::standardized_ready(bool final_pass) {
  const Index w = puppet_.delta_width(), A = puppet_.n_features();
  // frame s is ready once frame s + delta_lag is in (all frames at the end)
  const Index ready = final_pass ? pushed_ : std::max<Index>(0, pushed_ - delta_lag_);
  const Index k = ready - standardized_;
  RowMatrixXd z(std::max<Index>(k, 0), mean_.size());
  for (Index s = standardized_; s < ready; ++s) {
    // deltas of frame s from frames max(s − w, 0) .. s + delta_lag (.. min(s + w, last) at the
    // end): append_deltas on that window repeats its edge frames exactly as the offline deltas
    // repeat the recording's, whatever the chunking
    const Index lo = std::max<Index>(s - w, 0);
    const Index hi = final_pass ? std::min<Index>(s + w, pushed_ - 1) : s + delta_lag_;
    RowMatrixXd win(hi - lo + 1, A);
    for (Index u = lo; u <= hi; ++u) win.row(u - lo) = raw_[static_cast<size_t>(u - raw_first_)].transpose();
    const RowMatrixXd ext = append_deltas(win, w);
    z.row(s - standardized_) = ext.row(s - lo);
  }
  standardized_ = ready;
  z.rowwise() -= mean_.transpose();
  z.array().rowwise() /= std_.transpose().array();
  // forget raw frames no later delta needs (frames before the next frame's window)
  const Index keep = std::max<Index>(raw_first_, standardized_ - w);
  raw_.erase(raw_.begin(), raw_.begin() + static_cast<std::ptrdiff_t>(keep - raw_first_));
  raw_first_ = keep;
  return z;
}

RowMatrixXd StreamingPuppet::vocal_ready(const RowMatrixXd& z, bool final_pass) {
  if (!puppet_.projected()) return z;
  // frame s is ready once frame s + projection_lag is standardised (all frames at the end)
  const Index known = standardized_;
  const Index ready = final_pass ? known : std::max<Index>(0, known - projection_lag_);
  RowMatrixXd v = context_rows(z_, z_first_, projected_, ready, puppet_.projection_context(),
                               puppet_.projection_columns(), projection_lag_, known, final_pass,
                               puppet_.projection(), puppet_.projection_offset());
  projected_ = std::max(projected_, ready);
  return v;
}

void StreamingPuppet::guide_ready(bool final_pass) {
  if (!guide_on_) return;
  // ŷ of frame s once frame s + guide_lag is standardised (all frames at the end)
  const Index known = standardized_;
  const Index ready = final_pass ? known : std::max<Index>(0, known - guide_lag_);
  const RowMatrixXd y = context_rows(z_, z_first_, guided_, ready, puppet_.guide_context(), puppet_.guide_columns(),
                                     guide_lag_, known, final_pass, puppet_.guide_map(), puppet_.guide_offset());
  for (Index i = 0; i < y.rows(); ++i) yhat_.emplace_back(y.row(i).transpose());
  guided_ = std::max(guided_, ready);
  // ŷ at the output rate, as Puppet::animate: resample_weights' linear interpolation
  const double fin = puppet_.fps(), fout = out_fps_;
  const Index n = guided_;
  const Index m_total = final_pass ? resampled_count(n, fin, fout) : -1;
  for (;; ++yout_next_) {
    const Index k = yout_next_;
    if (final_pass && k >= m_total) break;
    Index j = 0;
    double fr = 0.0;
    if (!interpolation_at(k, n, fin, fout, final_pass, j, fr)) break;
    yout_.push_back(interpolate(yhat_, yhat_first_, j, fr));
  }
  // forget input frames no later output frame needs
  const Index keep = first_needed(yout_next_, fin, fout, yhat_first_, guided_);
  yhat_.erase(yhat_.begin(), yhat_.begin() + static_cast<std::ptrdiff_t>(keep - yhat_first_));
  yhat_first_ = keep;
}

void StreamingPuppet::trim_ring() {
  if (ring_columns_ == 0) return;  // neither a projection nor a guide: the ring is unused
  // forget standardised frames no later context needs (those before the next frame's)
  Index keep = standardized_;
  if (puppet_.projected()) keep = std::min(keep, projected_ - puppet_.projection_context());
  if (guide_on_) keep = std::min(keep, guided_ - puppet_.guide_context());
  keep = std::max(keep, z_first_);
  z_.erase(z_.begin(), z_.begin() + static_cast<std::ptrdiff_t>(keep - z_first_));
  z_first_ = keep;
}

StreamedFrames StreamingPuppet::advance(const RowMatrixXd& z, bool final_pass) {
  if (ring_columns_ > 0) {
    for (Index t = 0; t < z.rows(); ++t) z_.emplace_back(z.row(t).head(ring_columns_).transpose());
  }
  RowMatrixXd v = vocal_ready(z, final_pass);
  guide_ready(final_pass);
  trim_ring();
  return decode(std::move(v), final_pass);
}

StreamedFrames StreamingPuppet::decode(RowMatrixXd v, bool final_pass) {
  std::vector<RowMatrixXd> faces;
  for (Index p = 0; p < puppet_.n_parts(); ++p) {
    PartStream& ps = parts_[static_cast<size_t>(p)];
    DecodedFrames f = v.rows() ? ps.decoder.push(ps.vocal.log_density(v)) : DecodedFrames{};
    if (final_pass) {
      DecodedFrames rest = ps.decoder.flush();
      if (f.size() == 0) {
        f = std::move(rest);
      } else if (rest.size() > 0) {
        DecodedFrames both;
        both.first_frame = f.first_frame;
        both.states.resize(f.size() + rest.size());
        both.states << f.states, rest.states;
        both.posteriors.resize(both.states.size(), f.posteriors.cols());
        both.posteriors << f.posteriors, rest.posteriors;
        f = std::move(both);
      }
    }
    faces.push_back(feed(ps, f, final_pass));
  }
  if (guide_on_) {  // forget output-rate ŷ every part has pushed
    Index keep = yout_next_;
    for (const auto& ps : parts_) keep = std::min(keep, ps.in_trajectory);
    yout_.erase(yout_.begin(), yout_.begin() + static_cast<std::ptrdiff_t>(keep - yout_first_));
    yout_first_ = keep;
  }
  StreamedFrames out = assemble(faces);
  out.first_vocal = vocal_;
  vocal_ += v.rows();
  out.vocal = std::move(v);
  return out;
}

StreamedFrames StreamingPuppet::push(const MatrixRef& raw_features) {
  if (raw_features.cols() != puppet_.n_features()) {
    fail_argument("raw_features must have ", puppet_.n_features(), " columns (the puppet's audio "
                  "features), got ", shape_of(raw_features));
  }
  require_finite(raw_features, "raw_features");
  for (Index t = 0; t < raw_features.rows(); ++t) raw_.emplace_back(raw_features.row(t).transpose());
  pushed_ += raw_features.rows();
  return advance(standardized_ready(false), false);
}

StreamedFrames StreamingPuppet::flush() {
  StreamedFrames out;
  if (pushed_ == 0) {
    std::vector<RowMatrixXd> faces;
    for (Index p = 0; p < puppet_.n_parts(); ++p) faces.emplace_back(0, puppet_.part(p).n_dims());
    out = assemble(faces);
    out.vocal.resize(0, puppet_.n_vocal());
  } else {
    out = advance(standardized_ready(true), true);
  }
  reset();
  return out;
}

}  // namespace voicepuppet

