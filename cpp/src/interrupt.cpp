#include "voicepuppet/interrupt.hpp"

#include <atomic>
#include <chrono>
#include <cstdint>

#if defined(_OPENMP)
#include <omp.h>
#endif

namespace voicepuppet {
namespace {

std::atomic<InterruptHandler> g_handler{nullptr};
constexpr std::int64_t kPeriodNs = 20'000'000;  // 20 ms between calls of the handler
constexpr unsigned kCallsPerClockRead = 64;     // the clock is read every 64th check

}  // namespace

InterruptHandler set_interrupt_handler(InterruptHandler handler) { return g_handler.exchange(handler); }

void check_interrupt() {
  const InterruptHandler handler = g_handler.load(std::memory_order_relaxed);
  if (handler == nullptr) return;
#if defined(_OPENMP)
  if (omp_in_parallel()) return;  // an exception must not leave a parallel region
#endif
  thread_local unsigned calls = 0;
  thread_local std::int64_t last = 0;
  if (++calls % kCallsPerClockRead != 0) return;
  const std::int64_t now = std::chrono::duration_cast<std::chrono::nanoseconds>(
                               std::chrono::steady_clock::now().time_since_epoch()).count();
  if (now - last < kPeriodNs) return;
  last = now;
  handler();
}

}  // namespace voicepuppet
