#pragma once
/// @file interrupt.hpp
/// Interruption of long computations. The long loops of the core (audio features, the
/// trajectory solve, the HMM lattices) call check_interrupt() between steps; a host installs a
/// handler that throws to stop them: the Python bindings install one that raises
/// KeyboardInterrupt on Ctrl-C (PyErr_CheckSignals), so that a call on hours of audio stops
/// within a fraction of a second. C++ callers may install their own (e.g. one that throws when a
/// flag set by a signal handler or another thread is up). Without a handler nothing is checked.
/// The exception the handler throws leaves the computation as any other error would: no partial
/// result is returned.

namespace voicepuppet {

/// A function that throws to interrupt the computation in progress, and returns otherwise.
using InterruptHandler = void (*)();

/// Installs `handler` (nullptr: none, the default) for every thread; returns the previous one.
InterruptHandler set_interrupt_handler(InterruptHandler handler);

/// Calls the installed handler, at most about every 20 ms of this thread's wall time (a counter
/// and a clock read otherwise), and never inside an OpenMP parallel region.
void check_interrupt();

}  // namespace voicepuppet
