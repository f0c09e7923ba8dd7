// Tests of the per-frame evidence term of the batch trajectory solves (trajectory.hpp):
// against a dense solve of the objective assembled from its definition (selection matrices,
// not the block formulas), W = 0 equals the unguided solve exactly, a huge W returns the
// targets, a planted offset is fixed by the evidence, and bad evidence is refused.
#include <doctest/doctest.h>

#include "random_trajectory.hpp"
#include "throws_with.hpp"
#include "voicepuppet/trajectory.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

using namespace voicepuppet;
using Eigen::MatrixXd;
using testing::dense_solve;
using testing::diag_of;
using testing::one_hot;
using testing::random_model;
using testing::random_spd;
using testing::random_states;
using testing::RandomModel;
using testing::rel;

namespace {

MatrixXd soft(Index T, Index n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  MatrixXd w = MatrixXd::NullaryExpr(T, n, [&] { return u(rng); });
  for (Index t = 0; t < T; ++t) w.row(t) /= w.row(t).sum();
  return w;
}

RowMatrixXd random_targets(Index T, Index d, std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  return RowMatrixXd::NullaryExpr(T, d, [&] { return g(rng); });
}

}  // namespace

TEST_CASE("evidence: full and diagonal models, hard and weighted, equal the dense solve of the objective") {
  std::mt19937 rng(20261202);
  for (Index d : {1, 3, 9}) {
    const Index n = 4, T = 40;
    const RandomModel m = random_model(n, d, rng);
    const TrajectoryModel full(m.means, m.vel_means, m.covars, CovarianceType::Full);
    const TrajectoryModel diag(m.means, m.vel_means, diag_of(m), CovarianceType::Diagonal);
    const VectorXi s = random_states(T, n, rng);
    const MatrixXd g = soft(T, n, rng);
    const MatrixXd w_full = random_spd(d, rng, 0.7);
    const MatrixXd w_diag = MatrixXd(w_full.diagonal().asDiagonal());
    for (const MatrixXd& w : {w_full, w_diag}) {
      const TrajectoryEvidence e{random_targets(T, d, rng), w};
      CAPTURE(d);
      CHECK(rel(solve_trajectory(full, s, &e), dense_solve(m, one_hot(s, n), false, &e.targets, &w)) < 1e-10);
      CHECK(rel(solve_trajectory_weighted(full, g, &e), dense_solve(m, g, false, &e.targets, &w)) < 1e-10);
      // a diagonal model with a full W is solved as full; with a diagonal W as D scalar systems
      CHECK(rel(solve_trajectory(diag, s, &e), dense_solve(m, one_hot(s, n), true, &e.targets, &w)) < 1e-10);
      CHECK(rel(solve_trajectory_weighted(diag, g, &e), dense_solve(m, g, true, &e.targets, &w)) < 1e-10);
    }
  }
}

TEST_CASE("evidence: a zero precision is the unguided solve exactly") {
  std::mt19937 rng(7);
  for (Index d : {2, 17}) {
    const Index n = 5, T = 50;
    const RandomModel m = random_model(n, d, rng);
    const VectorXi s = random_states(T, n, rng);
    const MatrixXd g = soft(T, n, rng);
    const TrajectoryEvidence e{random_targets(T, d, rng), MatrixXd::Zero(d, d)};
    for (CovarianceType type : {CovarianceType::Full, CovarianceType::Diagonal}) {
      const TrajectoryModel model(m.means, m.vel_means, type == CovarianceType::Full ? m.covars : diag_of(m), type);
      CHECK((solve_trajectory(model, s, &e).array() == solve_trajectory(model, s).array()).all());
      CHECK((solve_trajectory_weighted(model, g, &e).array() == solve_trajectory_weighted(model, g).array()).all());
    }
  }
}

