// Python bindings of the DPDS / labelled SLDS kernels (dpds.hpp). Thin: argument names, the GIL
// released around the kernels, structs returned as dicts; the public API is voicepuppet.phonemes.models.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

#include "voicepuppet/dpds.hpp"

namespace py = pybind11;
using namespace voicepuppet;

void bind_dpds(py::module_& m) {
  m.def("dpds_generate", &dpds_generate, py::arg("a"), py::arg("mu"), py::arg("nu"), py::arg("labels"),
        py::arg("offsets"), py::call_guard<py::gil_scoped_release>(),
        "DPDS mean path [T,D] for phone labels [T] (offsets [S+1] restart sequences; empty: one).");
  m.def(
      "dpds_gradient",
      [](const MatrixRef& a, const MatrixRef& mu, const MatrixRef& nu, const VectorRef& r,
         const MatrixRef& Y, const IndexVectorRef& offsets, const IndexVectorRef& labels) {
        DpdsGradient g;
        {
          py::gil_scoped_release release;
          g = dpds_gradient(a, mu, nu, r, Y, offsets, labels);
        }
        py::dict d;
        d["log_likelihood"] = g.log_likelihood;
        d["grad_a"] = g.grad_a;
        d["grad_mu"] = g.grad_mu;
        d["grad_nu"] = g.grad_nu;
        d["residual"] = g.residual;
        return d;
      },
      py::arg("a"), py::arg("mu"), py::arg("nu"), py::arg("r"), py::arg("Y"), py::arg("offsets"),
      py::arg("labels"), "DPDS log-likelihood (eq. 1) and its gradients in a, mu, nu.");
  m.def(
      "dpds_solve",
      [](const MatrixRef& a, const MatrixRef& Y, const IndexVectorRef& offsets,
         const IndexVectorRef& labels, const VectorRef& r_floor) {
        DpdsSolve s;
        {
          py::gil_scoped_release release;
          s = dpds_solve(a, Y, offsets, labels, r_floor);
        }
        py::dict d;
        d["mu"] = s.mu;
        d["nu"] = s.nu;
        d["r"] = s.r;
        d["mu_used"] = s.mu_used;
        d["nu_used"] = s.nu_used;
        d["log_likelihood"] = s.log_likelihood;
        return d;
      },
      py::arg("a"), py::arg("Y"), py::arg("offsets"), py::arg("labels"), py::arg("r_floor"),
      "Exact maximisation of eq. 1 over mu, nu and the shared output variance r for fixed a.");
  m.def(
      "slds_smooth",
      [](const MatrixRef& a, const MatrixRef& nu, const MatrixRef& q, const MatrixRef& r,
         const MatrixRef& mu1, const MatrixRef& var1, const MatrixRef& Y, const IndexVectorRef& offsets,
         const IndexVectorRef& labels) {
        SldsSmooth s;
        {
          py::gil_scoped_release release;
          s = slds_smooth(a, nu, q, r, mu1, var1, Y, offsets, labels);
        }
        py::dict d;
        d["log_likelihood"] = s.log_likelihood;
        d["mean"] = s.mean;
        d["var"] = s.var;
        d["cross"] = s.cross;
        d["pred_mean"] = s.pred_mean;
        d["pred_var"] = s.pred_var;
        return d;
      },
      py::arg("a"), py::arg("nu"), py::arg("q"), py::arg("r"), py::arg("mu1"), py::arg("var1"),
      py::arg("Y"), py::arg("offsets"), py::arg("labels"),
      "Kalman filter + RTS smoother of the labelled diagonal SLDS (B = I).");
  py::class_<DpdsStream>(m, "DpdsStream", "Streaming DPDS generation, O(D) state (dpds.hpp).")
      .def(py::init<const MatrixRef&, const MatrixRef&, const MatrixRef&>(), py::arg("a"), py::arg("mu"),
           py::arg("nu"))
      .def("push", &DpdsStream::push, py::arg("labels"), py::call_guard<py::gil_scoped_release>())
      .def("reset", &DpdsStream::reset)
      .def_property_readonly("frames", &DpdsStream::frames)
      .def_property_readonly("state", &DpdsStream::state);
}
