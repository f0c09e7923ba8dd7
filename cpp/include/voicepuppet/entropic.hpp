#pragma once
/// @file entropic.hpp
/// Entropic estimation (Brand, Neural Computation 1999; Voice Puppetry §4.2): maximum a
/// posteriori estimates under the entropic prior P(θ) ∝ exp(−Z·H(θ)), parameter extinction
/// (transition trimming) and the annealing schedule of the weight Z.
///
/// For a multinomial θ with evidence ω (expected counts) the log posterior is
///     F(θ) = Σ_k (ω_k + Z·θ_k) log θ_k      on the simplex Σ_k θ_k = 1,
/// Z = 1 the minimum-entropy prior, Z = 0 maximum likelihood, Z < 0 a maximum-entropy bias (high
/// temperature, for annealing). Its stationary points are θ_k = −(ω_k/Z) / W(−(ω_k/Z)·e^{1+λ/Z}).

#include "voicepuppet/hmm_gaussian.hpp"
#include "voicepuppet/types.hpp"

namespace voicepuppet {

/// Principal branch W₀(x) of the Lambert W function for x = exp(log_x) > 0, computed from log x
/// so that arguments far beyond the double range (log_x up to ~1e300) are fine.
double lambert_w0_log(double log_x);

/// Lower branch W₋₁(x) for x = −exp(log_neg_x) in [−1/e, 0), computed from log(−x) ≤ −1, so
/// that tiny arguments (log_neg_x down to −1e300) keep full relative precision. Throws
/// std::invalid_argument if log_neg_x > −1 (x below the branch point −1/e).
double lambert_wm1_log(double log_neg_x);

/// The entropic log posterior Σ_k (ω_k + Z θ_k) log θ_k of a multinomial (0·log 0 = 0; −inf if
/// some ω_k > 0 has θ_k = 0). @param[in] omega #K evidence, @param[in] theta #K probabilities.
double entropic_objective(const VectorRef& omega, const VectorRef& theta, double z);

/// Entropic MAP estimate of a multinomial: the global maximiser of entropic_objective.
///  - Z = 0: ω / Σω (maximum likelihood, exactly).
///  - Z > 0: zero-evidence entries are extinguished (θ_k = 0); a single entry with evidence
///    gets θ = 1; otherwise all entries but the one with the largest evidence sit on the W₋₁
///    branch and the largest sits on W₋₁ or W₀ (W₀ when Σω is small against Z). The multiplier
///    is found by a safeguarded Newton iteration (bisection fallback) on the normalisation.
///  - Z < 0: every entry (zero evidence included) sits on the W₀ branch.
/// @param[in] omega  #K non-negative finite evidence
/// @param[in] z      finite weight of the prior
/// @return #K probabilities summing to 1
/// @throws std::invalid_argument on empty, negative or non-finite ω, non-finite Z, or an all-zero
///         ω with Z >= 0 (no evidence: the estimate is not unique).
VectorXd entropic_multinomial(const VectorRef& omega, double z);

/// Row-wise entropic_multinomial of a count matrix (transitions: rows are source states). Rows
/// without evidence are kept from `old` (which must then have the same shape).
/// @param[in] counts  #R by #K expected counts ξ
/// @param[in] old     #R by #K previous estimate (rows used where a row of counts is all zero)
RowMatrixXd entropic_rows(const MatrixRef& counts, double z, const MatrixRef& old);

/// Entropic MAP means and covariances from Gaussian statistics, with the variance floor c
/// (`prior`) of Baum–Welch. Maximises, per state,
///   Σ_t γ_tn E_ε log N(x_t + ε; μ_n, K_n) − (Z⁺/2) log|K_n|,   ε ~ N(0, c I),
/// i.e. Σ_t γ_tn log N(x_t; μ_n, K_n) − (c w_n/2) tr K_n⁻¹ − (Z⁺/2) log|K_n|, Z⁺ = max(Z, 0)
/// (the Gaussian part of Brand's entropy H_C; the covariance term is not annealed below 0),
/// giving μ_n = mean, K_n = (S_n + c·w_n·I) / (w_n + Z⁺) with S_n the centred scatter and
/// w_n = Σ_t γ_tn. With Z = 0 this is Baum–Welch's estimate S_n/w_n + c·I (gaussian_mstep)
/// for every c: the floor acts per frame in both, so the two trainers differ only by the prior.
/// States with weight below 1e-10 keep `old_means`/`old_covars`.
/// @throws std::invalid_argument on non-finite Z, a negative prior, or bad old shapes;
///         std::runtime_error if a state's w + Z⁺ is not positive.
GaussianParams entropic_gaussian_mstep(const GaussianStats& stats, double z, double prior,
                                       const MatrixRef& old_means, const MatrixRef& old_covars);

/// The log of the entropic prior of a Gaussian HMM (up to a constant independent of the model):
///   Z Σ_i π_i log π_i + Z Σ_ij θ_ij log θ_ij − Σ_i [Z⁺/2 · log((2πe)^D |K_i|) + prior/2 · tr K_i⁻¹].
/// @param[in] covars  full: #N·#D by #D; diag: #N by #D (positive definite)
double entropic_log_prior(const VectorRef& startprob, const MatrixRef& transmat, const MatrixRef& covars,
                          CovarianceType type, double z, double prior);

/// Each state's share of the negated log prior (its description cost):
///   cost_i = −Z Σ_j θ_ij log θ_ij + Z⁺/2 · log((2πe)^D |K_i|) + prior/2 · tr K_i⁻¹,
/// so that entropic_log_prior = Z Σ_i π_i log π_i − Σ_i cost_i.
/// @return #N costs
VectorXd entropic_state_costs(const MatrixRef& transmat, const MatrixRef& covars, CovarianceType type, double z,
                              double prior);

/// Transition trimming candidates (parameter extinction, Brand 1999): arc i→j is a candidate when
///   θ_ij ≤ exp(−(∂ log L/∂θ_ij)/Z),   ∂ log L/∂θ_ij = ξ_ij / θ_ij,
/// with ξ the expected transition counts of an E-step at exactly these θ. The largest arc of a
/// row is never a candidate (a row must keep an exit). No candidates when Z <= 0.
/// @param[in] transmat   #N by #N current transition matrix (row-stochastic)
/// @param[in] expected   #N by #N expected counts ξ from forward-backward at `transmat`
/// @return #N by #N matrix of 0/1 flags
RowMatrixXd transition_trim_candidates(const MatrixRef& transmat, const MatrixRef& expected, double z);

/// Zeroes the flagged arcs of `transmat` and renormalises each row.
/// @throws std::invalid_argument if a row would be left with no arc.
RowMatrixXd trim_transitions(const MatrixRef& transmat, const MatrixRef& flags);

/// Annealing schedule: Z per iteration, rising from z_start to z_final over the first n_anneal
/// iterations along a cosine ramp (slow at both ends), then constant at z_final.
/// @return #n_iter values
/// @throws std::invalid_argument if n_iter < 1, n_anneal < 0 or a Z is not finite.
VectorXd anneal_schedule(Index n_iter, double z_start, double z_final, Index n_anneal);

}  // namespace voicepuppet
