#pragma once
/// @file adapt.hpp
/// Unsupervised test-time adaptation of feature frames to a Gaussian HMM (fMLLR-style;
/// Leggetter & Woodland 1995, Gales 1998): the affine transform z' = A z + b of an input's
/// (standardised) features under which the HMM explains them best, found by EM with the HMM's
/// own state posteriors and no transcript.
///
/// Objective (penalised log-likelihood, W = [b, A] of #D by #D+1):
///   L(W) = log p(A z + b | HMM) + T log|det A|                        (the input's likelihood)
///        + τ Σ_i π_i E_{x ~ N(μ_i, Σ_i)} [log N(A x + b; μ_i, Σ_i)] + τ log|det A|   (prior)
/// The prior is τ frames of the model's own voice, the states weighted by the input's
/// occupancies π_i before adaptation (fixed over the iterations); its maximum alone is the
/// identity, so a short input cannot overfit and τ = ∞ is no adaptation.
/// EM: E-step, posteriors γ_ti by forward-backward on A z + b; M-step, W maximising
/// Σ_ti γ_ti log N(A z_t + b; μ_i, Σ_i) + T log|det A| + prior. With full covariances the M-step
/// is done row by row (each row of W maximised exactly given the others: a quadratic in the
/// row plus β log|c·w| with c the row's cofactors, Gales' two roots), `sweeps` times; each row
/// update raises the auxiliary function, so L never decreases over iterations.
///
/// Full A and b (a bias alone, or a scale per column and b, were measured and lost:
/// docs/results.md). Precisions through Cholesky factors; deterministic.

#include "voicepuppet/hmm_gaussian.hpp"
#include "voicepuppet/types.hpp"

#include <string>
#include <vector>

namespace voicepuppet {

enum class AdaptKind { None, Full };

/// Parses "none" or "full" (throws std::invalid_argument naming the choices).
AdaptKind parse_adapt_kind(const std::string& name);

struct AdaptOptions {
  AdaptKind kind = AdaptKind::None;
  double tau = 30;    ///< prior evidence in frames (> 0; +inf: the identity, no adaptation)
  Index n_iter = 1;   ///< EM iterations (>= 1)
  Index sweeps = 3;   ///< row sweeps per M-step
};

/// Throws std::invalid_argument naming the bad option.
void check_adapt_options(const AdaptOptions& options);

/// An affine feature transform z' = A z + b and how it was found.
struct FeatureTransform {
  RowMatrixXd A;                        ///< #D by #D
  VectorXd b;                           ///< #D
  std::vector<double> log_likelihood;   ///< L(W) before each M-step and after the last (n_iter + 1)
  /// z' = A z + b, frames in rows.
  RowMatrixXd apply(const MatrixRef& z) const;
  /// T log|det A|: what the transform adds to a log-likelihood of T transformed frames.
  double log_jacobian(Index n_frames) const;
};

/// Adapt features `z` (#T by #D, one or more sequences by `lengths`, empty: one) to the
/// Gaussian HMM (means #N by #D, covars full #N·D by D or diagonal #N by D, startprob,
/// transmat). AdaptKind::None or τ = ∞ returns the identity (log_likelihood empty).
/// @throws std::invalid_argument on bad shapes, values or options.
FeatureTransform adapt_features(const MatrixRef& z, const IndexVectorRef& lengths,
                                const MatrixRef& means, const MatrixRef& covars,
                                CovarianceType type, const VectorRef& startprob,
                                const MatrixRef& transmat, const AdaptOptions& options);

}  // namespace voicepuppet
