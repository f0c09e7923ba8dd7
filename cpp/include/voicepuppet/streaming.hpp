#pragma once
/// @file streaming.hpp
/// Live voice puppetry with a bounded latency: fixed-lag decoding of an HMM over per-frame log
/// densities (fixed-lag Viterbi and fixed-lag smoothed posteriors), and `StreamingPuppet`,
/// which drives a `Puppet` (puppet.hpp) from audio feature frames as they arrive.
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
#include "voicepuppet/puppet.hpp"
#include "voicepuppet/trajectory.hpp"
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

/// Options of a StreamingPuppet.
struct StreamingOptions {
  /// look-ahead of the audio deltas (frames at the puppet's rate, 0 .. the puppet's delta
  /// width; −1: what exactness needs, the full width, as offline, or 0 for a projected puppet
  /// whose projection reads the features alone, not their deltas): missing future frames
  /// repeat the latest one, as the offline deltas do at the end of a recording
  Index delta_lag = -1;
  /// look-ahead of a projected puppet's vocal features (Puppet::projected(): v_t reads the
  /// standardised frames t − k .. t + k), frames at the puppet's rate, 0 .. k; −1: the full
  /// context k, as offline. Missing future frames repeat the newest standardised one, as the
  /// offline projection repeats the last frame at the end of a recording. A puppet without a
  /// projection has k = 0.
  Index projection_lag = -1;
  /// look-ahead of a guided puppet's guide (Puppet::guided(): ŷ_t reads the standardised frames
  /// t − k_g .. t + k_g), frames at the puppet's rate, 0 .. k_g; −1: the full context k_g, as
  /// offline. Missing future frames repeat the newest standardised one (as projection_lag). An
  /// unguided stream (no guide, or guide_weight 0) resolves it to 0.
  Index guide_lag = -1;
  /// λ of the guide's evidence: negative or NaN: the file's guide/weight; 0: Brand's unguided
  /// stream; positive: needs a guided puppet. Resolved to the λ used.
  double guide_weight = -1;
  Index decode_lag = 2;      ///< look-ahead of the state decoder, frames at the puppet's rate
  Index trajectory_lag = 2;  ///< look-ahead of the trajectory solve, frames at the output rate
  double fps = 0;            ///< output frame rate; 0: the puppet's own rate
  bool posterior = false;    ///< posterior-weighted synthesis instead of the fixed-lag path
};

/// Face frames emitted by a push or a flush.
struct StreamedFrames {
  Index first_frame = 0;  ///< output index of the first row
  RowMatrixXd points;     ///< #M by 2P pixel landmarks (x0, y0, x1, y1, ...) at the mean pose
  RowMatrixXd face;       ///< #M by K face coordinates (parts side by side)
  /// #J by #V vocal features (Puppet::n_vocal) of the input frames whose features this call
  /// completed: a projected puppet's projection, else the standardised [features, deltas]
  RowMatrixXd vocal;
  Index first_vocal = 0;  ///< input index of the first row of `vocal`
  Index size() const { return points.rows(); }
};

/// The voice puppet on a stream: raw audio feature frames in (at the puppet's rate, in the
/// puppet's feature columns), face frames out, state carried between calls.
///
/// Audio deltas (a puppet with delta width w > 0) of frame s use frames s − w .. s + delta_lag,
/// the latest repeated for the missing ones. A projected puppet's vocal features of frame t
/// (Puppet::project: [z_{t−k}, …, z_{t+k}] · P + c over the standardised frames z, edges
/// repeated) are computed once z_{t + projection_lag} is known, the newest standardised frame
/// repeated for the later ones; without a projection the vocal features are z. A guided
/// puppet's prediction ŷ_t (Puppet::guide_predict, from the same ring of standardised frames
/// and the same context code) is computed once z_{t + guide_lag} is known, likewise, and
/// interpolated to the output rate as Puppet::animate does (linearly, at the resample_weights
/// positions). Then per face part: vocal log densities → FixedLagDecoder (frame t decided after
/// t + decode_lag) → states (or posteriors) resampled to the output rate as they are decided
/// (sample and hold, or linear interpolation, exactly as resample_states / resample_weights) →
/// FixedLagTrajectory (output frame k enters once its state and its ŷ_k are known, with the
/// evidence precision λ R[sl, sl]⁻¹ = λ Puppet::guide_precision(p), and is emitted after
/// k + trajectory_lag) → face coordinates → Puppet::to_points. Work per frame is
/// O((2k + 1) · C · V + (2k_g + 1) · C_g · K + decode_lag · arcs + D³ + trajectory_lag · D²)
/// (C projected columns, V vocal dimensions, C_g guide columns), independent of the stream's
/// length. With lags covering the whole stream (or for the frames still held back at `flush`)
/// the output equals Puppet::animate.
///
/// Latency (seconds of audio after a frame's time before it is emitted):
/// (delta_lag + max(projection_lag + decode_lag, guide_lag)) / puppet fps + trajectory_lag /
/// output fps (guide_lag 0 for an unguided stream; + the feature window's look-ahead, which
/// is the front end's): the guide's look-ahead overlaps the decoder's. At an output rate other
/// than the puppet's, an output frame between two input frames also waits for the later one's
/// posterior or ŷ (the interpolation's), up to one input frame more.
class StreamingPuppet {
 public:
  /// @param[in] puppet   copied: the stream does not depend on the caller's object
  /// @param[in] options  lags (≥ 0), output rate (≥ 0), synthesis mode
  /// @throws std::invalid_argument for a negative lag, a delta_lag above the puppet's delta
  ///         width, a projection_lag above its projection context, a guide_lag above its guide
  ///         context, a positive guide_weight for a puppet without a guide, or a bad rate.
  explicit StreamingPuppet(const Puppet& puppet, const StreamingOptions& options = {});

