// Python bindings of the audio front end's kernels (audio_features.hpp). Thin: argument names,
// the GIL released around pushes; the public API is voicepuppet.audio (stream.py, featureset.py).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "voicepuppet/audio_features.hpp"

namespace py = pybind11;
using namespace voicepuppet;

void bind_audio(py::module_& m) {
  py::class_<AudioFeatureOptions>(m, "AudioFeatureOptions",
                                  "Features and analysis tables of a StreamingAudioFeatures.")
      .def(py::init<>())
      .def_readwrite("rate", &AudioFeatureOptions::rate)
      .def_readwrite("fps", &AudioFeatureOptions::fps)
      .def_readwrite("features", &AudioFeatureOptions::features)
      .def_readwrite("n_fft", &AudioFeatureOptions::n_fft)
      .def_readwrite("spectral_window", &AudioFeatureOptions::spectral_window)
      .def_readwrite("fine", &AudioFeatureOptions::fine)
      .def_readwrite("mel_filters", &AudioFeatureOptions::mel_filters)
      .def_readwrite("dct", &AudioFeatureOptions::dct)
      .def_readwrite("delta_width", &AudioFeatureOptions::delta_width)
      .def_readwrite("band_weights", &AudioFeatureOptions::band_weights)
      .def_readwrite("parseval", &AudioFeatureOptions::parseval)
      .def_readwrite("bark_filters", &AudioFeatureOptions::bark_filters)
      .def_readwrite("loudness", &AudioFeatureOptions::loudness)
      .def_readwrite("rasta_b", &AudioFeatureOptions::rasta_b)
      .def_readwrite("rasta_pole", &AudioFeatureOptions::rasta_pole)
      .def_readwrite("rasta_zi", &AudioFeatureOptions::rasta_zi)
      .def_readwrite("rasta_order", &AudioFeatureOptions::rasta_order)
      .def_readwrite("n_rasta", &AudioFeatureOptions::n_rasta)
      .def_readwrite("rasta_first", &AudioFeatureOptions::rasta_first)
      .def_readwrite("lpc_window", &AudioFeatureOptions::lpc_window)
      .def_readwrite("lpc_order", &AudioFeatureOptions::lpc_order)
      .def_readwrite("lpc_preemph", &AudioFeatureOptions::lpc_preemph)
      .def_readwrite("n_lpc_cepstra", &AudioFeatureOptions::n_lpc_cepstra)
      .def_readwrite("resample_up", &AudioFeatureOptions::resample_up)
      .def_readwrite("resample_down", &AudioFeatureOptions::resample_down)
      .def_readwrite("resample_taps", &AudioFeatureOptions::resample_taps)
      .def_readwrite("formant_rate", &AudioFeatureOptions::formant_rate)
      .def_readwrite("formant_window", &AudioFeatureOptions::formant_window)
      .def_readwrite("formant_order", &AudioFeatureOptions::formant_order)
      .def_readwrite("formant_preemph", &AudioFeatureOptions::formant_preemph)
      .def_readwrite("formant_min_freq", &AudioFeatureOptions::formant_min_freq)
      .def_readwrite("formant_max_bandwidth", &AudioFeatureOptions::formant_max_bandwidth)
      .def_readwrite("formant_margin", &AudioFeatureOptions::formant_margin)
      .def_readwrite("formant_reference", &AudioFeatureOptions::formant_reference)
      .def_readwrite("formant_lag", &AudioFeatureOptions::formant_lag);

  py::class_<StreamingAudioFeatures>(m, "StreamingAudioFeatures",
                                     "The audio front end on a stream (audio_features.hpp).")
      .def(py::init<AudioFeatureOptions>(), py::arg("options"))
      .def("push", &StreamingAudioFeatures::push, py::arg("samples"),
           py::call_guard<py::gil_scoped_release>(),
           "Feed finite float64 samples (n,); returns the frames completed [K, D].")
      .def("flush", &StreamingAudioFeatures::flush, py::arg("total") = -1,
           py::call_guard<py::gil_scoped_release>(),
           "End of stream: the remaining frames up to `total` (-1: ceil(n fps / rate)); resets.")
      .def("process", &StreamingAudioFeatures::process, py::arg("samples"), py::arg("total") = -1,
           py::call_guard<py::gil_scoped_release>(),
           "A whole recording: push + flush(total) without emitting more than `total` frames.")
      .def("reset", &StreamingAudioFeatures::reset)
      .def_property_readonly("n_features", &StreamingAudioFeatures::n_features)
      .def_property_readonly("frames_out", &StreamingAudioFeatures::frames_out)
      .def_property_readonly("samples_in", &StreamingAudioFeatures::samples_in)
      .def_property_readonly("formants_forced", &StreamingAudioFeatures::formants_forced);

  py::class_<PolyphaseResampler>(m, "PolyphaseResampler",
                                 "resample_poly on a stream (audio_features.hpp).")
      .def(py::init<Index, Index, const VectorRef&>(), py::arg("up"), py::arg("down"),
           py::arg("taps"))
      .def("push",
           [](PolyphaseResampler& r, const VectorRef& x) {
             std::vector<double> out;
             {
               py::gil_scoped_release release;
               r.push(x.data(), x.size(), out);
             }
             return py::array_t<double>(static_cast<py::ssize_t>(out.size()), out.data());
           },
           py::arg("x"), "Feed inputs; returns the outputs they complete.")
      .def("flush",
           [](PolyphaseResampler& r) {
             std::vector<double> out;
             r.flush(out);
             return py::array_t<double>(static_cast<py::ssize_t>(out.size()), out.data());
           },
           "End of input: the remaining outputs; then reset.")
      .def("reset", &PolyphaseResampler::reset)
      .def_property_readonly("up", &PolyphaseResampler::up)
      .def_property_readonly("down", &PolyphaseResampler::down);

  py::class_<FormantTracker>(m, "FormantTracker",
                             "Online formant continuity tracker (audio_features.hpp).")
      .def(py::init<const VectorRef&, Index, Index>(), py::arg("reference"), py::arg("n_cand"),
           py::arg("max_delay") = -1)
      .def("push",
           [](FormantTracker& t, const MatrixRef& freqs, const MatrixRef& bands) {
             if (freqs.rows() != bands.rows() || freqs.cols() != bands.cols())
               fail_argument("formant tracker: freqs and bands must have the same shape, got ",
                             shape_of(freqs), " and ", shape_of(bands));
             std::vector<double> out;
             for (Index k = 0; k < freqs.rows(); ++k) {
               const Eigen::VectorXd f = freqs.row(k).transpose(), b = bands.row(k).transpose();
               t.push(f.data(), b.data(), out);
             }
             return out;
           },
           py::arg("freqs"), py::arg("bands"),
           "Candidates of new frames [K, n_cand] (NaN = none); returns the finished values, flat.")
      .def("force", [](FormantTracker& t) { std::vector<double> out; t.force(out); return out; })
      .def("finish", [](FormantTracker& t) { std::vector<double> out; t.finish(out); return out; })
      .def_property_readonly("forced", &FormantTracker::forced);

  m.def("levinson",
        [](const VectorRef& r, Index order) {
          LpcFit f = levinson(r, order);
          return py::make_tuple(f.a, f.err);
        },
        py::arg("r"), py::arg("order"), "Levinson-Durbin: ([1, a_1 .. a_p], err).");
  m.def("autocorrelation", &autocorrelation, py::arg("frame"), py::arg("max_lag"));
  m.def("lpc_cepstrum", &lpc_cepstrum, py::arg("a"), py::arg("err"), py::arg("n_ceps"));
  m.def("lpc_roots", &lpc_roots, py::arg("a"), "Roots of A(z) (companion-matrix eigenvalues).");
}
