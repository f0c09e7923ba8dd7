// Python bindings of the streaming kernels (streaming.hpp). Thin: argument names, the GIL
// released around pushes; the public API is voicepuppet.live.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

#include "voicepuppet/streaming.hpp"

namespace py = pybind11;
using namespace voicepuppet;

void bind_streaming(py::module_& m) {
  py::class_<DecodedFrames>(m, "DecodedFrames", "Frames decided by a fixed-lag decoder push.")
      .def_readonly("first_frame", &DecodedFrames::first_frame)
      .def_readonly("states", &DecodedFrames::states)
      .def_readonly("posteriors", &DecodedFrames::posteriors)
      .def("__len__", &DecodedFrames::size);
  py::class_<FixedLagDecoder>(m, "FixedLagDecoder",
                              "Online fixed-lag Viterbi and smoothed posteriors (streaming.hpp).")
      .def(py::init<const VectorRef&, const MatrixRef&, Index>(), py::arg("startprob"),
           py::arg("transmat"), py::arg("lag"))
      .def("push", &FixedLagDecoder::push, py::arg("log_b"),
           py::call_guard<py::gil_scoped_release>(),
           "Push log densities [K, N]; returns the frames decided by them.")
      .def("flush", &FixedLagDecoder::flush, py::call_guard<py::gil_scoped_release>(),
           "Decide the held-back frames from the whole stream, then reset.")
      .def("reset", &FixedLagDecoder::reset)
      .def_property_readonly("lag", &FixedLagDecoder::lag)
      .def_property_readonly("n_states", &FixedLagDecoder::n_states)
      .def_property_readonly("frames_pushed", &FixedLagDecoder::frames_pushed)
      .def_property_readonly("frames_emitted", &FixedLagDecoder::frames_emitted)
      .def_property_readonly("log_likelihood", &FixedLagDecoder::log_likelihood);
}