  /// Pushes raw (unstandardised) audio feature frames at the puppet's rate.
  /// @param[in] raw_features  #K by #A (A = puppet.n_features()), K ≥ 0, finite
  /// @return the face frames completed by these frames (possibly none)
  /// @throws std::invalid_argument on a wrong column count or non-finite values.
  StreamedFrames push(const MatrixRef& raw_features);

  /// Ends the stream: emits every frame still held back (from the whole stream, as offline),
  /// then resets for a new stream. Output length: that of Puppet::animate on the frames pushed.
  StreamedFrames flush();

  /// Forgets the stream.
  void reset();

  const Puppet& puppet() const { return puppet_; }
  const StreamingOptions& options() const { return options_; }
  double output_fps() const { return out_fps_; }
  Index frames_pushed() const { return pushed_; }
  Index frames_emitted() const { return emitted_; }
  /// Algorithmic latency in seconds: (delta_lag + max(projection_lag + decode_lag, guide_lag)) /
  /// fps + trajectory_lag / output fps.
  double latency_seconds() const;
  /// log p(features so far) under each part's vocal HMM, summed over parts.
  double log_likelihood() const;

 private:
  /// Vocal Gaussians of one part with their Cholesky factors computed once (the per-call
  /// factorisation of gaussian_log_density would cost O(N·A³) per pushed frame).
  struct VocalModel {
    bool diagonal = false;
    RowMatrixXd means;                   ///< #N by #A'
    RowMatrixXd inv_var;                 ///< diagonal: #N by #A' 1 / σ²
    std::vector<Eigen::MatrixXd> chol;   ///< full: lower Cholesky factor per state
    VectorXd constant;                   ///< −½ (A' log 2π + log |Σ_n|)
    RowMatrixXd log_density(const RowMatrixXd& z) const;  ///< #T by #N
  };
  struct PartStream {
    VocalModel vocal;
    FixedLagDecoder decoder;
    FixedLagTrajectory trajectory;
    std::vector<Index> states;           ///< decided input frames not yet fully resampled
    std::vector<VectorXd> weights;       ///< likewise, posterior mode
    Index first = 0;                     ///< input index of states[0] / weights[0]
    Index decided = 0;                   ///< input frames decided so far
    Index next_out = 0;                  ///< next output frame to resample
    std::vector<Index> pending_states;   ///< resampled output frames waiting for their ŷ
    std::vector<VectorXd> pending_weights;
    Index in_trajectory = 0;             ///< output frames pushed into the trajectory
    Index col = 0;                       ///< the part's first face column
  };
  RowMatrixXd feed(PartStream& ps, const DecodedFrames& f, bool final_pass);
  /// Pushes a part's pending output frames whose ŷ is known (all of them unguided).
  RowMatrixXd push_ready(PartStream& ps);
  /// The guide's ŷ of the frames whose context is now known (all of them at the end), and its
  /// resampling to the output rate.
  void guide_ready(bool final_pass);
  /// Forgets standardised frames of the ring no later projection or ŷ needs.
  void trim_ring();
  /// Standardised frames z in: the ring, the vocal features, the guide, the decoders.
  StreamedFrames advance(const RowMatrixXd& z, bool final_pass);
  StreamedFrames assemble(std::vector<RowMatrixXd>& faces);
  /// Standardised [features, deltas] of the frames whose deltas are now known (all of them at
  /// the end of the stream).
  RowMatrixXd standardized_ready(bool final_pass);
  /// A projected puppet's vocal features of the frames whose projection context is now known
  /// (all of them at the end), the newly standardised frames z already in the ring; z itself
  /// without a projection.
  RowMatrixXd vocal_ready(const RowMatrixXd& z, bool final_pass);
  /// Decodes the vocal features v of the next input frames; the result carries them.
  StreamedFrames decode(RowMatrixXd v, bool final_pass);

  Puppet puppet_;
  StreamingOptions options_;
  double out_fps_ = 0;
  std::vector<PartStream> parts_;
  Index delta_lag_ = 0;
  std::vector<VectorXd> raw_;  ///< raw frames raw_first_ .. pushed_ − 1 still needed for deltas
  Index raw_first_ = 0, standardized_ = 0;
  VectorXd mean_, std_;
  // The projection (Puppet::projection): v_t = [z_{t−k}, …, z_{t+k}] (first C columns) · P + c.
  Index projection_lag_ = 0;
  /// first max(C, C_g) standardised columns of frames z_first_ .. standardized_ − 1 (the ring
  /// the projection and the guide share; empty for a puppet with neither)
  std::vector<VectorXd> z_;
  Index ring_columns_ = 0;
  Index z_first_ = 0, projected_ = 0;
  // The guide (a guided puppet streamed with λ > 0): ŷ_t = [z_{t−k_g}, …, z_{t+k_g}] · G + g.
  bool guide_on_ = false;
  Index guide_lag_ = 0;
  Index guided_ = 0;                   ///< input frames whose ŷ is computed
  std::vector<VectorXd> yhat_;         ///< ŷ of input frames yhat_first_ .. guided_ − 1
  Index yhat_first_ = 0;
  std::vector<VectorXd> yout_;         ///< ŷ at the output rate, frames yout_first_ .. yout_next_ − 1
  Index yout_first_ = 0, yout_next_ = 0;
  Index vocal_ = 0;               ///< input frames whose vocal features are computed
  Index pushed_ = 0, emitted_ = 0;
};

}  // namespace voicepuppet