TEST_CASE("evidence: a huge precision returns the targets") {
  std::mt19937 rng(11);
  const Index n = 3, d = 6, T = 30;
  const RandomModel m = random_model(n, d, rng);
  const TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  const VectorXi s = random_states(T, n, rng);
  const TrajectoryEvidence e{random_targets(T, d, rng), random_spd(d, rng, 1e9)};
  CHECK((solve_trajectory(model, s, &e) - e.targets).cwiseAbs().maxCoeff() < 1e-6);
  CHECK((solve_trajectory_weighted(model, one_hot(s, n), &e) - e.targets).cwiseAbs().maxCoeff() < 1e-6);
}

TEST_CASE("evidence: a planted offset of the model's means is fixed by the evidence") {
  // Truth: a trajectory through one state's mean. The model's mean is off by a known offset;
  // evidence at the truth with precision equal to the model's pose precision pulls the solve
  // halfway back (one state, zero velocity mean: y = (P μ' + P μ) / 2P = μ + offset / 2).
  const Index d = 3, T = 25;
  const Eigen::VectorXd mu = (Eigen::VectorXd(d) << 1.0, -2.0, 0.5).finished();
  const Eigen::VectorXd offset = (Eigen::VectorXd(d) << 0.4, 0.3, -0.6).finished();
  RowMatrixXd means = (mu + offset).transpose(), vel = RowMatrixXd::Zero(1, d);
  MatrixXd k = MatrixXd::Identity(2 * d, 2 * d);
  k.topLeftCorner(d, d) = (MatrixXd(d, d) << 2.0, 0.3, 0.1, 0.3, 1.0, 0.2, 0.1, 0.2, 1.5).finished();
  const TrajectoryModel model(means, vel, k, CovarianceType::Full);
  const VectorXi s = VectorXi::Zero(T);
  const MatrixXd p = MatrixXd(k.topLeftCorner(d, d)).inverse();
  TrajectoryEvidence e{RowMatrixXd(mu.transpose().replicate(T, 1)), p};
  const RowMatrixXd y = solve_trajectory(model, s, &e);
  for (Index t = 0; t < T; ++t) CHECK((y.row(t).transpose() - (mu + 0.5 * offset)).norm() < 1e-12);
  const RowMatrixXd unguided = solve_trajectory(model, s);
  CHECK((unguided.row(T - 1).transpose() - (mu + offset)).norm() < 1e-12);
  e.precision *= 1e7;  // the evidence dominates: the planted offset is gone
  CHECK((solve_trajectory(model, s, &e).row(T / 2).transpose() - mu).norm() < 1e-6);
}

TEST_CASE("evidence: bad shapes and values throw std::invalid_argument naming the array") {
  std::mt19937 rng(3);
  const Index n = 2, d = 3, T = 10;
  const RandomModel m = random_model(n, d, rng);
  const TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  const VectorXi s = random_states(T, n, rng);
  const MatrixXd w = random_spd(d, rng, 1.0);
  const RowMatrixXd y = random_targets(T, d, rng);
  auto bad = [&](const TrajectoryEvidence& e, const char* what) {
    CAPTURE(what);
    CHECK(testing::throws_with<std::invalid_argument>([&] { solve_trajectory(model, s, &e); }, what));
    CHECK(testing::throws_with<std::invalid_argument>([&] { solve_trajectory_weighted(model, one_hot(s, n), &e); }, what));
  };
  bad({random_targets(T - 1, d, rng), w}, "evidence.targets must be 10 x 3");
  bad({y, MatrixXd::Identity(d + 1, d + 1)}, "evidence.precision must be 3 x 3");
  RowMatrixXd y_nan = y;
  y_nan(4, 1) = std::numeric_limits<double>::quiet_NaN();
  bad({y_nan, w}, "evidence.targets");
  MatrixXd w_inf = w;
  w_inf(0, 0) = std::numeric_limits<double>::infinity();
  bad({y, w_inf}, "NaN or infinite");
  MatrixXd w_asym = w;
  w_asym(0, 1) += 0.1;
  bad({y, w_asym}, "not symmetric");
  bad({y, -w}, "not positive semi-definite");
}
