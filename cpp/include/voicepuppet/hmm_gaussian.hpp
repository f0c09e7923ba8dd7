#pragma once
/// @file hmm_gaussian.hpp
/// Gaussian emissions for HMMs (full or diagonal covariance) computed through Cholesky
/// factors, their sufficient statistics, the maximum-likelihood (Baum-Welch) M-step,
/// k-means++ initialisation and sampling.
///
/// Covariances cross the API as one 2-D array: full: #N·#D by #D (state n's matrix is rows
/// n·D .. n·D+D-1, i.e. a C-contiguous [N, D, D] numpy array reshaped); diagonal: #N by #D.

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/types.hpp"

#include <cstdint>

namespace voicepuppet {

enum class CovarianceType { Full, Diagonal };

/// Parses "full" or "diag" (throws std::invalid_argument otherwise).
CovarianceType parse_covariance_type(const std::string& name);

/// Checks that `covars` has the shape of `type` for N states and D dims, is finite, symmetric
/// (full) and positive definite; throws std::invalid_argument naming `covars` and the state.
void check_covariances(const MatrixRef& covars, Index n_states, Index n_dims, CovarianceType type);

/// log N(x_t; μ_n, Σ_n) for all frames and states.
/// @param[in] X       #T by #D observations
/// @param[in] means   #N by #D
/// @param[in] covars  full: #N·#D by #D; diag: #N by #D
/// @return #T by #N log densities
/// @throws std::invalid_argument on shape mismatch, non-finite values or a covariance that is
///         not positive definite.
RowMatrixXd gaussian_log_density(const MatrixRef& X, const MatrixRef& means, const MatrixRef& covars,
                                 CovarianceType type);

/// Float32 estimates of full-covariance log densities with a rigorous bound on their error.
struct ScreenedLogDensity {
  RowMatrixXd log_b;  ///< #T by #N float32-evaluated log N(x_t; μ_n, Σ_n)
  RowMatrixXd bound;  ///< #T by #N bound on |log_b − exact| (+inf where float32 overflowed)
};

/// The screening step alone (full covariance): the log densities in float32 and their error
/// bounds (see gaussian_hmm_score). For tests and diagnostics.
ScreenedLogDensity gaussian_log_density_screened(const MatrixRef& X, const MatrixRef& means,
                                                 const MatrixRef& covars);

/// What the screened evaluation did: how many of the T·N log densities were evaluated in
/// double, in how many lattice rounds, and whether it fell back to all-double.
struct ScreeningInfo {
  Index entries = 0;
  Index refined = 0;
  Index rounds = 0;
  bool all_double = false;
};

/// log p(X) of a Gaussian HMM, summed over sequences.
///
/// With full covariances and `exact = false`, the log densities are first evaluated in float32
/// with a per-entry error bound, then in double only where they can matter: entries within 50
/// nats of their frame's best, refined further until raising and lowering every remaining float32
/// entry by its bound moves log p(X) by at most 1e-13 relative (log p(X) is increasing in every
/// log density, so this brackets the all-double value; the midpoint is returned). It falls back
/// to all-double when most entries need it. `exact = true` (or diagonal covariances) evaluates
/// every density in double.
/// @param[in] X        #T by #D observations of all sequences
/// @param[in] lengths  #S sequence lengths (empty: one sequence)
/// @param[out] info    optional: what the screening did
double gaussian_hmm_score(const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob,
                          const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars,
                          CovarianceType type, bool exact = false, ScreeningInfo* info = nullptr);

/// Viterbi decoding of a Gaussian HMM. Screened as gaussian_hmm_score: Viterbi runs on the
/// upper bounds of the unrefined entries, and the path is accepted once it visits only entries
/// evaluated in double (no other path can then beat it); otherwise its unrefined entries and
/// their rivals are refined and Viterbi reruns.
ViterbiResult gaussian_hmm_decode(const MatrixRef& X, const IndexVectorRef& lengths, const VectorRef& startprob,
                                  const MatrixRef& transmat, const MatrixRef& means, const MatrixRef& covars,
                                  CovarianceType type, bool exact = false, ScreeningInfo* info = nullptr);

/// Forward-backward of a Gaussian HMM. Screened: forward-backward reruns until every entry left
/// in float32 has γ·e^{2Δ} ≤ 1e-13 (Δ its bound), so log p(X) errs from the all-double value by
/// at most Σ γΔ ≤ 2e-14 per such entry (to first order; d log p / d log b_tn = γ_tn).
ForwardBackwardResult gaussian_hmm_posteriors(const MatrixRef& X, const IndexVectorRef& lengths,
                                              const VectorRef& startprob, const MatrixRef& transmat,
                                              const MatrixRef& means, const MatrixRef& covars, CovarianceType type,
                                              bool exact = false, ScreeningInfo* info = nullptr);

/// Posterior-weighted sufficient statistics of Gaussian emissions. Moments are taken about
/// `shift` (a fixed vector, e.g. the data mean) so that large offsets do not cancel.
/// Statistics of disjoint data add: merge them with `+=`.
struct GaussianStats {
  VectorXd shift;   ///< #D
  VectorXd weight;  ///< #N Σ_t γ_tn
  RowMatrixXd sum;  ///< #N by #D Σ_t γ_tn (x_t − shift)
  RowMatrixXd outer;  ///< full: #N·#D by #D Σ_t γ_tn (x_t−shift)(x_t−shift)ᵀ; diag: #N by #D squares
  CovarianceType type = CovarianceType::Full;
  GaussianStats& operator+=(const GaussianStats& other);
};

/// Accumulates GaussianStats of X under posteriors γ (#T by #N). Full covariance: a frame
/// whose γ_tn·(1 + ‖x_t − shift‖²) is below 1e-13/T of the state's total is left out of the
/// state's outer products (it changes them by at most 1e-13 of weight + trace).
GaussianStats gaussian_stats(const MatrixRef& X, const MatrixRef& posteriors, const VectorRef& shift,
                             CovarianceType type);

/// Maximum-likelihood means and covariances from statistics; `variance_floor` (absolute) is
/// added to every covariance diagonal. A state with weight below 1e-10 keeps `old_means` /
/// `old_covars` (pass empty matrices to get the global moments instead).
struct GaussianParams {
  RowMatrixXd means;
  RowMatrixXd covars;
};
GaussianParams gaussian_mstep(const GaussianStats& stats, double variance_floor,
                              const MatrixRef& old_means, const MatrixRef& old_covars);

/// Everything the E-step of one EM iteration yields: forward-backward counts and Gaussian
/// statistics. Additive over disjoint sets of sequences.
struct EStepResult {
  double log_likelihood = 0;
  RowMatrixXd expected_transitions;  ///< #N by #N
  VectorXd expected_starts;          ///< #N
  GaussianStats stats;
  EStepResult& operator+=(const EStepResult& other);
};

/// The E-step: log densities, forward-backward (gaussian_hmm_posteriors, screened unless
/// `exact`) and statistics, in one call.
EStepResult gaussian_hmm_estep(const MatrixRef& X, const IndexVectorRef& lengths,
                               const VectorRef& startprob, const MatrixRef& transmat,
                               const MatrixRef& means, const MatrixRef& covars,
                               CovarianceType type, const VectorRef& shift, bool exact = false,
                               ScreeningInfo* info = nullptr);

/// Maximum-likelihood re-estimate of a row-stochastic matrix (or a start vector, as one row)
/// from expected counts; rows with no evidence are kept from `old`.
RowMatrixXd normalize_counts(const MatrixRef& counts, const MatrixRef& old);

/// Deterministic k-means++ seeding followed by `n_iter` Lloyd iterations.
/// @return #K by #D centres
RowMatrixXd kmeans(const MatrixRef& X, Index k, std::uint64_t seed, Index n_iter);

/// Samples T frames from a Gaussian HMM (first state from startprob). Deterministic per seed.
struct SampleResult {
  RowMatrixXd X;    ///< #T by #D
  VectorXi states;  ///< #T
};
SampleResult gaussian_hmm_sample(const VectorRef& startprob, const MatrixRef& transmat,
                                 const MatrixRef& means, const MatrixRef& covars, CovarianceType type,
                                 Index n_frames, std::uint64_t seed);

}  // namespace voicepuppet
