// Python bindings of the streaming kernels (streaming.hpp). Thin: argument names, the GIL
// released around pushes; the public API is voicepuppet.live.server.
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

  py::class_<StreamedFrames>(m, "StreamedFrames", "Face frames emitted by a streaming puppet.")
      .def_readonly("first_frame", &StreamedFrames::first_frame)
      .def_readonly("points", &StreamedFrames::points)
      .def_readonly("face", &StreamedFrames::face)
      .def_readonly("vocal", &StreamedFrames::vocal)
      .def_readonly("first_vocal", &StreamedFrames::first_vocal)
      .def("__len__", &StreamedFrames::size);
  py::class_<StreamingPuppet>(m, "StreamingPuppet",
                              "A Puppet driven frame by frame with bounded latency (streaming.hpp).")
      .def(py::init([](const Puppet& puppet, Index decode_lag, Index trajectory_lag, double fps,
                       bool posterior, Index delta_lag, Index projection_lag, Index guide_lag,
                       double guide_weight) {
             StreamingOptions o;
             o.delta_lag = delta_lag;
             o.projection_lag = projection_lag;
             o.guide_lag = guide_lag;
             o.guide_weight = guide_weight;
             o.decode_lag = decode_lag;
             o.trajectory_lag = trajectory_lag;
             o.fps = fps;
             o.posterior = posterior;
             return StreamingPuppet(puppet, o);
           }),
           py::arg("puppet"), py::arg("decode_lag") = 2, py::arg("trajectory_lag") = 2,
           py::arg("fps") = 0.0, py::arg("posterior") = false, py::arg("delta_lag") = -1,
           py::arg("projection_lag") = -1, py::arg("guide_lag") = -1, py::arg("guide_weight") = -1.0)
      .def("push", &StreamingPuppet::push, py::arg("raw_features"),
           py::call_guard<py::gil_scoped_release>(),
           "Push raw audio feature frames [K, A]; returns the face frames completed.")
      .def("flush", &StreamingPuppet::flush, py::call_guard<py::gil_scoped_release>(),
           "Emit the held-back frames (from the whole stream), then reset.")
      .def("reset", &StreamingPuppet::reset)
      .def_property_readonly("output_fps", &StreamingPuppet::output_fps)
      .def_property_readonly("latency_seconds", &StreamingPuppet::latency_seconds)
      .def_property_readonly("frames_pushed", &StreamingPuppet::frames_pushed)
      .def_property_readonly("frames_emitted", &StreamingPuppet::frames_emitted)
      .def_property_readonly("log_likelihood", &StreamingPuppet::log_likelihood)
      .def_property_readonly("delta_lag", [](const StreamingPuppet& s) { return s.options().delta_lag; })
      .def_property_readonly("projection_lag",
                             [](const StreamingPuppet& s) { return s.options().projection_lag; })
      .def_property_readonly("guide_lag", [](const StreamingPuppet& s) { return s.options().guide_lag; })
      .def_property_readonly("guide_weight", [](const StreamingPuppet& s) { return s.options().guide_weight; })
      .def_property_readonly("decode_lag", [](const StreamingPuppet& s) { return s.options().decode_lag; })
      .def_property_readonly("trajectory_lag",
                             [](const StreamingPuppet& s) { return s.options().trajectory_lag; })
      .def_property_readonly("posterior", [](const StreamingPuppet& s) { return s.options().posterior; });
}
