// Tests of trajectory.hpp against independent truth: a dense solve of the normal equations
// assembled from the objective itself (selection matrices, not the block formulas), closed
// forms (one state gives its mean; a step gives the analytic exponential approach), one-hot
// weights equal the hard solve, and the fixed-lag stream equals truncated dense solves.
#include <doctest/doctest.h>

#include "random_trajectory.hpp"
#include "voicepuppet/trajectory.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>

#include <cmath>
#include <random>
#include <stdexcept>
#include <thread>

using namespace voicepuppet;
using Eigen::MatrixXd;

using testing::dense_solve;
using testing::diag_of;
using testing::one_hot;
using testing::random_model;
using testing::random_states;
using testing::RandomModel;
using testing::rel;

TEST_CASE("full covariance: block Cholesky equals the dense solve of the objective") {
  std::mt19937 rng(1234);
  for (Index d : {1, 3, 5}) {
    const Index n = 4, T = 60;
    RandomModel m = random_model(n, d, rng);
    TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
    VectorXi s = random_states(T, n, rng);
    RowMatrixXd y = solve_trajectory(model, s);
    CHECK(rel(y, dense_solve(m, one_hot(s, n), false)) < 1e-11);
  }
}

TEST_CASE("full covariance, D up to 50: every panel width, tail block and row tile equals the dense solve") {
  // D = 8k ± 1 and 50 exercise the 8-column blocks with and without a narrow last block, the
  // 24/16/8-row tiles of the panel updates and the vector parts of the triangular sweeps.
  std::mt19937 rng(4321);
  for (Index d : {7, 8, 9, 16, 17, 24, 31, 50}) {
    const Index n = 3, T = d >= 24 ? 9 : 25;
    CAPTURE(d);
    RandomModel m = random_model(n, d, rng);
    TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
    VectorXi s = random_states(T, n, rng);
    CHECK(rel(solve_trajectory(model, s), dense_solve(m, one_hot(s, n), false)) < 1e-10);
    if (d == 17) {
      for (Index t : {1, 2}) {
        VectorXi s1 = s.head(t);
        CHECK(rel(solve_trajectory(model, s1), dense_solve(m, one_hot(s1, n), false)) < 1e-10);
      }
    }
  }
}

TEST_CASE("the factor store a thread keeps between solves changes no result") {
  std::mt19937 rng(55);
  const Index n = 4, d = 13;
  RandomModel m = random_model(n, d, rng);
  TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  const VectorXi long_s = random_states(700, n, rng), short_s = random_states(20, n, rng);
  const RowMatrixXd first = solve_trajectory(model, long_s);
  // a shorter solve reuses the larger store: still the dense answer
  CHECK(rel(solve_trajectory(model, short_s), dense_solve(m, one_hot(short_s, n), false)) < 1e-10);
  // repeated and on another thread (its own store): the same bits
  CHECK((solve_trajectory(model, long_s).array() == first.array()).all());
  RowMatrixXd other;
  std::thread worker([&] { other = solve_trajectory(model, long_s); });
  worker.join();
  CHECK((other.array() == first.array()).all());
}

TEST_CASE("diagonal covariance: tridiagonal path equals the dense solve; single frame works") {
  std::mt19937 rng(99);
  const Index n = 3, d = 4;
  RandomModel m = random_model(n, d, rng);
  TrajectoryModel model(m.means, m.vel_means, diag_of(m), CovarianceType::Diagonal);
  for (Index T : {1, 2, 50}) {
    VectorXi s = random_states(T, n, rng);
    CHECK(rel(solve_trajectory(model, s), dense_solve(m, one_hot(s, n), true)) < 1e-11);
  }
}

TEST_CASE("posterior-weighted solve equals the dense weighted objective; one-hot equals hard") {
  std::mt19937 rng(7);
  for (Index d : {3, 19}) {
    const Index n = 3, T = d > 8 ? 15 : 40;
    CAPTURE(d);
    RandomModel m = random_model(n, d, rng);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    RowMatrixXd w = RowMatrixXd::NullaryExpr(T, n, [&] { return u(rng); });
    w.col(1).setZero();  // exact zeros are skipped
    for (auto type : {CovarianceType::Full, CovarianceType::Diagonal}) {
      const bool diag = type == CovarianceType::Diagonal;
      TrajectoryModel model(m.means, m.vel_means, diag ? diag_of(m) : m.covars, type);
      CHECK(rel(solve_trajectory_weighted(model, w), dense_solve(m, w, diag)) < 1e-11);
      VectorXi s = random_states(T, n, rng);
      RowMatrixXd oh = one_hot(s, n);
      CHECK(rel(solve_trajectory_weighted(model, oh), solve_trajectory(model, s)) < 1e-14);
    }
  }
}

