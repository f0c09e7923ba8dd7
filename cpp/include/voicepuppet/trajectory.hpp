#pragma once
/// @file trajectory.hpp
/// Closed-form trajectory synthesis (Brand, Voice Puppetry §4.5, eq. 5–6): the most probable
/// trajectory Y (#T by #D) given a state sequence (or per-frame state weights) and per-state
/// Gaussians over [pose, velocity]. This is MLPG (Tokuda 2000) with full pose–velocity covariance.
///
/// Objective (minimised):
///   frame 0:   (y_0 − μ_s)ᵀ (K_s^xx)⁻¹ (y_0 − μ_s)           pose marginal only, no velocity term
///   frame t≥1: õ_tᵀ K_s⁻¹ õ_t,  õ_t = [y_t − μ_s, (y_t − y_{t−1}) − μ̇_s],  s = s(t)
/// With P = K⁻¹ = [[A, B], [Bᵀ, C]] (blocks D×D) frame t ≥ 1 adds to the normal equations
///   H[t,t] += A + B + Bᵀ + C,  H[t−1,t−1] += C,  H[t−1,t] = H[t,t−1]ᵀ = −(Bᵀ + C),
///   r[t]   += (A + Bᵀ) μ + (B + C) μ̇,           r[t−1] −= Bᵀ μ + C μ̇,
/// and frame 0 adds (K^xx)⁻¹ to H[0,0] and (K^xx)⁻¹ μ to r[0]. H is block tridiagonal and
/// positive definite; it is factored by block Cholesky in O(T·D³) time, storing one packed
/// lower-triangular D×D factor per frame (O(T·D²) memory). Diagonal covariances decouple the
/// dimensions: D scalar tridiagonal systems, O(T·D).
///
/// Covariances cross the API like hmm_gaussian.hpp: full: #N·2D by 2D (state n's [pose, velocity]
/// covariance is rows n·2D .. n·2D+2D−1, a C-contiguous [N, 2D, 2D] array reshaped);
/// diagonal: #N by 2D variances (pose variances, then velocity variances).
///
/// Per-frame evidence (optional, TrajectoryEvidence): a Gaussian observation of each frame's
/// pose, targets ŷ_t with one precision W (= λ R⁻¹: the caller folds the weight λ in), adds
///   Σ_t (y_t − ŷ_t)ᵀ W (y_t − ŷ_t)
/// to the objective, i.e. H[t,t] += W and r[t] += W ŷ_t for every frame t (not γ-weighted in
/// the posterior-weighted solve: one term per frame). H stays block tridiagonal; the term is
/// added where frame t's diagonal block and right-hand side are formed, so the solve costs D²
/// more per frame (plus the T×D by D×D product W ŷ). A diagonal-covariance model with a
/// non-diagonal W is expanded to full blocks and solved as a full model (O(T·D³)); with a
/// diagonal W it stays D scalar systems. W = 0 gives the unguided solve exactly.
///
/// Other frame rates: a model trained at rate f_model and synthesised at f_out uses the
/// velocity scale r = f_model / f_out: μ̇ → r·μ̇, K^xv → r·K^xv, K^vv → r²·K^vv (the exact
/// change of variables from training-frame to output-frame differences).

#include "voicepuppet/hmm_gaussian.hpp"
#include "voicepuppet/types.hpp"

#include <Eigen/Core>

#include <vector>

namespace voicepuppet {

/// The per-state blocks of the trajectory normal equations, computed once per model from
/// the Cholesky factor of each state's [pose, velocity] covariance (no explicit inverses of
/// the system; each precision is L⁻ᵀL⁻¹ from the state's own factor).
class TrajectoryModel {
 public:
  /// @param[in] means           #N by #D pose means μ
  /// @param[in] vel_means       #N by #D velocity means μ̇ (per training frame)
  /// @param[in] covars          full: #N·2D by 2D; diagonal: #N by 2D (see file comment)
  /// @param[in] type            CovarianceType::Full or CovarianceType::Diagonal
  /// @param[in] velocity_scale  r = f_model / f_out (> 0); 1 synthesises at the training rate
  /// @throws std::invalid_argument naming the argument on empty or mismatched shapes, non-finite
  ///         values, a non-symmetric covariance, or one that is not (numerically) positive
  ///         definite (condition estimate above 1e12).
  TrajectoryModel(const MatrixRef& means, const MatrixRef& vel_means, const MatrixRef& covars,
                  CovarianceType type, double velocity_scale = 1.0);

  Index n_states() const { return n_states_; }
  Index n_dims() const { return n_dims_; }
  CovarianceType covariance_type() const { return type_; }
  double velocity_scale() const { return velocity_scale_; }

