// Tests of the fixed-lag trajectory stream with per-frame evidence (trajectory.hpp,
// FixedLagTrajectory(model, lag, precision)): every emitted frame is the value at t of a dense
// solve of the guided objective truncated to 0 .. t + lag (assembled from its definition, not
// from the block formulas), flush and a lag covering the stream give the batch guided solve,
// W = 0 is the unguided stream bit for bit, and bad targets or precisions are refused.
#include <doctest/doctest.h>

#include "random_trajectory.hpp"
#include "throws_with.hpp"
#include "voicepuppet/trajectory.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

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
using testing::throws_with;

namespace {

/// Pushes frames [0, T) in chunks of `chunk` (hard states, or weights if `weights` is given),
/// then flushes; returns every emitted row in order and checks the emission counts.
RowMatrixXd stream(FixedLagTrajectory& s, const VectorXi& states, const RowMatrixXd* weights,
                   const RowMatrixXd& targets, Index chunk) {
  const Index T = targets.rows(), d = targets.cols();
  std::vector<RowMatrixXd> parts;
  Index emitted = 0;
  for (Index t0 = 0; t0 < T; t0 += chunk) {
    const Index n = std::min(chunk, T - t0);
    parts.push_back(weights ? s.push_weights(weights->middleRows(t0, n), targets.middleRows(t0, n))
                            : s.push_states(states.segment(t0, n), targets.middleRows(t0, n)));
    emitted += parts.back().rows();
    CHECK(emitted == std::max<Index>(0, t0 + n - s.lag()));
  }
  parts.push_back(s.flush());
  RowMatrixXd all(T, d);
  Index r = 0;
  for (const auto& p : parts) {
    if (p.rows()) all.middleRows(r, p.rows()) = p;
    r += p.rows();
  }
  REQUIRE(r == T);
  return all;
}

}  // namespace

TEST_CASE("fixed lag with evidence: each frame is the truncated guided solve; flush is the batch guided solve") {
  std::mt19937 rng(5);
  const Index n = 3, d = 3, T = 24;
  const RandomModel m = random_model(n, d, rng);
  const VectorXi s = random_states(T, n, rng);
  std::uniform_real_distribution<double> u(0.05, 1.0);
  RowMatrixXd w = RowMatrixXd::NullaryExpr(T, n, [&] { return u(rng); });
  std::normal_distribution<double> g(0.0, 1.0);
  const RowMatrixXd y = RowMatrixXd::NullaryExpr(T, d, [&] { return 2.0 * g(rng); });
  const MatrixXd W = random_spd(d, rng, 0.7);
  for (bool diagonal : {false, true}) {
    const TrajectoryModel model = diagonal ? TrajectoryModel(m.means, m.vel_means, diag_of(m), CovarianceType::Diagonal)
                                           : TrajectoryModel(m.means, m.vel_means, m.covars, CovarianceType::Full);
    for (bool weighted : {false, true}) {
      const MatrixXd weights = weighted ? MatrixXd(w) : one_hot(s, n);
      const TrajectoryEvidence ev{y, W};
      const RowMatrixXd batch = weighted ? solve_trajectory_weighted(model, w, &ev) : solve_trajectory(model, s, &ev);
      // the batch solve itself against the dense objective (the reference of the truncations)
      CHECK(rel(batch, dense_solve(m, weights, diagonal, &y, &W)) < 1e-10);
      for (Index lag : {0, 1, 3}) {
        for (Index chunk : {Index(1), Index(7), T}) {
          CAPTURE(diagonal);
          CAPTURE(weighted);
          CAPTURE(lag);
          CAPTURE(chunk);
          FixedLagTrajectory fl(model, lag, W);
          CHECK(fl.has_evidence());
          const RowMatrixXd got = stream(fl, s, weighted ? &w : nullptr, y, chunk);
          for (Index t = 0; t < T - lag; ++t) {
            const Index end = t + lag + 1;
            const RowMatrixXd yt = y.topRows(end);
            const MatrixXd truncated = dense_solve(m, weights.topRows(end), diagonal, &yt, &W);
            CHECK((got.row(t) - truncated.row(t)).cwiseAbs().maxCoeff() < 1e-10 * (1.0 + truncated.cwiseAbs().maxCoeff()));
          }
          // the frames held back come from the whole guided solve
          CHECK(rel(got.bottomRows(lag + 1), batch.bottomRows(lag + 1)) < 1e-10);
        }
      }
      // a lag covering the stream: the batch guided solve
      for (Index lag : {T - 1, T + 10}) {
        FixedLagTrajectory fl(model, lag, W);
        CHECK(rel(stream(fl, s, weighted ? &w : nullptr, y, 5), batch) < 1e-10);
      }
    }
  }
}

