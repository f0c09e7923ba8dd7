#pragma once
/// @file dpds.hpp
/// Phoneme-driven linear dynamical models of Englebienne, Cootes & Rattray (NIPS 2007):
/// the Deterministic Process Dynamical System (DPDS) and the labelled SLDS with B = I.
///
/// Data: S sequences stacked row-wise in Y (#N by #D, N = ΣT_s), with `offsets` (#S+1,
/// offsets[0] = 0, offsets[S] = N, strictly increasing) and one phone label per frame in
/// `labels` (#N, values in 0..#P−1).
///
/// DPDS (§3, eq. 1, appendix A): per phone p a diagonal transition a_p (#D), a start mean μ_p and
/// a bias ν_p; the hidden path is deterministic given the labels,
///   x_1 = μ_{s_1},   x_t = a_{s_t} ∘ x_{t−1} + ν_{s_t}   (t ≥ 2),
/// and y_t = x_t + v_t, v_t ~ N(0, diag(r)) with one output variance r (#D) shared by all
/// phones and frames. Parameters cross the API as #P by #D matrices (row p = phone p).
/// For fixed a the path is linear in θ_j = [μ_{·j}; ν_{·j}] (2P entries) separately for every
/// dimension j, so μ, ν maximise the likelihood by D independent least-squares problems
/// (the paper's Algorithm 1; we form the 2P×2P normal equations per dimension by propagating
/// the coefficient vector c_t = a_{s_t j} c_{t−1} + e_{ν,s_t} along each sequence, touching only
/// the phones that occurred in it). The gradient of eq. 1 in a is computed by the adjoint
/// (reverse) recursion λ_T = g_T, λ_t = g_t + a_{s_{t+1}} ∘ λ_{t+1}, g_t = (y_t − x_t)/r:
/// ∂L/∂a_p = Σ_{t≥2, s_t=p} λ_t ∘ x_{t−1}, which equals the forward chain rule of appendix A
/// (eq. 2) in O(N·D) instead of O(N·D·P).
///
/// SLDS (B = I, labels known): x_1 ~ N(μ_{s_1}, diag(σ²_{s_1})), x_t = a_{s_t} ∘ x_{t−1} + ν_{s_t}
/// + w_t, w_t ~ N(0, diag(q_{s_t})), y_t = x_t + v_t, v_t ~ N(0, diag(r_{s_t})). With diagonal
/// parameters every dimension is an independent scalar LDS; `slds_smooth` runs the Kalman filter
/// and Rauch–Tung–Striebel smoother for all of them and returns the E-step statistics.

#include "voicepuppet/types.hpp"

#include <Eigen/Core>

namespace voicepuppet {

/// Checks the stacked-sequence layout shared by every function here and returns S.
/// @param[in] n_frames  N, rows of Y
/// @param[in] offsets   #S+1 sequence boundaries
/// @param[in] labels    #N phone labels
/// @param[in] n_phones  P
/// @throws std::invalid_argument on a bad layout or a label outside 0..P−1 (naming the frame).
Index check_sequences(Index n_frames, const IndexVectorRef& offsets, const IndexVectorRef& labels,
                      Index n_phones);

/// DPDS mean path (generation, eq. 1): x_1 = μ_{s_1}, x_t = a_{s_t} ∘ x_{t−1} + ν_{s_t}.
/// @param[in] a        #P by #D diagonal transitions
/// @param[in] mu       #P by #D start means
/// @param[in] nu       #P by #D biases
/// @param[in] labels   #T phone labels (T ≥ 1)
/// @param[in] offsets  #S+1 sequence starts (each sequence restarts at μ); empty: one sequence
/// @return #T by #D path
RowMatrixXd dpds_generate(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu,
                          const IndexVectorRef& labels, const IndexVectorRef& offsets);

/// Streaming DPDS generation: O(D) state, O(D) time per frame; frames equal dpds_generate.
class DpdsStream {
 public:
  /// @param[in] a, mu, nu  #P by #D parameters (copied)
  DpdsStream(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu);
  /// Appends frames for `labels` (#T) and returns them (#T by #D).
  RowMatrixXd push(const IndexVectorRef& labels);
  /// Starts a new sequence: the next frame is μ of its phone.
  void reset() { started_ = false; }
  Index frames() const { return frames_; }
  /// The current frame x_t (#D); zeros before the first frame.
  const VectorXd& state() const { return x_; }