TEST_CASE("closed forms: one state gives its mean; a step gives the exponential approach") {
  // One state, zero velocity mean, full correlated covariance: y_t = μ for every t.
  std::mt19937 rng(3);
  RandomModel m = random_model(1, 3, rng);
  m.vel_means.setZero();
  TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  RowMatrixXd y = solve_trajectory(model, VectorXi::Zero(25));
  for (Index t = 0; t < 25; ++t) CHECK((y.row(t) - m.means.row(0)).cwiseAbs().maxCoeff() < 1e-12);

  // Step between two 1-D states (pose precision a, velocity precision c): far from the ends,
  // y_{k+j} = m1 − Δ ρ^{j+1}/(1+ρ) and y_{k−1−j} = m0 + Δ ρ^{j+1}/(1+ρ), where ρ is the root
  // in (0,1) of c ρ² − (a + 2c) ρ + c = 0.
  const double a = 2.0, c = 5.0, m0 = -1.0, m1 = 3.0, delta = m1 - m0;
  RowMatrixXd means(2, 1), vel = RowMatrixXd::Zero(2, 1), var(2, 2);
  means << m0, m1;
  var << 1.0 / a, 1.0 / c, 1.0 / a, 1.0 / c;
  TrajectoryModel step(means, vel, var, CovarianceType::Diagonal);
  const Index T = 400, k = 200;
  VectorXi s(T);
  for (Index t = 0; t < T; ++t) s[t] = t < k ? 0 : 1;
  RowMatrixXd ys = solve_trajectory(step, s);
  const double rho = ((a + 2 * c) - std::sqrt((a + 2 * c) * (a + 2 * c) - 4 * c * c)) / (2 * c);
  for (Index j = 0; j < 30; ++j) {
    CHECK(ys(k + j, 0) == doctest::Approx(m1 - delta * std::pow(rho, j + 1) / (1 + rho)).epsilon(1e-12));
    CHECK(ys(k - 1 - j, 0) == doctest::Approx(m0 + delta * std::pow(rho, j + 1) / (1 + rho)).epsilon(1e-12));
  }
  // The same through the full path (a diagonal matrix given as full covariance).
  RowMatrixXd full(4, 2);
  full << 1.0 / a, 0, 0, 1.0 / c, 1.0 / a, 0, 0, 1.0 / c;
  TrajectoryModel stepf(means, vel, full, CovarianceType::Full);
  CHECK(rel(solve_trajectory(stepf, s), ys) < 1e-12);
}

TEST_CASE("first frame has no velocity term") {
  // Two frames, 1-D: frame 0 state has pose variance 1 at mean 0; frame 1's state pins pose at 5
  // and velocity 0 tightly. If a velocity term (against μ̇ of frame 0's state) acted on frame 0
  // from a virtual frame −1, y_0 would move; without it, the exact optimum is
  // y0 = c·y1/(a0 + c) with y1 ≈ 5 in the tight limit; check against the 2×2 solve.
  RowMatrixXd means(2, 1), vel(2, 1), var(2, 2);
  means << 0.0, 5.0;
  vel << 7.0, 0.0;  // state 0's velocity mean would pull frame 0 if it had a velocity term
  var << 1.0, 0.25, 0.01, 0.5;
  TrajectoryModel model(means, vel, var, CovarianceType::Diagonal);
  VectorXi s(2);
  s << 0, 1;
  RowMatrixXd y = solve_trajectory(model, s);
  // H = [[a0 + c1, −c1], [−c1, a1 + c1]], r = [a0·μ0 − c1·μ̇1, a1·μ1 + c1·μ̇1]
  const double a0 = 1.0, a1 = 100.0, c1 = 2.0;
  Eigen::Matrix2d h;
  h << a0 + c1, -c1, -c1, a1 + c1;
  Eigen::Vector2d r(a0 * 0.0 - c1 * 0.0, a1 * 5.0 + c1 * 0.0);
  Eigen::Vector2d expect = h.inverse() * r;
  CHECK(y(0, 0) == doctest::Approx(expect(0)).epsilon(1e-13));
  CHECK(y(1, 0) == doctest::Approx(expect(1)).epsilon(1e-13));
}

