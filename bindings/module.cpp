// The private module voicepuppet._core: one bind_<area> per file under bindings/.
#include <pybind11/pybind11.h>

#include "voicepuppet/types.hpp"

namespace py = pybind11;

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
