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

/// Accumulates GaussianStats of X under posteriors γ (#T by #N).
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

/// The E-step: log densities, forward-backward and statistics, in one call.
EStepResult gaussian_hmm_estep(const MatrixRef& X, const IndexVectorRef& lengths,
                               const VectorRef& startprob, const MatrixRef& transmat,
                               const MatrixRef& means, const MatrixRef& covars,
                               CovarianceType type, const VectorRef& shift);

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