TEST_CASE("fixed lag with evidence: W = 0 is the unguided stream bit for bit; the evidence changes it") {
  std::mt19937 rng(8);
  const Index n = 4, d = 2, T = 30;
  const RandomModel m = random_model(n, d, rng);
  const TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  const VectorXi s = random_states(T, n, rng);
  std::normal_distribution<double> g(0.0, 1.0);
  const RowMatrixXd y = RowMatrixXd::NullaryExpr(T, d, [&] { return 3.0 * g(rng); });
  for (Index lag : {0, 2}) {
    FixedLagTrajectory plain(model, lag), zero(model, lag, MatrixXd::Zero(d, d)), guided(model, lag, MatrixXd::Identity(d, d));
    CHECK(!plain.has_evidence());
    RowMatrixXd a(T, d), b(T, d), c(T, d);
    const RowMatrixXd a1 = plain.push_states(s), b1 = zero.push_states(s, y), c1 = guided.push_states(s, y);
    a << a1, plain.flush();
    b << b1, zero.flush();
    c << c1, guided.flush();
    CHECK((a.array() == b.array()).all());
    CHECK((a - c).cwiseAbs().maxCoeff() > 1e-2);
  }
}

TEST_CASE("fixed lag with evidence: bad targets and precisions throw std::invalid_argument naming them") {
  std::mt19937 rng(3);
  const Index n = 2, d = 2;
  const RandomModel m = random_model(n, d, rng);
  const TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  VectorXi s(3);
  s << 0, 1, 1;
  const RowMatrixXd y = RowMatrixXd::Zero(3, d);
  FixedLagTrajectory plain(model, 1), guided(model, 1, MatrixXd::Identity(d, d));
  CHECK(throws_with<std::invalid_argument>([&] { plain.push_states(s, y); }, "has no evidence"));
  CHECK(throws_with<std::invalid_argument>([&] { guided.push_states(s); }, "needs the frames' targets"));
  CHECK(throws_with<std::invalid_argument>([&] { guided.push_weights(one_hot(s, n)); }, "needs the frames' targets"));
  CHECK(throws_with<std::invalid_argument>([&] { guided.push_states(s, RowMatrixXd::Zero(2, d)); }, "targets must be 3 x 2"));
  RowMatrixXd bad = y;
  bad(1, 0) = std::nan("");
  CHECK(throws_with<std::invalid_argument>([&] { guided.push_weights(one_hot(s, n), bad); }, "targets"));
  CHECK(guided.frames_pushed() == 0);  // nothing was pushed by the refused calls
  MatrixXd asym = MatrixXd::Identity(d, d);
  asym(0, 1) = 0.5;
  CHECK(throws_with<std::invalid_argument>([&] { FixedLagTrajectory f(model, 1, asym); }, "precision is not symmetric"));
  CHECK(throws_with<std::invalid_argument>([&] { FixedLagTrajectory f(model, 1, -MatrixXd::Identity(d, d)); },
                                           "not positive semi-definite"));
  CHECK(throws_with<std::invalid_argument>([&] { FixedLagTrajectory f(model, 1, MatrixXd::Identity(3, 3)); },
                                           "precision must be 2 x 2"));
}
