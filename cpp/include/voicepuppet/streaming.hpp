#pragma once
/// @file streaming.hpp
/// Live analysis with a bounded latency: fixed-lag decoding of an HMM over per-frame log
/// densities (fixed-lag Viterbi and fixed-lag smoothed posteriors).
///
/// A frame t is decided once frame t + L has been pushed (L = lag, in frames):
///  - its Viterbi state is the state at t of the best path ending at t + L (the best partial
///    path, traced back L steps);
///  - its posterior is p(s_t | x_0 .. x_{t+L}) ∝ α_t ⊙ β_{t|t+L}, with the backward pass over
///    the L frames of look-ahead only.
/// Work per frame is O(L · arcs) (independent of the stream's length) and memory O(L · N).
/// With L ≥ T − 1 (or at `flush`, for the frames still held back) the decisions are those of
/// the offline `viterbi` and `forward_backward` (hmm.hpp) on the whole sequence.

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/types.hpp"

#include <cstdint>
#include <vector>

namespace voicepuppet {

/// Frames decided by a push or a flush.
struct DecodedFrames {
  Index first_frame = 0;   ///< stream index of the first decided frame
  VectorXi states;         ///< #K fixed-lag Viterbi states
  RowMatrixXd posteriors;  ///< #K by #N fixed-lag smoothed posteriors (rows sum to 1)
  Index size() const { return states.size(); }
};

/// Online fixed-lag decoder of one hidden Markov model. State is carried between pushes.
class FixedLagDecoder {
 public:
  /// @param[in] startprob  #N start probabilities (non-negative, summing to 1)
  /// @param[in] transmat   #N by #N row-stochastic transition matrix
  /// @param[in] lag        frames of look-ahead L ≥ 0
  /// @throws std::invalid_argument on a bad model (as make_transitions) or a negative lag.
  FixedLagDecoder(const VectorRef& startprob, const MatrixRef& transmat, Index lag);

  /// Pushes frames of log emission densities; returns the frames decided by them (those that
  /// now have L frames after them).
  /// @param[in] log_b  #K by #N log p(x_t | state n), K ≥ 0; finite or −inf (never NaN or +inf)
  /// @throws std::invalid_argument on a wrong shape or NaN / +inf; std::runtime_error when the
  ///         stream has zero probability under the model (every path blocked).
  DecodedFrames push(const MatrixRef& log_b);

  /// Ends the stream: decides the frames still held back from the whole stream (as offline),
  /// then resets for a new stream.
  DecodedFrames flush();

  /// Forgets the stream (a new one starts at frame 0).
  void reset();

  Index lag() const { return lag_; }
  Index n_states() const { return tr_.n_states; }
  Index frames_pushed() const { return pushed_; }
  Index frames_emitted() const { return emitted_; }
  /// log p(x_0 .. x_{t}) of the frames pushed so far (forward algorithm).
  double log_likelihood() const { return loglik_; }

 private:
  void step(const double* log_b);
  void decide(Index s, Index t_end, bool final_pass, DecodedFrames& out, Index row);
  void backward_step(Index u);
  void posterior_row(Index s, DecodedFrames& out, Index row) const;
  Index ring(Index t) const { return t % (lag_ + 1); }

  Transitions tr_;
  VectorXd log_start_;
  std::vector<double> in_lp_;   ///< log probabilities of the arcs grouped by destination
  std::vector<double> out_lp_;  ///< log probabilities of the arcs grouped by source
  Index lag_ = 0, pushed_ = 0, emitted_ = 0;
  double loglik_ = 0;
  VectorXd delta_, next_;                 ///< Viterbi scores of the last frame
  RowMatrixXd log_alpha_;                 ///< ring of normalised log forward vectors (L+1 by N)
  RowMatrixXd log_b_;                     ///< ring of log densities (L+1 by N)
  Eigen::Matrix<std::int32_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> back_;  ///< ring
  VectorXd beta_, beta_next_, scratch_;
};

}  // namespace voicepuppet