  // Normal-equation blocks (documented in the file comment), state n:
  // full: D×D column-major matrices; diagonal: row n of #N by #D arrays.
  struct FullBlocks {
    Eigen::MatrixXd self;   ///< A + B + Bᵀ + C, frames t ≥ 1
    Eigen::MatrixXd first;  ///< (K^xx)⁻¹, frame 0
    Eigen::MatrixXd next;   ///< C, added to the previous frame's diagonal block
    Eigen::MatrixXd up;     ///< −(Bᵀ + C) = H[t−1, t]
    Eigen::MatrixXd up_t;   ///< upᵀ = H[t, t−1] (stored for the solve's column-major panels)
    VectorXd r_self;        ///< (A + Bᵀ) μ + (B + C) μ̇
    VectorXd r_first;       ///< (K^xx)⁻¹ μ
    VectorXd r_next;        ///< −(Bᵀ μ + C μ̇), added to the previous frame's right-hand side
  };
  const std::vector<FullBlocks>& full_blocks() const { return full_; }
  struct DiagBlocks {
    RowMatrixXd self, first, next, up, r_self, r_first, r_next;  ///< each #N by #D
  };
  const DiagBlocks& diag_blocks() const { return diag_; }

 private:
  Index n_states_ = 0, n_dims_ = 0;
  CovarianceType type_ = CovarianceType::Full;
  double velocity_scale_ = 1.0;
  std::vector<FullBlocks> full_;
  DiagBlocks diag_;
};

/// Per-frame Gaussian evidence on the trajectory (see the file comment).
struct TrajectoryEvidence {
  RowMatrixXd targets;       ///< #T by #D targets ŷ_t (one row per output frame)
  Eigen::MatrixXd precision; ///< #D by #D symmetric positive semi-definite W = λ R⁻¹ (0: no evidence)
};

/// Checks evidence for T frames of D dims: the shapes, finite values, a symmetric (to 1e-10
/// relative) positive semi-definite precision (smallest eigenvalue ≥ −1e-12 of the largest
/// magnitude entry; W = 0 is allowed and means no evidence).
/// @throws std::invalid_argument naming `name` and what is wrong.
void check_trajectory_evidence(const TrajectoryEvidence& evidence, Index n_frames, Index n_dims,
                               const char* name = "evidence");

/// Largest condition estimate (ratio of the largest to the smallest squared Cholesky pivot, a
/// lower bound of cond(H)) accepted before a solve throws std::runtime_error.
constexpr double kTrajectoryMaxCondition = 1e12;

/// Most probable trajectory for a hard state sequence.
/// Memory: full covariance stores one packed factor per frame (T·D(D+1)/2 doubles, padded to
/// 64 bytes per frame); each thread keeps the store of its last full solve, up to 256 MB, for
/// its next one (the pages of a fresh store are the solve's largest fixed cost), and frees it
/// when the thread ends. Larger stores are freed after the call.
/// @param[in] model   per-state blocks
/// @param[in] states  #T state indices in [0, N)
/// @param[in] evidence  optional per-frame evidence (targets #T by #D, precision #D by #D);
///                      nullptr: Brand's solve, unchanged
/// @return #T by #D trajectory
/// @throws std::invalid_argument on an empty sequence, an index out of range or bad evidence
///         (check_trajectory_evidence);
///         std::runtime_error when the system is numerically singular (message gives the
///         condition estimate).
RowMatrixXd solve_trajectory(const TrajectoryModel& model, const IndexVectorRef& states,
                             const TrajectoryEvidence* evidence = nullptr);

/// Posterior-weighted trajectory: minimises Σ_t Σ_n γ_tn · (frame t's cost under state n), i.e.
/// the precision blocks and precision-weighted means are γ-weighted sums over states. Memory as
/// solve_trajectory.
/// @param[in] weights  #T by #N non-negative state weights (e.g. forward–backward posteriors);
///                     every row must have a positive sum (rows need not be normalised)
/// @param[in] evidence  optional per-frame evidence as in solve_trajectory (not γ-weighted)
/// @return #T by #D trajectory; one-hot weights give exactly the hard solve.
/// @throws std::invalid_argument on a wrong shape, negative or non-finite weights, a zero row,
///         bad evidence;
///         std::runtime_error when the system is numerically singular.
RowMatrixXd solve_trajectory_weighted(const TrajectoryModel& model, const MatrixRef& weights,
                                      const TrajectoryEvidence* evidence = nullptr);

/// The number of frames resample_states and resample_weights give for #n frames at fps_in:
/// ceil(n · fps_out / fps_in) (at least 1), tolerant to the rounding of an exact ratio.
Index resampled_length(Index n, double fps_in, double fps_out);

/// Resamples a state sequence from rate fps_in to fps_out by sample and hold: output frame k
/// (time k / fps_out) takes the state of input frame floor(k · fps_in / fps_out), and there are
/// ceil(T · fps_out / fps_in) output frames (every output time inside the input's duration).
VectorXi resample_states(const IndexVectorRef& states, double fps_in, double fps_out);

/// Resamples per-frame state weights (#T by #N) to fps_out by linear interpolation at input
/// position u = k · fps_in / fps_out (clamped to T − 1); row sums are preserved.
RowMatrixXd resample_weights(const MatrixRef& weights, double fps_in, double fps_out);

/// Fixed-lag streaming synthesis: frame t is emitted once frame t + lag has been pushed, as the
/// value at t of the exact solution of the system truncated to frames 0 .. t + lag. State is
/// carried between calls (a ring of lag + 2 factors), so each push costs O(D³ + lag·D²) and
/// memory is O((lag + 1)·D²). `flush` ends the stream: the remaining frames come from the full
/// solve (so with lag ≥ T − 1 the output equals solve_trajectory exactly), and the object is
/// ready for a new stream.
///
/// With evidence (the constructor taking a precision W, as TrajectoryEvidence::precision, the
/// same for every frame): each frame is pushed with its target ŷ_t, which adds W to its diagonal
/// block and W ŷ_t to its right-hand side; frame t emitted is then the value at t of the exact
/// solution of the guided system truncated to 0 .. t + lag, `flush` gives the batch guided solve
/// (solve_trajectory(_weighted) with the evidence {targets, W}). W = 0 is the unguided stream.
class FixedLagTrajectory {
 public:
  /// @param[in] model  copied; the stream is independent of the caller's object afterwards
  /// @param[in] lag    frames of look-ahead L ≥ 0
  FixedLagTrajectory(const TrajectoryModel& model, Index lag);
  /// A stream with per-frame evidence of precision W (#D by #D, symmetric PSD, λ folded in).
  /// @throws std::invalid_argument on a bad W (check_trajectory_evidence) or a negative lag.
  FixedLagTrajectory(const TrajectoryModel& model, Index lag, const Eigen::MatrixXd& precision);