TEST_CASE("fixed lag: each emitted frame is the truncated solve; flush completes the full solve") {
  std::mt19937 rng(11);
  const Index n = 3, d = 2, T = 30;
  RandomModel m = random_model(n, d, rng);
  TrajectoryModel model(m.means, m.vel_means, m.covars, CovarianceType::Full);
  VectorXi s = random_states(T, n, rng);
  for (Index lag : {0, 1, 4}) {
    FixedLagTrajectory stream(model, lag);
    RowMatrixXd first = stream.push_states(s.head(10));
    RowMatrixXd second = stream.push_states(s.tail(T - 10));
    CHECK(first.rows() == 10 - lag);
    CHECK(second.rows() == 20);
    RowMatrixXd rest = stream.flush();
    CHECK(rest.rows() == lag);
    RowMatrixXd all(T, d);
    all << first, second, rest;
    for (Index t = 0; t < T - lag; ++t) {
      const Index end = t + lag + 1;
      VectorXi sub = s.head(end);
      RowMatrixXd truncated = solve_trajectory(model, sub);
      CHECK((all.row(t) - truncated.row(t)).cwiseAbs().maxCoeff() < 1e-11 * truncated.cwiseAbs().maxCoeff());
    }
    RowMatrixXd full = solve_trajectory(model, s);
    CHECK(rel(all.bottomRows(lag + 1), full.bottomRows(lag + 1)) < 1e-12);
    CHECK(stream.frames_pushed() == 0);
  }
  // a lag longer than the stream: everything comes from flush, equal to the batch solve
  FixedLagTrajectory longlag(model, 100);
  CHECK(longlag.push_states(s).rows() == 0);
  CHECK(rel(longlag.flush(), solve_trajectory(model, s)) < 1e-12);
  // weighted pushes, diagonal model
  TrajectoryModel dmodel(m.means, m.vel_means, diag_of(m), CovarianceType::Diagonal);
  std::uniform_real_distribution<double> u(0.1, 1.0);
  RowMatrixXd w = RowMatrixXd::NullaryExpr(T, n, [&] { return u(rng); });
  FixedLagTrajectory ws(dmodel, 2);
  RowMatrixXd a = ws.push_weights(w);
  RowMatrixXd b = ws.flush();
  RowMatrixXd allw(T, d);
  allw << a, b;
  CHECK(rel(allw.bottomRows(3), solve_trajectory_weighted(dmodel, w).bottomRows(3)) < 1e-12);
  CHECK(rel(allw.row(5), solve_trajectory_weighted(dmodel, w.topRows(8)).row(5)) < 1e-12);
}

TEST_CASE("resampling in time") {
  VectorXi s(4);
  s << 0, 1, 2, 3;
  VectorXi up = resample_states(s, 10.0, 20.0);
  REQUIRE(up.size() == 8);
  VectorXi expect(8);
  expect << 0, 0, 1, 1, 2, 2, 3, 3;
  CHECK(up == expect);
  VectorXi down = resample_states(s, 20.0, 10.0);
  REQUIRE(down.size() == 2);
  CHECK(down[0] == 0);
  CHECK(down[1] == 2);
  CHECK(resample_states(s, 29.97, 29.97) == s);
  RowMatrixXd w(2, 2);
  w << 1.0, 0.0, 0.0, 1.0;
  RowMatrixXd wu = resample_weights(w, 1.0, 2.0);
  REQUIRE(wu.rows() == 4);
  CHECK(wu(1, 0) == doctest::Approx(0.5));
  CHECK(wu(3, 1) == doctest::Approx(1.0));
}

