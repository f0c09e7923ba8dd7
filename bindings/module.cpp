// The private module voicepuppet._core: one bind_<area> per file under bindings/.
#include <pybind11/pybind11.h>

#include <thread>

#include "voicepuppet/interrupt.hpp"
#include "voicepuppet/types.hpp"

namespace py = pybind11;

namespace {

std::thread::id g_main_thread;

// Ctrl-C while a kernel runs: Python's signal handler only sets a flag, acted on when the
// interpreter runs again; the core's long loops call this (interrupt.hpp), which runs the pending
// handlers and turns a KeyboardInterrupt (or SIGTERM's exception) into a C++ exception carrying
// it back to Python. Signals are only handled on the main thread, so other threads skip the GIL.
void raise_pending_signals() {
  if (std::this_thread::get_id() != g_main_thread) return;
  py::gil_scoped_acquire gil;
  if (PyErr_CheckSignals() != 0) throw py::error_already_set();
}

}  // namespace

void bind_hmm(py::module_& m);
void bind_tracker(py::module_& m);
void bind_trajectory(py::module_& m);
void bind_entropic(py::module_& m);
void bind_puppet(py::module_& m);
void bind_streaming(py::module_& m);
void bind_dpds(py::module_& m);
void bind_audio(py::module_& m);

PYBIND11_MODULE(_core, m) {
  m.doc() = "voicepuppet's C++ kernels (private: use the voicepuppet package)";
  g_main_thread = std::this_thread::get_id();
  voicepuppet::set_interrupt_handler(&raise_pending_signals);
  m.def("build_info", [] {
    auto info = voicepuppet::build_info();
    py::dict d;
    d["version"] = info.version;
    d["build_type"] = info.build_type;
    d["compiler"] = info.compiler;
    d["eigen"] = info.eigen_version;
    d["simd"] = info.simd;
    return d;
  });
  bind_hmm(m);
  bind_tracker(m);
  bind_trajectory(m);
  bind_entropic(m);
  bind_puppet(m);
  bind_streaming(m);
  bind_dpds(m);
  bind_audio(m);
}