  /// Pushes hard states; returns the frames emitted by these pushes (#K by #D, K may be 0).
  /// @throws std::invalid_argument on a state out of range, or on a stream with evidence
  ///         (which needs the targets overload).
  RowMatrixXd push_states(const IndexVectorRef& states);
  /// Pushes per-frame weights (#K by #N, rows as in solve_trajectory_weighted).
  RowMatrixXd push_weights(const MatrixRef& weights);
  /// The same with the frames' evidence targets ŷ (#K by #D, finite), for a stream constructed
  /// with a precision (a stream without evidence refuses them).
  RowMatrixXd push_states(const IndexVectorRef& states, const MatrixRef& targets);
  RowMatrixXd push_weights(const MatrixRef& weights, const MatrixRef& targets);
  /// Emits the frames still held back and resets the stream.
  RowMatrixXd flush();

  Index lag() const { return lag_; }
  /// Whether frames carry evidence (constructed with a precision).
  bool has_evidence() const { return evidence_; }
  /// W (#D by #D, symmetrised; empty without evidence).
  const Eigen::MatrixXd& precision() const { return w_; }
  Index frames_pushed() const { return pushed_; }
  Index frames_emitted() const { return emitted_; }
  const TrajectoryModel& model() const { return model_; }

 private:
  struct Slot {  ///< one frame of the ring (index t mod (lag + 2))
    Eigen::MatrixXd qpart;  ///< diagonal block after the Schur update, without the next frame's term
    VectorXd gpart;         ///< right-hand side likewise
    Eigen::MatrixXd lc;     ///< Cholesky factor of the complete diagonal block (once finalised)
    VectorXd z;             ///< forward-substituted right-hand side (once finalised)
    Eigen::MatrixXd up;     ///< H[t−1, t]
  };
  void push_frame(const double* weights, Index state, const double* target, std::vector<VectorXd>& out);
  void check_targets(const MatrixRef& targets, Index rows) const;
  RowMatrixXd push_states_checked(const IndexVectorRef& states, const MatrixRef* targets);
  RowMatrixXd push_weights_checked(const MatrixRef& weights, const MatrixRef* targets);
  void emit_back_to(Index first, bool whole, std::vector<VectorXd>& out);
  Slot& slot(Index t);

  TrajectoryModel model_;
  std::vector<TrajectoryModel::FullBlocks> blocks_;  ///< full blocks (diagonal models expanded)
  Eigen::MatrixXd dg_, next_, up_;                     ///< scratch for the weighted terms
  VectorXd rh_, rnext_;
  bool evidence_ = false;
  Eigen::MatrixXd w_;  ///< evidence precision W (evidence_ only)
  Index lag_ = 0;
  Index pushed_ = 0, emitted_ = 0;
  std::vector<Slot> ring_;
};

}  // namespace voicepuppet
