#pragma once
/// @file hmm.hpp
/// Hidden Markov model inference on precomputed log emission densities: forward-backward
/// (log lattices with shifted linear sums, and a pure log-sum-exp reference), Viterbi and the log-likelihood, over one or many
/// sequences. Transitions are held so that a sparse machine costs only its allowed arcs.
///
/// Shapes: T frames (all sequences stacked), N states. `lengths` splits the T frames into
/// sequences; an empty `lengths` means one sequence of T frames.

#include "voicepuppet/types.hpp"

#include <vector>

namespace voicepuppet {

/// A transition matrix stored as its allowed arcs (entries > 0), by source and by destination.
struct Transitions {
  Index n_states = 0;
  /// Arcs grouped by destination j: sources `in_src[in_ptr[j] .. in_ptr[j+1])`, probs `in_p`.
  std::vector<Index> in_ptr, in_src;
  std::vector<double> in_p;
  /// Arcs grouped by source i: destinations `out_dst[out_ptr[i] .. out_ptr[i+1])`, probs `out_p`.
  std::vector<Index> out_ptr, out_dst;
  std::vector<double> out_p;
  /// log of `in_p` and `out_p`, arc by arc.
  std::vector<double> in_lp, out_lp;
  /// Total arc probability into each destination (column sums) and out of each source (row sums).
  std::vector<double> in_sum, out_sum;
  Index n_arcs() const { return static_cast<Index>(in_src.size()); }
};

/// Checks a start vector and transition matrix and builds the arc lists.
/// @param[in] startprob  #N start probabilities, non-negative, summing to 1 (±1e-6)
/// @param[in] transmat   #N by #N row-stochastic matrix (rows sum to 1 ±1e-6)
/// @throws std::invalid_argument naming the argument on a wrong shape, a negative or
///         non-finite entry, or a row that does not sum to one.
Transitions make_transitions(const VectorRef& startprob, const MatrixRef& transmat);

/// Checks `lengths` (positive entries summing to `n_frames`); returns the sequence starts,
/// with a final entry equal to n_frames. Empty lengths means one sequence.
std::vector<Index> sequence_bounds(const IndexVectorRef& lengths, Index n_frames);

/// Result of forward-backward over all sequences.
struct ForwardBackwardResult {
  double log_likelihood = 0;      ///< sum over sequences of log p(sequence)
  VectorXd sequence_log_likelihoods;  ///< #S, one per sequence
  RowMatrixXd posteriors;         ///< #T by #N state posteriors γ (rows sum to 1)
  RowMatrixXd expected_transitions;  ///< #N by #N expected transition counts ξ summed over t
  VectorXd expected_starts;       ///< #N posterior of the first frame, summed over sequences
};

/// Forward-backward on log lattices log α, log β. Each frame's sum over arcs is done in linear
/// space on the previous log lattice shifted by its maximum (one exp and one log per state, one
/// multiply-add per arc); a state whose kept sum could be dominated by the terms flushed to zero
/// (bound: 1e-24 relative) is recomputed by log-sum-exp over its arcs, so a state far below the
/// others is never lost and the results equal forward_backward_log's in every regime. O(T·arcs).
/// @param[in] log_b      #T by #N log emission densities log p(x_t | state n)
/// @param[in] startprob  #N start probabilities
/// @param[in] transmat   #N by #N transition probabilities
/// @param[in] lengths    #S sequence lengths summing to T (empty: one sequence)
/// @throws std::invalid_argument on bad shapes or values; std::runtime_error when a
///         sequence has zero probability under the model (no allowed path).
ForwardBackwardResult forward_backward(const MatrixRef& log_b, const VectorRef& startprob,
                                       const MatrixRef& transmat, const IndexVectorRef& lengths);

/// The same quantities computed entirely with log-sum-exp (the reference implementation).
ForwardBackwardResult forward_backward_log(const MatrixRef& log_b, const VectorRef& startprob,
                                           const MatrixRef& transmat,
                                           const IndexVectorRef& lengths);

/// Log forward lattice log α_t(n) = log p(x_1..x_t, s_t = n) of one sequence. #T by #N.
RowMatrixXd forward_lattice_log(const MatrixRef& log_b, const VectorRef& startprob,
                                const MatrixRef& transmat);

/// Log backward lattice log β_t(n) = log p(x_{t+1}..x_T | s_t = n) of one sequence. #T by #N.
RowMatrixXd backward_lattice_log(const MatrixRef& log_b, const MatrixRef& transmat);

/// Log-likelihood only (the forward pass of forward_backward), summed over sequences.
double log_likelihood(const MatrixRef& log_b, const VectorRef& startprob,
                      const MatrixRef& transmat, const IndexVectorRef& lengths);

/// Result of Viterbi decoding.
struct ViterbiResult {
  double log_probability = 0;  ///< log p(best path, data), summed over sequences
  VectorXi path;               ///< #T most likely state per frame
};

/// Viterbi decoding in log space on the arc lists; ties go to the lowest state index.
ViterbiResult viterbi(const MatrixRef& log_b, const VectorRef& startprob,
                      const MatrixRef& transmat, const IndexVectorRef& lengths);

}  // namespace voicepuppet