 private:
  RowMatrixXd a_, mu_, nu_;
  VectorXd x_;
  bool started_ = false;
  Index frames_ = 0;
};

/// Log-likelihood of eq. 1 and its gradient for fixed parameters.
struct DpdsGradient {
  double log_likelihood = 0;  ///< Σ_t log N(y_t; x_t, diag(r))
  RowMatrixXd grad_a;         ///< #P by #D, ∂L/∂a
  RowMatrixXd grad_mu;        ///< #P by #D, ∂L/∂μ
  RowMatrixXd grad_nu;        ///< #P by #D, ∂L/∂ν
  RowMatrixXd residual;       ///< #N by #D, y − x
};

/// @param[in] a, mu, nu  #P by #D parameters
/// @param[in] r          #D output variances (> 0)
/// @param[in] Y          #N by #D observations
/// @param[in] offsets    #S+1 sequence boundaries
/// @param[in] labels     #N phone labels
/// @throws std::invalid_argument on bad shapes, non-finite values or r ≤ 0.
DpdsGradient dpds_gradient(const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu,
                           const VectorRef& r, const MatrixRef& Y, const IndexVectorRef& offsets,
                           const IndexVectorRef& labels);

/// The exact maximisation over μ, ν and r for fixed a (Algorithm 1).
struct DpdsSolve {
  RowMatrixXd mu;                     ///< #P by #D (rows of phones that never start a sequence: 0)
  RowMatrixXd nu;                     ///< #P by #D (rows of phones never seen at t ≥ 2: 0)
  VectorXd r;                         ///< #D output variances, mean squared residual, ≥ r_floor
  Eigen::Matrix<Index, Eigen::Dynamic, 1> mu_used;  ///< #P, 1 if phone p starts a sequence
  Eigen::Matrix<Index, Eigen::Dynamic, 1> nu_used;  ///< #P, 1 if phone p labels a frame t ≥ 2
  double log_likelihood = 0;          ///< eq. 1 at the solution
};

/// @param[in] a        #P by #D transitions
/// @param[in] Y        #N by #D observations
/// @param[in] offsets  #S+1 sequence boundaries
/// @param[in] labels   #N phone labels
/// @param[in] r_floor  #D variance floors (≥ 0) applied to r
/// The per-dimension normal equations are solved by Cholesky; if a system is singular (e.g.
/// two parameters always appear together) the minimum-norm least-squares solution is taken
/// (complete orthogonal decomposition), as numpy's lstsq would.
DpdsSolve dpds_solve(const MatrixRef& a, const MatrixRef& Y, const IndexVectorRef& offsets,
                     const IndexVectorRef& labels, const VectorRef& r_floor);

/// Kalman smoother output for the labelled diagonal SLDS (all #N by #D unless noted).
struct SldsSmooth {
  double log_likelihood = 0;  ///< log p(Y | labels), by the prediction-error decomposition
  RowMatrixXd mean;           ///< E[x_t | Y]
  RowMatrixXd var;            ///< Var[x_t | Y]
  RowMatrixXd cross;          ///< Cov[x_t, x_{t−1} | Y] (0 at each sequence's first frame)
  RowMatrixXd pred_mean;      ///< E[x_t | y_1..y_{t−1}] (filter prediction)
  RowMatrixXd pred_var;       ///< Var[x_t | y_1..y_{t−1}]
};

/// @param[in] a, nu        #P by #D transitions and biases
/// @param[in] q            #P by #D process variances (> 0)
/// @param[in] r            #P by #D output variances (> 0)
/// @param[in] mu1, var1    #P by #D first-frame mean and variance (> 0)
/// @param[in] Y, offsets, labels  stacked sequences as above
SldsSmooth slds_smooth(const MatrixRef& a, const MatrixRef& nu, const MatrixRef& q,
                       const MatrixRef& r, const MatrixRef& mu1, const MatrixRef& var1,
                       const MatrixRef& Y, const IndexVectorRef& offsets,
                       const IndexVectorRef& labels);

}  // namespace voicepuppet
