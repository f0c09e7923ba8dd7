// interrupt.hpp: the long loops call the installed handler, whose exception stops them.
#include <doctest/doctest.h>

#include "voicepuppet/hmm.hpp"
#include "voicepuppet/interrupt.hpp"
#include "voicepuppet/trajectory.hpp"

#include <chrono>
#include <thread>

using namespace voicepuppet;

namespace {

struct Stopped {};
int g_calls = 0;

void stop() {
  ++g_calls;
  throw Stopped{};
}

void count() { ++g_calls; }

// Installs a handler, and restores the one a test found whatever happens in it. The handler is
// called at most every 20 ms: the scope starts after that much time, so its first due check calls it.
struct HandlerScope {
  InterruptHandler previous;
  explicit HandlerScope(InterruptHandler h) : previous(set_interrupt_handler(h)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  ~HandlerScope() { set_interrupt_handler(previous); }
};

}  // namespace

TEST_CASE("a throwing handler stops Viterbi; a returning one leaves its result unchanged") {
  const Index T = 20000, N = 3;
  RowMatrixXd log_b(T, N);
  for (Index t = 0; t < T; ++t)
    for (Index j = 0; j < N; ++j) log_b(t, j) = -0.5 * static_cast<double>((t / 7 + j) % N);
  const VectorXd start = VectorXd::Constant(N, 1.0 / N);
  const RowMatrixXd trans = RowMatrixXd::Constant(N, N, 1.0 / N);
  VectorXi lengths(1);
  lengths << T;
  const ViterbiResult plain = viterbi(log_b, start, trans, lengths);
  {
    HandlerScope scope(&stop);
    g_calls = 0;
    CHECK_THROWS_AS(viterbi(log_b, start, trans, lengths), Stopped);
    CHECK(g_calls == 1);  // the first check that reaches the handler stops it
  }
  {
    HandlerScope scope(&count);
    const ViterbiResult counted = viterbi(log_b, start, trans, lengths);
    CHECK(counted.path == plain.path);
    CHECK(counted.log_probability == plain.log_probability);
  }
  const bool restored = set_interrupt_handler(nullptr) == nullptr;  // the scopes put the default back
  CHECK(restored);
}

TEST_CASE("a throwing handler stops the trajectory solve") {
  const Index D = 2, N = 2, T = 5000;
  RowMatrixXd means(N, D);
  means << 0, 0, 1, 2;
  const TrajectoryModel model(means, RowMatrixXd::Zero(N, D), RowMatrixXd::Ones(N, 2 * D), CovarianceType::Diagonal);
  VectorXi states(T);
  for (Index t = 0; t < T; ++t) states[t] = (t / 10) % N;
  HandlerScope scope(&stop);
  g_calls = 0;
  CHECK_THROWS_AS(solve_trajectory(model, states), Stopped);
  CHECK(g_calls == 1);
}