TEST_CASE("velocity scale: doubling the frame rate halves per-frame velocities") {
  // One state, 1-D, velocity mean 1 per training frame, tight velocity, loose pose, all at
  // the training rate: the interior slope is about 1 per frame; at twice the rate about 1/2.
  RowMatrixXd means(1, 1), vel(1, 1), var(1, 2);
  means << 0.0;
  vel << 1.0;
  var << 1e6, 1e-4;
  TrajectoryModel m1(means, vel, var, CovarianceType::Diagonal, 1.0);
  TrajectoryModel m2(means, vel, var, CovarianceType::Diagonal, 0.5);
  RowMatrixXd y1 = solve_trajectory(m1, VectorXi::Zero(41));
  RowMatrixXd y2 = solve_trajectory(m2, VectorXi::Zero(81));
  CHECK(y1(21, 0) - y1(20, 0) == doctest::Approx(1.0).epsilon(1e-6));
  CHECK(y2(41, 0) - y2(40, 0) == doctest::Approx(0.5).epsilon(1e-6));
  // and the same time span covers the same distance
  CHECK(y2(80, 0) - y2(0, 0) == doctest::Approx(y1(40, 0) - y1(0, 0)).epsilon(1e-6));
}

TEST_CASE("bad input throws std::invalid_argument naming the argument") {
  RowMatrixXd means(2, 1), vel(2, 1), var(2, 2);
  means << 0, 1;
  vel << 0, 0;
  var << 1, 1, 1, 1;
  TrajectoryModel model(means, vel, var, CovarianceType::Diagonal);
  VectorXi bad(3);
  bad << 0, 2, 1;
  CHECK_THROWS_WITH_AS(solve_trajectory(model, bad), doctest::Contains("states[1] = 2"), std::invalid_argument);
  CHECK_THROWS_AS(solve_trajectory(model, VectorXi(0)), std::invalid_argument);
  RowMatrixXd zero_var = var;
  zero_var(1, 1) = 0.0;
  CHECK_THROWS_WITH_AS(TrajectoryModel(means, vel, zero_var, CovarianceType::Diagonal),
                       doctest::Contains("covars[1, 1]"), std::invalid_argument);
  CHECK_THROWS_WITH_AS(TrajectoryModel(means, RowMatrixXd::Zero(3, 1), var, CovarianceType::Diagonal),
                       doctest::Contains("vel_means"), std::invalid_argument);
  RowMatrixXd notpd(4, 2);
  notpd << 1, 2, 2, 1, 1, 0, 0, 1;
  CHECK_THROWS_WITH_AS(TrajectoryModel(means, vel, notpd, CovarianceType::Full),
                       doctest::Contains("state 0 is not positive definite"), std::invalid_argument);
  RowMatrixXd w(2, 2);
  w << 0.5, 0.5, 0.0, 0.0;
  CHECK_THROWS_WITH_AS(solve_trajectory_weighted(model, w), doctest::Contains("row 1 sums to zero"),
                       std::invalid_argument);
  CHECK_THROWS_AS(FixedLagTrajectory(model, -1), std::invalid_argument);
  CHECK_THROWS_AS(resample_states(bad, 0.0, 30.0), std::invalid_argument);
}

TEST_CASE("an ill-conditioned system is reported with its condition estimate") {
  // Per-dimension variances spanning 1e-8 .. 1e8 in one full-covariance state: each covariance
  // is accepted only up to condition 1e12, so a model at 1e16 is rejected at construction.
  RowMatrixXd means = RowMatrixXd::Zero(1, 1), vel = RowMatrixXd::Zero(1, 1), k(2, 2);
  k << 1e8, 0, 0, 1e-8;
  CHECK_THROWS_WITH_AS(TrajectoryModel(means, vel, k, CovarianceType::Full), doctest::Contains("condition estimate"),
                       std::invalid_argument);
  // Diagonal: pose precision tiny and velocity precision huge makes H nearly singular (the
  // constant direction is only weakly pinned): condition ≈ 4·c·T²/π² / a → reported.
  RowMatrixXd var(1, 2);
  var << 1e10, 1e-6;
  TrajectoryModel weak(means, vel, var, CovarianceType::Diagonal);
  CHECK_THROWS_WITH_AS(solve_trajectory(weak, VectorXi::Zero(50)), doctest::Contains("condition estimate"),
                       std::runtime_error);
}
