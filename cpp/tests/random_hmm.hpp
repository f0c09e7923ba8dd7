#pragma once
// A random HMM and random log emission densities for the C++ tests of hmm.hpp and streaming.hpp.
#include "voicepuppet/types.hpp"

#include <random>

namespace voicepuppet::testing {

struct Model {
  VectorXd pi;
  RowMatrixXd A;
  RowMatrixXd log_b;
};

/// `n` states, `T` frames of N(−3, 2²) log densities; each off-diagonal arc is absent with
/// probability `sparsity`; deterministic for a seed.
inline Model random_model(Index n, Index T, unsigned seed, double sparsity = 0.0) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.05, 1.0);
  Model m;
  m.pi.resize(n);
  m.A.resize(n, n);
  for (Index i = 0; i < n; ++i) {
    m.pi[i] = u(rng);
    for (Index j = 0; j < n; ++j) m.A(i, j) = (j != i && u(rng) < sparsity) ? 0.0 : u(rng);
    m.A.row(i) /= m.A.row(i).sum();
  }
  m.pi /= m.pi.sum();
  m.log_b.resize(T, n);
  std::normal_distribution<double> g(-3.0, 2.0);
  for (Index t = 0; t < T; ++t)
    for (Index j = 0; j < n; ++j) m.log_b(t, j) = g(rng);
  return m;
}

}  // namespace voicepuppet::testing
